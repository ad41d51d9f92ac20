"""Derivatives benchmark: cstorm's analytic hybrid_dynamics_derivatives, aba_derivatives
and rnea_derivatives (and their autodiff references), vmap-batched, against Pinocchio's
computeABADerivatives / computeRNEADerivatives called in a Python loop on the same
configurations, same machine, same run. Compile time is reported separately.

    python -m benchmarks.derivatives [--batch 4096] [--models ur5,solo12,talos] [--no-autodiff]
    python -m benchmarks.derivatives --rollout [--models solo12] [--steps 100]
    python -m benchmarks.derivatives --quick        # what `python -m benchmarks` runs, short

`run(quick=False)` (the interface of `python -m benchmarks`) returns the rows of both
parts: per-configuration batched times against Pinocchio, and the whole-rollout gradient
with the custom JVP rule (`hybrid_dynamics_fast`) against plain autodiff of the
hybrid algorithm (the "peer" of those rows is cstorm itself).

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


def run(quick=False):
    """Rows for `python -m benchmarks` (keys benchmark, case, cstorm_us, peer, peer_us,
    ratio, compile_s, notes). Full: batch 4096 on UR5, Solo12, TALOS, the autodiff
    reference for the hybrid derivatives on UR5 and Solo12 only (TALOS's takes minutes to
    compile), rollout gradients on Solo12 (100 steps).
    Quick: UR5, batch 128, analytic only, a 10-step rollout."""
    if quick:
        return (measure(128, ("ur5",), autodiff=(), repeat=1)
                + rollout_rows(("ur5",), steps=10, repeat=1))
    return (measure(4096, ("ur5", "solo12", "talos"), autodiff=("hybrid_dynamics_derivatives",), autodiff_max_nv=18)
            + rollout_rows(("solo12",), steps=100))


ALGOS = ("hybrid_dynamics_derivatives", "aba_derivatives", "rnea_derivatives")


def measure(batch=4096, models=("ur5", "solo12", "talos"), autodiff=ALGOS, pin_n=None, repeat=3, autodiff_max_nv=None):
    """Batched (vmap over `batch` configurations) per-configuration times of the analytic
    derivatives (and of the jacfwd reference for the algorithms named in `autodiff`, on
    models with at most `autodiff_max_nv` DoFs) against Pinocchio in a Python loop.
    Returns rows (dicts, see `run`)."""
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
            # the outputs computeABADerivatives computes too (values, d/dq, d/dv, d/d
            # inputs): df_ext (nv, n_bodies, 6; 60 KB per configuration on TALOS), which
            # Pinocchio has no counterpart of, is left to XLA's dead-code elimination, as
            # in any jitted caller that does not use it
            "hybrid_dynamics_derivatives without df_ext": (
                lambda q, v, a, meth: D.hybrid_dynamics_derivatives(m, q, v, a[ia], a[ip], act, method=meth)[:5],
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

            t_pin = best_of(pin_loop, repeat=repeat) / npin
            ad = name in autodiff and (autodiff_max_nv is None or m.nv <= autodiff_max_nv)
            for meth in ("analytic", "autodiff") if ad else ("analytic",):
                g = lambda q, v, a: f(q, v, a, meth)
                fb_, cb = time_compile(jax.vmap(g), Qj, Vj, Aj)
                t_batch = best_of(lambda: fb_(Qj, Vj, Aj), repeat=repeat, warmup=3) / batch
                del fb_
                rows.append(dict(benchmark="derivatives", case=f"{label}: {name} ({meth})", cstorm_us=t_batch * 1e6,
                                 peer=f"Pinocchio {pname}", peer_us=t_pin * 1e6, ratio=t_batch / t_pin,
                                 compile_s=cb, notes=f"cstorm vmap {batch}; Pinocchio Python loop"))
                print(_line(rows[-1]), flush=True)
    return rows


def _line(r):
    return (f"{r['case']}: cstorm {r['cstorm_us']:.2f} us, {r['peer']} {r['peer_us']:.2f} us, "
            f"ratio {r['ratio']:.2f}, compile {r['compile_s']:.1f} s")


def rollout_loss(m, act, hyb, q0, v0, dt=1e-3):
    """The rollout benchmarks' scalar loss of the controls ``U`` (steps, n_active):
    explicit Euler with ``lax.scan``, the ``act`` joints following ``U`` as
    accelerations, the rest passive with damping -0.1 v, dynamics by ``hyb``
    (`cs.hybrid_dynamics` or `hybrid_dynamics_fast`); sin of the final q, squared final
    v, 1e-3 times the summed squared active torques."""
    import cstorm as cs

    ia = np.nonzero(act)[0]
    ip = np.nonzero(~np.array(act))[0]

    def loss(U):
        def step(c, u):
            q, v = c
            ta, ap = hyb(m, q, v, u, -0.1 * v[ip], act)
            a = jnp.zeros(m.nv).at[ia].set(u).at[ip].set(ap)
            return (cs.integrate(m, q, v, dt), v + dt * a), jnp.sum(ta ** 2)

        (q, v), e = jax.lax.scan(step, (q0, v0), U)
        return jnp.sum(jnp.sin(q)) + jnp.sum(v ** 2) + 1e-3 * jnp.sum(e)
    return loss


def rollout_rows(models=("solo12",), steps=100, repeat=3):
    """Gradient of a scalar rollout loss (explicit Euler, lax.scan, free base passive,
    joints active) w.r.t. the controls: plain autodiff of `hybrid_dynamics` vs the custom
    JVP rule of `hybrid_dynamics_fast`, reverse mode (grad) and forward mode (jacfwd).
    Rows: cstorm_us = the fast rule, peer_us = plain autodiff (ratio < 1: the rule is
    faster), compile_s = the fast rule's compile (plain's in the notes)."""
    import cstorm as cs
    from cstorm.dynamics.derivatives_fast import hybrid_dynamics_fast

    rows = []
    for key in models:
        label, rel, fb = MODELS[key]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            m = cs.load_urdf(erd_urdf(rel), floating_base=fb, load_meshes=False, inertia_check="lenient")
        nfb = 6 if fb else 0
        act = tuple(i >= nfb for i in range(m.nv))
        ia = np.nonzero(act)[0]
        ip = np.nonzero(~np.array(act))[0]
        rng = np.random.default_rng(0)
        q0 = jnp.asarray(m.neutral())
        v0 = jnp.asarray(rng.normal(size=m.nv) * 0.1)
        U = jnp.asarray(rng.normal(size=(steps, len(ia))))

        def loss(hyb, U):
            return rollout_loss(m, act, hyb, q0, v0)(U)

        for mode, tr in (("grad (reverse)", jax.grad), ("jacfwd (forward)", jax.jacfwd)):
            times = {}
            for name, hyb in (("plain autodiff", cs.hybrid_dynamics), ("fast rule", hybrid_dynamics_fast)):
                f = lambda U, hyb=hyb: loss(hyb, U)
                c, ct = time_compile(tr(f), U)
                times[name] = (best_of(lambda: c(U), repeat=repeat), ct)
            (tp, cp), (tf, cf) = times["plain autodiff"], times["fast rule"]
            rows.append(dict(benchmark="derivatives", case=f"{label}: rollout gradient, {mode}", cstorm_us=tf * 1e6,
                             peer="cstorm plain autodiff", peer_us=tp * 1e6, ratio=tf / tp, compile_s=cf,
                             notes=f"{steps} Euler steps, {len(ia)} controls/step; speed-up {tp / tf:.2f}x; "
                                   f"plain compiles in {cp:.1f} s"))
            print(_line(rows[-1]), flush=True)
    return rows


def _table(rows):
    return f"Machine: {machine()}\n\n" + table(
        [[r["case"], f"{r['cstorm_us']:.2f}", r["peer"], f"{r['peer_us']:.2f}", f"**{r['ratio']:.2f}**",
          f"{r['compile_s']:.1f}", r["notes"]] for r in rows],
        ["case", "cstorm (us)", "peer", "peer (us)", "ratio", "compile (s)", "notes"])


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--batch", type=int, default=4096)
    ap.add_argument("--models", default="ur5,solo12,talos")
    ap.add_argument("--no-autodiff", action="store_true")
    ap.add_argument("--rollout", action="store_true")
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--quick", action="store_true", help="the short smoke run of `python -m benchmarks --quick`")
    args = ap.parse_args()
    models = tuple(args.models.split(","))
    if args.quick:
        print(_table(run(quick=True)))
    elif args.rollout:
        print(_table(rollout_rows(models, args.steps)))
    else:
        print(_table(measure(args.batch, models, () if args.no_autodiff else ALGOS)))
