"""Dynamics benchmark: cstorm's rnea, aba, hybrid_dynamics and mass_matrix, single call
and vmap-batched, against Pinocchio called in a Python loop on the same machine in the
same run. Compile time is reported separately.

    python -m benchmarks.dynamics [--batch 4096]

Models: UR5 (6-DoF fixed-base arm) and TALOS reduced (38-DoF humanoid with a free base),
both from example-robot-data. Hybrid dynamics (half the joints active) is compared with
Pinocchio's ABA, the closest algorithm it offers.
"""

from __future__ import annotations

import argparse

import numpy as np

from benchmarks._common import best_of, erd_urdf, machine, table, time_compile

import jax
import jax.numpy as jnp


MODELS = [("ur5 (6 DoF)", "ur_description/urdf/ur5_robot.urdf", None),
          ("talos_reduced (38 DoF)", "talos_data/robots/talos_reduced.urdf", "free")]


def run(batch=4096, single=200):
    import pinocchio as pin

    import cstorm as cs

    rows = []
    for label, rel, fb in MODELS:
        path = erd_urdf(rel)
        m = cs.load_urdf(path, floating_base=fb)
        pm = pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer()) if fb else pin.buildModelFromUrdf(path)
        pd = pm.createData()
        rng = np.random.default_rng(0)
        Q = np.stack([m.random_q(rng) for _ in range(batch)])
        V, A = rng.normal(size=(2, batch, m.nv))
        PQ = np.stack([pin.randomConfiguration(pm, -np.ones(pm.nq), np.ones(pm.nq)) for _ in range(batch)])
        act = tuple(bool(i % 2) if i >= (6 if fb else 0) else False for i in range(m.nv))
        ia = np.nonzero(act)[0]
        ip = np.nonzero(~np.array(act))[0]
        algos = {
            "rnea": (lambda q, v, a: cs.rnea(m, q, v, a), lambda i: pin.rnea(pm, pd, PQ[i], V[i], A[i])),
            "aba": (lambda q, v, a: cs.aba(m, q, v, a), lambda i: pin.aba(pm, pd, PQ[i], V[i], A[i])),
            "hybrid": (lambda q, v, a: cs.hybrid_dynamics(m, q, v, a[ia], a[ip], act),
                       lambda i: pin.aba(pm, pd, PQ[i], V[i], A[i])),
            "mass_matrix": (lambda q, v, a: cs.mass_matrix(m, q), lambda i: pin.crba(pm, pd, PQ[i])),
        }
        Qj, Vj, Aj = jnp.asarray(Q), jnp.asarray(V), jnp.asarray(A)
        for name, (f, pf) in algos.items():
            f1, c1 = time_compile(f, Qj[0], Vj[0], Aj[0])
            fb_, cb = time_compile(jax.vmap(f), Qj, Vj, Aj)
            t_single = best_of(lambda: [f1(Qj[i], Vj[i], Aj[i]) for i in range(single)], repeat=3) / single
            t_batch = best_of(lambda: fb_(Qj, Vj, Aj), repeat=5) / batch

            def pin_loop():
                for i in range(batch):
                    pf(i)
                return jnp.zeros(())

            t_pin = best_of(pin_loop, repeat=3) / batch
            rows.append([label, name, f"{t_single * 1e6:.1f}", f"{t_batch * 1e6:.2f}", f"{t_pin * 1e6:.2f}",
                         f"**{t_batch / t_pin:.2f}**", f"{c1:.1f} / {cb:.1f}"])
            print(" | ".join(rows[-1]), flush=True)
    hdr = ["model", "algorithm", "cstorm single call (us)", f"cstorm vmap {batch} (us/config)",
           "Pinocchio loop (us/config)", "ratio batched / Pinocchio", "compile single / batched (s)"]
    return f"Machine: {machine()}\n\n" + table(rows, hdr)


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--batch", type=int, default=4096)
    print(run(ap.parse_args().batch))
