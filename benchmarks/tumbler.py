"""Tumbler rollout benchmark: per-step cost of the contact rollout that the tumbler
handstand problem evaluates at every SLSQP iteration (compile and run timed separately).

    python -m benchmarks.tumbler [--quick]
    python -m benchmarks --only tumbler

The problem: ``cstorm.examples.tumbler.tumbler_segment("handstand")``: the planar
three-capsule tumbler (planar passive base ``root_x, root_z, root_pitch`` on the torso,
active hip and shoulder), 10 contact points against the ground, RK4 at `HANDSTAND_DT`
over `HANDSTAND_T`. Timed: ``problem.compiled("fun")`` (objective and constraints: one
recorded rollout) and, unless ``--quick``, ``problem.compiled("fun_jac")`` (values and
the forward-mode Jacobian, one tangent per decision variable), each at the initial
guess, best of several calls, reported per RK4 step; compile time separately.

Peer (same run, same process): one dynamics *stage* (contact forces, passive forces and
the hybrid dynamics at one instant, the work an RK4 step does four times) in a plain
``lax.scan`` of as many evaluations as the rollout has steps. ``ratio`` = rollout step / (4 x stage): how much the
rollout (state updates, the stage loop, divergence checks, recording, the running cost)
adds on top of the dynamics itself; 1 would be no overhead (for ``fun_jac`` the ratio
includes the derivatives).

Reference point (DESIGN.md): the feasibility study's hand-written rollout of the same
robot took 12 us per RK4 step. On a shared machine the ratios carry noise; the load
average is recorded with each run.

Results: ``benchmarks/results/tumbler.json`` (written by ``python -m benchmarks``).
"""

from __future__ import annotations

import os
import time

import jax
import numpy as np
import jax.numpy as jnp

from benchmarks._common import best_of


def _stage_scan(p, d, n):
    """A jitted scan of ``n`` dynamics stages (contact + passive + hybrid) at perturbed
    states of the problem's start posture."""
    from cstorm.contact import contact_forces
    from cstorm.simulate import _stage

    lay = p.layout
    ia, iva = np.array(lay.qa_idx, int), np.array(lay.va_idx, int)

    def f(m, env, cp, q0):
        def cfn(q, v):
            o = contact_forces(m, env, cp, q, v)
            return o.f_ext, o

        def body(carry, _):  # the step index in the carry: no loop buffer over 512 bytes
            acc, k = carry
            q = q0 + 1e-3 * jnp.sin(0.01 * k)
            v = 0.1 * jnp.cos(0.01 * k) * jnp.ones(m.nv)
            out = _stage(m, lay, q, v, q[ia], v[iva], 0.1 * jnp.ones(len(iva)) * jnp.cos(k), 0.0, cfn, None, None)
            return (acc + jnp.sum(out[2]) + jnp.sum(out[3]), k + 1.0), None

        return jax.lax.scan(body, (jnp.zeros(()), jnp.zeros(())), None, length=n)[0][0]

    args = (d["model"], d["env"], d["contact"], jnp.asarray(p.q0))
    t0 = time.perf_counter()
    c = jax.jit(f).lower(*args).compile()
    return c, args, time.perf_counter() - t0


def run(quick=False):
    """Rows for `python -m benchmarks` (see the module docstring)."""
    jax.config.update("jax_enable_x64", True)
    from cstorm.examples.tumbler import tumbler_segment

    p = tumbler_segment("handstand")
    d = p.data()
    x0 = jnp.asarray(p.x0() if callable(p.x0) else p.x0)
    N = p.n_steps
    repeat = 3 if quick else 7
    stage, sargs, st_compile = _stage_scan(p, d, N)
    t_stage = best_of(lambda: stage(*sargs), repeat=repeat) / N
    rows = []
    which = ["fun"] if quick else ["fun", "fun_jac"]
    for w in which:
        fn = p.fun_jac if w == "fun_jac" else (
            lambda x, dd: (lambda r: (r["f"], r["c_eq"], r["c_in"], r["diverged"]))(p.evaluate(x, dd)))
        t0 = time.perf_counter()
        c = jax.jit(fn).lower(x0, d).compile()
        tc = time.perf_counter() - t0
        t = best_of(lambda: c(x0, d), repeat=repeat)
        rows.append(dict(case=f"tumbler handstand {w}: per RK4 step ({N} steps, {t * 1e3:.1f} ms per call)",
                         cstorm_us=t / N * 1e6, peer="4 x one dynamics stage (contact + hybrid) in a plain scan",
                         peer_us=4 * t_stage * 1e6, ratio=t / N / (4 * t_stage), compile_s=tc,
                         notes=f"stage scan compile {st_compile:.1f} s; load {os.getloadavg()[0]:.1f}"))
    return rows


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args()
    for r in run(quick=a.quick):
        print(r)
