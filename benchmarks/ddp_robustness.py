"""Robustness of `method="ddp"` with its defaults on perturbed variants of a shipped
problem: masses and link lengths +-20 %, horizons +-20 %, noise on the guess's
keyframes, seeded; and the same problem with analytic and with autodiff derivatives
(the optimum must not depend on rounding: costs within 1e-6 relative).

    python -m benchmarks.ddp_robustness [--problem acrobot] [--variants 20] [--seed 0]
                                        [--ddp-options '{"second_order": true}'] [--out PATH]

Writes ``benchmarks/results/ddp-robustness-<problem>-<date>.json`` (date, commit,
machine, one row per variant: what was changed, success, cost, iterations, wall and
compile time), rewritten after every variant (``complete`` false until the rounding check
at the end), and prints a table with the success rate. ``--ddp-options``: solver options
(JSON) for every solve instead of the defaults. The variants of one horizon
share compiled code through JAX's persistent cache (set here to a fresh directory).
A benchmark, never a test.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time

import numpy as np
import jax

jax.config.update("jax_enable_x64", True)


def _acrobot_variant(rng, k):
    """A perturbed acrobot swing-up: masses, lengths and horizon +-20 %, and the elbow
    guess's amplitude and phase jittered. Variant 0 is the nominal problem."""
    from cstorm.examples.acrobot import acrobot_model
    from cstorm.optimize import costs, constraints
    from cstorm.optimize.problem import MotionProblem

    if k == 0:
        mass, length, T, amp, phase = 1.0, 1.0, 3.0, 0.3, 0.0
    else:
        mass = float(rng.uniform(0.8, 1.2))
        length = float(rng.uniform(0.8, 1.2))
        T = float(rng.choice([2.5, 3.0, 3.5]))  # +-17 %: three shapes, each compiled once
        amp, phase = float(rng.uniform(0.1, 0.5)), float(rng.uniform(-0.5, 0.5))
    model = acrobot_model(length=length, mass=mass)
    t = np.linspace(0, T, 64)
    guess = amp * np.sin(np.pi * t + phase) * np.sin(np.pi * t / T) ** 2
    p = MotionProblem(model, active=["elbow"], t_final=T, n_ctrl=16, dt=0.01, q0=np.zeros(2),
                      q_final_active={"elbow": 0.0}, rest_end=True, costs=[costs.TorqueSquared()],
                      constraints=[constraints.TerminalState("shoulder", q=np.pi, v=0.0)],
                      initial_guess={"elbow": (t, guess)}, name=f"acrobot-variant-{k}")
    return p, dict(mass=mass, length=length, t_final=T, guess_amplitude=amp, guess_phase=phase)


def _luxo_variant(rng, k):
    """A perturbed Luxo hop: every body's mass and rotational inertia x U(0.8, 1.2),
    friction U(0.5, 1.0), contact stiffness x 2^U(-1, 1), hop distance x U(0.7, 1.3), and
    the guess's keyframe postures jittered by N(0, 0.05) rad. The start and the landing
    pose are the variant's own standing equilibrium. Horizon and step as shipped (one
    compiled shape). Variant 0 is the nominal problem."""
    from cstorm.contact import Environment, ground
    from cstorm.examples.hopping import standing_equilibrium
    from cstorm.examples.luxo import ACTIVE, FOOT_LENGTH, KEYFRAMES, REST_ACTIVE, REST_PITCH, REST_Z, luxo, \
        luxo_contact, luxo_model

    model = luxo_model()
    if k == 0:
        ms, fr, ks, ds, noise = 1.0, 0.8, 1.0, 1.0, 0.0
        mass = np.ones(model.n_bodies)
    else:
        mass = rng.uniform(0.8, 1.2, model.n_bodies)
        fr, ks, ds, noise = float(rng.uniform(0.5, 1.0)), float(2.0 ** rng.uniform(-1, 1)), \
            float(rng.uniform(0.7, 1.3)), 0.05
        ms = float(np.mean(mass))
    model = model.replace(mass=model.mass * mass, inertia=model.inertia * mass[:, None, None])
    contact = luxo_contact(stiffness=5e3 * ks, friction=fr)
    q_rest, _ = standing_equilibrium(model, Environment([ground()]), contact,
                                     np.array([0.0, REST_Z, REST_PITCH, *REST_ACTIVE]), ACTIVE)
    keys = tuple((t, tuple(np.asarray(post) + noise * rng.standard_normal(3))) if 0 < t < 1 else (t, post)
                 for t, post in KEYFRAMES)
    p = luxo(distance=FOOT_LENGTH * ds, contact=contact, model=model, q_rest=np.asarray(q_rest), keyframes=keys,
             name=f"luxo-variant-{k}")
    return p, dict(mass_scale_mean=ms, friction=fr, stiffness_scale=ks, distance_scale=ds, keyframe_noise_rad=noise)


VARIANTS = {"acrobot": _acrobot_variant, "luxo": _luxo_variant}


def main(argv=None):
    import cstorm as cs
    from benchmarks.ddp import _provenance

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--problem", default="acrobot", choices=sorted(VARIANTS))
    ap.add_argument("--variants", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--ddp-options", default=None, help="DDP options (JSON) instead of the defaults")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    options = json.loads(a.ddp_options) if a.ddp_options else None
    prov = _provenance()
    out = a.out or os.path.join(os.path.dirname(__file__), "results",
                                f"ddp-robustness-{a.problem}{'-options' if options else ''}-{prov['date'][:10]}.json")
    os.makedirs(os.path.dirname(out), exist_ok=True)

    def write(rows, **extra):  # atomically, after every variant: a stopped run keeps what it measured
        ok = sum(r["success"] for r in rows)
        with open(out + ".tmp", "w") as f:
            json.dump(dict(provenance=prov, problem=a.problem, seed=a.seed, options=options or {},
                           success_rate=ok / len(rows), variants_done=len(rows), variants=a.variants, rows=rows,
                           **extra), f, indent=1)
        os.replace(out + ".tmp", out)

    jax.config.update("jax_compilation_cache_dir", tempfile.mkdtemp(prefix="cstorm-bench-"))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    rng = np.random.default_rng(a.seed)
    rows = []
    for k in range(a.variants):
        p, what = VARIANTS[a.problem](rng, k)
        t0 = time.perf_counter()
        s = cs.solve(p, method="ddp", options=options)
        rows.append(dict(variant=k, **what, success=s.success, cost=s.cost, violation=s.constraint_violation,
                         iterations=s.iterations, wall_s=time.perf_counter() - t0, compile_s=s.compile_time_s,
                         message=s.message))
        print(f"{k:3d} {'ok ' if s.success else 'NO '} cost {s.cost:10.5g} it {s.iterations:4d} "
              f"{rows[-1]['wall_s']:6.1f} s  {what}", flush=True)
        write(rows, complete=False)
    # rounding: the nominal problem with autodiff derivatives
    p, _ = VARIANTS[a.problem](np.random.default_rng(a.seed), 0)
    p.derivatives = "autodiff"
    s = cs.solve(p, method="ddp", options=options)
    nominal = rows[0]
    rel = abs(s.cost - nominal["cost"]) / abs(nominal["cost"])
    rounding = dict(analytic_cost=nominal["cost"], autodiff_cost=s.cost, relative_difference=rel,
                    both_success=bool(s.success and nominal["success"]))
    ok = sum(r["success"] for r in rows)
    print(f"success {ok}/{len(rows)} ({100.0 * ok / len(rows):.0f} %); analytic vs autodiff derivatives: costs "
          f"{nominal['cost']:.12g} / {s.cost:.12g}, relative difference {rel:.2e}")
    write(rows, complete=True, rounding=rounding)
    print(f"written to {out}")


if __name__ == "__main__":
    main()
