"""Dynamics benchmark: cstorm's rnea, aba, hybrid_dynamics and mass_matrix, single call
and vmap-batched, against Pinocchio called in a Python loop on the same machine in the
same run. Compile time is reported separately.

    python -m benchmarks.dynamics [--batch 4096] [--quick]

`run(quick=False)` is the interface of `python -m benchmarks`: rows (dicts with keys
benchmark, case, cstorm_us, peer, peer_us, ratio, compile_s, notes) of the batched
per-configuration time against Pinocchio, the single-call time in the notes. Quick: UR5
only, batch 128.

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


def run(quick=False):
    """Rows for `python -m benchmarks` (see the module docstring)."""
    if quick:
        return measure(batch=128, single=20, models=MODELS[:1], repeat=1)
    return measure()


def measure(batch=4096, single=200, models=MODELS, repeat=5):
    """Single-call and vmap-batched times of rnea, aba, hybrid_dynamics, mass_matrix
    against Pinocchio in a Python loop on the same machine; one row per (model, algorithm)."""
    import pinocchio as pin

    import cstorm as cs

    rows = []
    for label, rel, fb in models:
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
        peers = {"rnea": "Pinocchio rnea", "aba": "Pinocchio aba", "hybrid": "Pinocchio aba",
                 "mass_matrix": "Pinocchio crba"}
        Qj, Vj, Aj = jnp.asarray(Q), jnp.asarray(V), jnp.asarray(A)
        for name, (f, pf) in algos.items():
            f1, c1 = time_compile(f, Qj[0], Vj[0], Aj[0])
            fb_, cb = time_compile(jax.vmap(f), Qj, Vj, Aj)
            t_single = best_of(lambda: [f1(Qj[i], Vj[i], Aj[i]) for i in range(single)], repeat=min(repeat, 3)) / single
            t_batch = best_of(lambda: fb_(Qj, Vj, Aj), repeat=repeat) / batch

            def pin_loop():
                for i in range(batch):
                    pf(i)
                return jnp.zeros(())

            t_pin = best_of(pin_loop, repeat=min(repeat, 3)) / batch
            rows.append(dict(benchmark="dynamics", case=f"{label}: {name}", cstorm_us=t_batch * 1e6,
                             peer=peers[name] + " (Python loop)", peer_us=t_pin * 1e6, ratio=t_batch / t_pin,
                             compile_s=cb, notes=f"vmap {batch}; single call {t_single * 1e6:.0f} us "
                                                 f"(compile {c1:.1f} s)"))
            r = rows[-1]
            print(f"{r['case']}: {r['cstorm_us']:.2f} us vs {r['peer_us']:.2f} us, ratio {r['ratio']:.2f}, "
                  f"compile {r['compile_s']:.1f} s; {r['notes']}", flush=True)
    return rows


def _table(rows):
    return f"Machine: {machine()}\n\n" + table(
        [[r["case"], f"{r['cstorm_us']:.2f}", r["peer"], f"{r['peer_us']:.2f}", f"**{r['ratio']:.2f}**",
          f"{r['compile_s']:.1f}", r["notes"]] for r in rows],
        ["case", "cstorm (us/config)", "peer", "peer (us/config)", "ratio", "compile batched (s)", "notes"])


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--batch", type=int, default=4096)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    print(_table(run(quick=True) if args.quick else measure(args.batch)))
