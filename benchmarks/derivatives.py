"""Derivatives benchmark: cstorm's analytic hybrid_dynamics_derivatives, aba_derivatives
and rnea_derivatives (and their autodiff references), vmap-batched, against Pinocchio's
computeABADerivatives / computeRNEADerivatives called in a Python loop on the same
configurations, same machine, same run. Compile time is reported separately.

    python -m benchmarks.derivatives [--batch 4096] [--models ur5,solo12,talos] [--no-autodiff]

Models (example-robot-data, loaded with `cs.load_urdf`): UR5 (6-DoF arm), Solo12 (18 DoF:
12 joints and a free base), TALOS reduced (38 DoF: 32 joints and a free base). Hybrid: the
free base and every other joint passive, the rest active. Pinocchio has no hybrid
derivative; its ABA derivatives are the closest (and the target: <= 2x).
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np

from benchmarks._common import best_of, erd_urdf, machine, table, time_compile

import jax
import jax.numpy as jnp

MODELS = {
    "ur5": ("ur5 (6 DoF)", "ur_description/urdf/ur5_robot.urdf", None),
    "solo12": ("solo12 (18 DoF)", "solo_description/robots/solo12.urdf", "free"),
    "talos": ("talos_reduced (38 DoF)", "talos_data/robots/talos_reduced.urdf", "free"),
}


def run(batch=4096, models=("ur5", "solo12", "talos"), autodiff=True, pin_n=None):
    import pinocchio as pin

    import cstorm as cs
    from cstorm.dynamics import derivatives as D

    rows = []
    for key in models:
        label, rel, fb = MODELS[key]
        path = erd_urdf(rel)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            m = cs.load_urdf(path, floating_base=fb, load_meshes=False, inertia_check="lenient")
        pm = pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer()) if fb else pin.buildModelFromUrdf(path)
        pd = pm.createData()
        rng = np.random.default_rng(0)
        Q = np.stack([m.random_q(rng) for _ in range(batch)])
        V, A = rng.normal(size=(2, batch, m.nv))
        PQ = np.stack([pin.randomConfiguration(pm, -np.ones(pm.nq), np.ones(pm.nq)) for _ in range(batch)])
        nfb = 6 if fb else 0
        act = tuple(bool(i % 2) if i >= nfb else False for i in range(m.nv))
        ia = np.nonzero(act)[0]
        ip = np.nonzero(~np.array(act))[0]
        algos = {
            "hybrid_dynamics_derivatives": (
                lambda q, v, a, meth: D.hybrid_dynamics_derivatives(m, q, v, a[ia], a[ip], act, method=meth),
                lambda i: pin.computeABADerivatives(pm, pd, PQ[i], V[i], A[i]), "computeABADerivatives"),
            "aba_derivatives": (
                lambda q, v, a, meth: D.aba_derivatives(m, q, v, a, method=meth),
                lambda i: pin.computeABADerivatives(pm, pd, PQ[i], V[i], A[i]), "computeABADerivatives"),
            "rnea_derivatives": (
                lambda q, v, a, meth: D.rnea_derivatives(m, q, v, a, method=meth),
                lambda i: pin.computeRNEADerivatives(pm, pd, PQ[i], V[i], A[i]), "computeRNEADerivatives"),
        }
        Qj, Vj, Aj = jnp.asarray(Q), jnp.asarray(V), jnp.asarray(A)
        npin = pin_n or batch
        for name, (f, pf, pname) in algos.items():

            def pin_loop():
                for i in range(npin):
                    pf(i)
                return jnp.zeros(())

            t_pin = best_of(pin_loop, repeat=3) / npin
            for meth in ("analytic", "autodiff") if autodiff else ("analytic",):
                g = lambda q, v, a: f(q, v, a, meth)
                fb_, cb = time_compile(jax.vmap(g), Qj, Vj, Aj)
                t_batch = best_of(lambda: fb_(Qj, Vj, Aj), repeat=3) / batch
                del fb_
                rows.append([label, name, meth, f"{t_batch * 1e6:.2f}", pname, f"{t_pin * 1e6:.2f}",
                             f"**{t_batch / t_pin:.2f}**", f"{cb:.1f}"])
                print(" | ".join(rows[-1]), flush=True)
    hdr = ["model", "cstorm function", "method", f"cstorm vmap {batch} (us/config)", "Pinocchio",
           "Pinocchio loop (us/config)", "ratio cstorm / Pinocchio", "compile batched (s)"]
    return f"Machine: {machine()}\n\n" + table(rows, hdr)


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--batch", type=int, default=4096)
    ap.add_argument("--models", default="ur5,solo12,talos")
    ap.add_argument("--no-autodiff", action="store_true")
    args = ap.parse_args()
    print(run(args.batch, tuple(args.models.split(",")), not args.no_autodiff))
