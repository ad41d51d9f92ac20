"""The time-parallel tangent rule of rollouts (`cstorm.simulate.tangents`, the rollout's
``derivatives="parallel"``) against plain autodiff through the scan
(``derivatives="autodiff"``), which we did not specialize: forward and reverse mode, a
free body landing on the ground through the smooth contact model (RKMK4 and
semi-implicit Euler), every recorded output (states, accelerations, torques, contact
data), a traced step count (frozen padding steps), a diverged rollout (frozen state),
and tangents of closed-over values (contact stiffness, the time step, a link mass).

Compile budget: one small model, 24 steps; each mode's Jacobians (with the values as an aux
output) are compiled once per integrator, with XLA's backend optimizations off.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pytest
import jax
import jax.numpy as jnp

import cstorm as cs
from cstorm.contact import contact_forces
from cstorm.simulate import tangents as rollout_tangents
from cstorm.simulate import RolloutLayout, rollout

N = 24

# These tests need correct numbers, not fast code: compile with XLA's backend
# optimizations off (as tests/test_derivatives.py does), and take the values from the
# Jacobian's compile (``has_aux``) rather than compiling the primal again.
jit = functools.partial(jax.jit, compiler_options={"xla_backend_optimization_level": 0,
                                                   "xla_llvm_disable_expensive_passes": True})


def _with_values(jac, f):
    """``(th, ...) -> (Jacobian w.r.t. th, values)``, jitted, from one trace of f by
    ``jac`` (jax.jacfwd or jax.jacrev)."""
    def f2(*a):
        y = f(*a)
        return y, y
    return jit(jac(f2, has_aux=True))


def _model():
    """A capsule on a hinge on a free base: a free body with one active joint, which
    lands on the ground during the rollout."""
    b = cs.ModelBuilder("hinged", gravity=(0.0, 0.0, -9.81))
    b.add_link("base", mass=1.0, inertia=np.diag([0.01, 0.012, 0.014]))
    b.add_geom("base", cs.Sphere(0.05))
    b.add_body("arm", "base", "revolute", mass=0.4, com=(0.1, 0.0, 0.0), inertia=np.diag([1e-4, 2e-3, 2e-3]),
               axis=(0.0, 1.0, 0.0), xyz=(0.03, 0.0, 0.0))
    b.add_geom("arm", cs.Capsule(0.02, 0.2), xyz=(0.1, 0.0, 0.0), rpy=(0.0, np.pi / 2, 0.0))
    return b.build(floating_base="free")


@pytest.fixture(scope="module")
def hinged():
    return _setup()


def _setup():
    m = _model()
    lay = RolloutLayout.make(m, ["arm"])
    env = cs.Environment([cs.ground()])
    P = cs.ContactParams(stiffness=3000.0, damping=30.0, d_on=0.005, d_off=0.0, friction=0.7, v_max=0.1)
    rng = np.random.default_rng(7)
    t = np.linspace(0.0, 1.0, N + 1)
    tm = (t[:-1] + t[1:]) / 2
    paths = dict(qa=0.3 * np.sin(3 * t)[:, None], va=0.9 * np.cos(3 * t)[:, None], aa=-2.7 * np.sin(3 * t)[:, None],
                 qm=0.3 * np.sin(3 * tm)[:, None], vm=0.9 * np.cos(3 * tm)[:, None],
                 am=-2.7 * np.sin(3 * tm)[:, None])
    paths = {k: jnp.asarray(v) for k, v in paths.items()}
    # starts 2 cm above the ground, tilted, moving down and sideways: lands within ~40 ms
    q0 = jnp.asarray(np.concatenate([[0.0, 0.0, 0.075], [np.cos(0.1), 0.0, np.sin(0.1), 0.0], [0.0]]))
    v0 = jnp.asarray([0.2, -0.3, 0.1, 0.3, 0.1, -0.6, 0.0])
    return dict(m=m, lay=lay, env=env, P=P, paths=paths, q0=q0, v0=v0, dirs=rng.normal(size=(3, N + 1)))


def _outputs(s, derivatives, integrator, scale, stiffness, dt, mass, n_valid, v_bound):
    """A vector of rollout outputs: final state, cost, and weighted sums of every
    recorded field (states, accelerations, torques, contact distances and forces)."""
    m = s["m"].replace(mass=s["m"].mass.at[1].set(mass))
    P = dataclasses.replace(s["P"], stiffness=stiffness)
    paths = {k: v * scale for k, v in s["paths"].items()}

    def cfn(q, v):  # the reference differentiates the contact code plainly too
        out = contact_forces(m, s["env"], P, q, v, jacobians="autodiff" if derivatives == "autodiff" else "analytic")
        return out.f_ext, out

    cost = lambda t, q, v, a, tau, c, p: 0.5 * jnp.sum(tau ** 2) + jnp.sum(c.normal_magnitude)
    r = rollout(m, s["lay"], s["q0"], s["v0"], paths, dt, N, integrator=integrator, contact_fn=cfn, cost_fn=cost,
                n_valid=n_valid, v_bound=v_bound, derivatives=derivatives)
    tr, w = r["traj"], jnp.asarray(s["dirs"])
    rec = [tr["q"], tr["v"], tr["a"], tr["tau"], tr["contact"].d, tr["contact"].normal_force,
           tr["contact"].friction_force, tr["contact"].f_ext]
    sums = [jnp.einsum("k,k...->...", w[i % 3], y).reshape(-1) for i, y in enumerate(rec)]
    return jnp.concatenate([r["qT"], r["vT"], r["J"][None], jnp.where(r["diverged"], 1.0, 0.0)[None]] + sums)


_FNS = {}


def _fns(s, integrator):
    """Per mode: jitted ``(Jacobian, values)`` w.r.t. (path scale, stiffness, dt, mass)
    in forward mode, and for the parallel rule in reverse mode too, all with traced
    n_valid and v_bound (three compiles per integrator)."""
    if integrator not in _FNS:
        out = {}
        for mode in ("parallel", "autodiff"):
            def f(th, n_valid, v_bound, mode=mode):
                return _outputs(s, mode, integrator, th[0], th[1], th[2], th[3], n_valid, v_bound)

            out[mode] = (_with_values(jax.jacfwd, f),) + ((_with_values(jax.jacrev, f),) if mode == "parallel" else ())
        _FNS[integrator] = out
    return _FNS[integrator]


def _check(hinged, integrator, n_valid, v_bound=1e4):
    th = jnp.asarray([1.0, 3000.0, 1.0 / N, 0.4])
    fns = _fns(hinged, integrator)
    n_valid, v_bound = jnp.asarray(n_valid), jnp.asarray(v_bound)
    ref_f, ref_v = fns["autodiff"][0](th, n_valid, v_bound)
    (jf, val), (jr, val_r) = (g(th, n_valid, v_bound) for g in fns["parallel"])
    assert np.all(np.isfinite(np.asarray(ref_f)))
    # the values come out of the tangent rules' primal passes (different code paths,
    # different rounding): equal to ~1e-12 through ~24 steps with contact
    np.testing.assert_allclose(val, ref_v, rtol=1e-11, atol=1e-12)
    np.testing.assert_allclose(val_r, ref_v, rtol=1e-11, atol=1e-12)
    R = np.abs(np.asarray(ref_f))
    scale = np.maximum(np.maximum(R, 1e-3 * R.max(axis=0)), 1e-12)  # (a frozen rollout has zero columns)
    for J in (jf, jr):
        err = np.abs(np.asarray(J) - np.asarray(ref_f)) / scale
        assert err.max() < 1e-9, (integrator, int(n_valid), float(v_bound), J is jr, err.max())
    return val, ref_f


def _all_cases(hinged, integrator):
    # full length: the body lands, so the Jacobians go through the contact law
    val, J = _check(hinged, integrator, N)
    assert float(val[15]) > 0  # cost
    assert np.abs(np.asarray(J)[:, 1]).max() > 0  # the contact stiffness matters: there was contact
    # a traced step count below N (the padding steps are frozen)
    _check(hinged, integrator, N - 7)
    # a velocity bound that the falling body exceeds: the rollout diverges and its state freezes
    val, _ = _check(hinged, integrator, N, v_bound=1.2)
    assert float(val[16]) == 1.0


def test_parallel_tangents_equal_autodiff_rk4(hinged, monkeypatch):
    """RK4 (RKMK4 on the free base): forward- and reverse-mode Jacobians of every output
    w.r.t. a path scale, the contact stiffness, the time step (free final time) and the
    arm's mass equal autodiff's to 1e-9, at full length, with frozen padding steps and
    after divergence (one compiled function per mode for all three). The step Jacobians
    are evaluated in batches of 5 here (24 steps: five batches, the last one padded);
    the Euler test uses the default single batch."""
    monkeypatch.setattr(rollout_tangents, "BATCH", 5)
    _all_cases(hinged, "rk4")


@pytest.mark.slow
def test_parallel_tangents_equal_autodiff_euler(hinged):
    """The same for semi-implicit Euler (slow: ~70 s alone on 2 cores, mostly compilation)."""
    _all_cases(hinged, "euler")


def test_record_rows_hold_those_points_with_exact_tangents(hinged):
    """``rollout(record_rows=...)`` records those grid points only (sorted, no repeats).
    Its values equal the full recording's rows with the plain rule and the parallel one,
    and the parallel rule's forward-mode Jacobian (which then evaluates the grid-point
    Jacobians at those rows only) equals autodiff's through the full recording, to 1e-9,
    w.r.t. a path scale and the contact stiffness, with the body landing."""
    s = hinged
    rows = (24, 0, 5, 11, 5, 23)
    keep = np.array(sorted(set(rows)))

    def out(th, derivatives, rows):
        P = dataclasses.replace(s["P"], stiffness=th[1])
        paths = {k: v * th[0] for k, v in s["paths"].items()}

        def cfn(q, v):
            o = contact_forces(s["m"], s["env"], P, q, v, jacobians="autodiff" if derivatives == "autodiff" else "analytic")
            return o.f_ext, o

        cost = lambda t, q, v, a, tau, c, p: 0.5 * jnp.sum(tau ** 2)
        r = rollout(s["m"], s["lay"], s["q0"], s["v0"], paths, 1.0 / N, N, contact_fn=cfn, cost_fn=cost,
                    derivatives=derivatives, record_rows=rows)
        tr = r["traj"]
        rec = [tr["q"], tr["v"], tr["a"], tr["tau"], tr["contact"].d, tr["contact"].normal_force, tr["contact"].f_ext]
        if rows is None:
            rec = [y[keep] for y in rec]
        return jnp.concatenate([r["qT"], r["vT"], r["J"][None]] + [y.reshape(-1) for y in rec])

    th = jnp.asarray([1.0, 3000.0])
    ref_J, ref = _with_values(jax.jacfwd, lambda t: out(t, "autodiff", None))(th)
    J, val = _with_values(jax.jacfwd, lambda t: out(t, "parallel", rows))(th)
    np.testing.assert_allclose(val, ref, rtol=1e-11, atol=1e-12)  # (rounding: see _check)
    # the analytic rule's values (its primal, not a tangent rule's)
    np.testing.assert_allclose(jit(lambda t: out(t, "analytic", rows))(th), ref, rtol=1e-11, atol=1e-12)
    assert np.abs(np.asarray(ref_J)[:, 1]).max() > 0  # there was contact
    scale = np.maximum(np.abs(np.asarray(ref_J)), 1e-3 * np.abs(np.asarray(ref_J)).max(axis=0))
    assert (np.abs(np.asarray(J) - np.asarray(ref_J)) / np.maximum(scale, 1e-12)).max() < 1e-9
    with pytest.raises(cs.InputError, match="record_rows"):
        out(th, "analytic", (0, N + 1))
