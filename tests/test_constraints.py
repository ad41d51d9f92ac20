"""Constraint terms (`cstorm.optimize.constraints`): their values against what they are
documented to be, their descriptions, their checks; the smooth helpers' bounds."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import jax
import jax.numpy as jnp

from cstorm.contact import ContactParams, Environment, contact_labels, ground
from cstorm.errors import ProblemError
from cstorm.examples import robots
from cstorm.examples.acrobot import acrobot_model
from cstorm.optimize import MotionProblem, constraints
from cstorm.optimize.constraints import (AtRest, FlightClearance, ForwardDistance, PitchBound, ScaledTorqueLimits,
                                         SlipPower, SwingClearance, ks_max, soft_clearance, window_index)


def test_soft_clearance_bounds():
    rng = np.random.default_rng(0)
    d = rng.uniform(-0.01, 0.1, size=(40, 6))
    true = np.max(np.min(d, axis=1))
    s = float(soft_clearance(d, 1e-3, 2e-3))
    assert true - 1e-3 * np.log(6) - 1e-12 <= s <= true + 2e-3 * np.log(40) + 1e-12


def test_at_rest_accel_tol_values():
    """`AtRest` with ``accel_tol``: ``|v_p| <= tol`` and ``|a_p| <= accel_tol`` (values
    scaled by ``accel_scale``), each from both sides; without it the old single
    tolerance; ``accel_tol`` needs ``acceleration=True`` and ``tol``."""
    prob = SimpleNamespace(layout=SimpleNamespace(vp_idx=[0, 1]))
    ctx = SimpleNamespace(params={"tv": 1e-3, "ta": 0.5})
    end = dict(v=np.array([2e-4, -3e-3, 9.0]), a=np.array([0.4, -0.7, 9.0]))
    c = AtRest(tol="tv", accel_tol="ta")
    c.check(prob)
    np.testing.assert_allclose(np.asarray(c.values(ctx, end, None)),
                               [8e-4, 4e-3, 1.2e-3, -2e-3, 0.01, 0.12, 0.09, -0.02], atol=1e-15)
    assert c.describe()["accel_tol"] == "ta" and "accel_tol" not in AtRest(tol="tv").describe()
    old = AtRest(tol="tv")
    old.check(prob)
    assert np.asarray(old.values(ctx, end, None)).shape == (8,)
    with pytest.raises(ProblemError, match="accel_tol"):
        AtRest(accel_tol="ta")


def test_terminal_state_acceleration_part():
    """``TerminalState(joint, v=..., a=...)``: the values are the final velocity, then the
    final acceleration (the dynamics' passive acceleration at the end state) minus their
    targets; as an inequality ``tol -/+ error``; ``a`` alone is enough."""
    m = acrobot_model()
    cons = [constraints.TerminalState("shoulder", v=0.0, a=0.5),
            constraints.TerminalState("shoulder", a=0.0, kind="ineq", tol="atol")]
    p = MotionProblem(m, ["elbow"], 0.4, 6, 0.02, np.array([0.3, 0.2]), constraints=cons, params={"atol": 2.0})
    x = jnp.asarray(p.x0) + 0.1
    r = p.evaluate(x, p.data())
    tr = p.trajectory(x, p.data())
    vT, aT = float(tr["v"][-1][0]), float(tr["a"][-1][0])
    assert abs(aT) > 1e-3  # the passive shoulder is not at rest at 0.3 rad
    np.testing.assert_allclose(np.asarray(r["c_eq"]), [vT, aT - 0.5], rtol=1e-12)
    np.testing.assert_allclose(np.asarray(r["c_in"]), [2.0 - aT, 2.0 + aT], rtol=1e-12)
    assert "a" in cons[0].describe() and "a" not in constraints.TerminalState("shoulder", v=0.0).describe()


def test_torque_limits_dense_bound_every_step():
    """``TorqueLimits(dense=True)``: every integration step enters, through a smooth max per
    window of the constraint grid, so its values bound the worst step's from the safe side,
    within ``ln(L)/rho`` of the limit; the sampled form misses steps between samples. The
    gradient is finite and matches central differences."""
    W = window_index(np.array([0, 4, 8, 10]), 10)
    assert W.shape == (4, 4)
    assert sorted(set(W.ravel().tolist())) == list(range(11))  # every step, in its own window
    g = jnp.array([[0.3, 0.9, 0.9, -2.0]])
    k = float(ks_max(g, 50.0, axis=1)[0])
    assert 0.9 <= k <= 0.9 + np.log(4) / 50
    m = acrobot_model()
    lim = 2.0
    terms = [constraints.TorqueLimits(limits=lim, normalized=True),
             constraints.TorqueLimits(limits=lim, normalized=True, dense=True, rho=400.0)]
    p = MotionProblem(m, ["elbow"], 0.6, 6, 0.01, np.array([0.3, 0.2]), constraints=terms, n_path_samples=5)
    x = jnp.asarray(p.x0) + jnp.linspace(-0.4, 0.5, p.n_vars)
    r = np.asarray(p.evaluate(x, p.data())["c_in"])
    n = len(r) // 2
    grid, dense = r[:n], r[n:]
    tau = np.asarray(p.trajectory(x, p.data())["tau"])[:, list(p.layout.va_idx)]
    worst = 1.0 - np.max(np.abs(tau)) / lim  # the true margin on the worst step
    Wn = window_index(p.sample_idx, p.n_steps)
    L = Wn.shape[1]
    assert dense.min() <= worst + 1e-12 and dense.min() >= worst - np.log(L) / 400.0
    assert np.all(dense <= grid + 1e-12)  # never less strict than the samples
    up = 1.0 - np.max(tau[Wn, 0], axis=1) / lim  # each window's true margin, upper bound
    assert np.all(dense[:len(up)] <= up + 1e-12) and np.all(dense[:len(up)] >= up - np.log(L) / 400.0)
    assert np.any(grid[:len(up)] > up + 1e-3)  # the samples alone miss steps between them
    assert terms[1].describe()["dense"] and "dense" not in terms[0].describe()
    f = lambda xx: p.evaluate(xx, p.data())["c_in"][n:]
    J = np.asarray(jax.jacfwd(f)(x))
    e = np.zeros(p.n_vars)
    e[1] = 1e-6
    fd = (np.asarray(f(x + e)) - np.asarray(f(x - e))) / 2e-6
    np.testing.assert_allclose(J[:, 1], fd, rtol=1e-5, atol=1e-8)


def test_swing_and_flight_clearance_are_soft_clearance_of_their_points():
    """`SwingClearance`: one value per geom group, `soft_clearance` of that group's columns
    minus the clearance; `FlightClearance`: ``scale`` times the same over every point."""
    rng = np.random.default_rng(1)
    ctx = SimpleNamespace(params={"c": 0.02}, problem=SimpleNamespace(env=object()))
    model, env = robots.tumbler(), Environment([ground()])
    labels = contact_labels(model, env)  # (geom, ...) per contact point
    groups = [["legs"], ["arms", "torso"]]
    cols = [[i for i, lab in enumerate(labels) if lab[0] in g] for g in groups]
    d = jnp.asarray(rng.uniform(-0.01, 0.1, size=(30, len(labels))))
    samples = dict(contact=SimpleNamespace(d=d))
    sw = SwingClearance(groups, "c")
    sw.check(SimpleNamespace(model=model, env=None))  # without env: the points against the ground
    want = [float(soft_clearance(d[:, c], 1e-3, 2e-3)) - 0.02 for c in cols]
    np.testing.assert_allclose(np.asarray(sw.values(ctx, None, samples)), want, rtol=0, atol=1e-15)
    fl = FlightClearance("c")
    np.testing.assert_allclose(np.asarray(fl.values(ctx, None, samples)),
                               [100.0 * (float(soft_clearance(d, 1e-3, 2e-3)) - 0.02)], rtol=1e-14)
    assert all(cols)  # both groups have contact points
    with pytest.raises(ProblemError, match="no contact points on geoms"):
        SwingClearance([["nope"]], "c").check(SimpleNamespace(model=model, env=env))
    with pytest.raises(ProblemError, match="no environment"):
        fl.values(SimpleNamespace(params={"c": 0.02}, problem=SimpleNamespace(env=None)), None, samples)


def test_slip_power_values():
    """`SlipPower`: ``limit - sum_k N_k sqrt(|v_t,k|^2 + v_eps^2)`` per sample (the normal
    part of the contact velocity does not count)."""
    n = jnp.tile(jnp.array([0.0, 0.0, 1.0]), (2, 3, 1))  # (S=2, k=3, 3)
    v = jnp.array([[[0.3, 0.4, 9.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]],
                   [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]])
    N = jnp.array([[10.0, 5.0, 0.0], [2.0, 0.0, 0.0]])
    c = SlipPower("lim", v_eps=1e-3)
    out = np.asarray(c.values(SimpleNamespace(params={"lim": 8.0}), None,
                              dict(contact=SimpleNamespace(velocity=v, n=n, normal_magnitude=N))))
    want = [8.0 - 10.0 * np.hypot(0.5, 1e-3) - 5.0 * 1e-3, 8.0 - 2.0 * 1e-3]
    np.testing.assert_allclose(out, want, rtol=1e-14)
    assert c.describe() == {"type": "SlipPower", "limit": "lim", "v_eps": 1e-3, "stage": 0}


def test_base_terms_on_a_planar_base():
    """`ForwardDistance`, `PitchBound` and `ScaledTorqueLimits` on the tumbler's planar
    base: distance gained along ``root_x`` (scaled), the pitch band on every sample, the
    torques over the effort limits; how DDP evaluates each (``ddp``)."""
    m = robots.tumbler()
    q0 = robots.tumbler_standing_q()
    terms = [ForwardDistance("dist"), PitchBound(0.5, center=0.1), ScaledTorqueLimits(factor="f")]
    p = MotionProblem(m, ["hip", "shoulder"], 0.2, 6, 0.01, q0, constraints=terms, n_path_samples=5,
                      params={"dist": 0.05, "f": 1.5})
    assert [t.ddp for t in terms] == ["end", "path", "box"] and AtRest.ddp == "end"
    x = jnp.asarray(p.x0) + 0.2
    r = np.asarray(p.evaluate(x, p.data())["c_in"])
    tr = p.trajectory(x, p.data())
    q, tau = np.asarray(tr["q"]), np.asarray(tr["tau"])
    rows = np.asarray(p.sample_idx)
    np.testing.assert_allclose(r[0], 10.0 * (q[-1, 0] - q[0, 0] - 0.05), rtol=1e-12, atol=1e-15)
    e = q[rows, 2] - 0.1
    np.testing.assert_allclose(r[1:1 + 2 * len(rows)], np.concatenate([0.5 - e, 0.5 + e]), rtol=1e-12)
    lim = np.asarray(m.effort_limit)[list(p.layout.va_idx)]
    ratio = tau[rows][:, list(p.layout.va_idx)] / lim
    np.testing.assert_allclose(r[1 + 2 * len(rows):], np.concatenate([(1.5 - ratio).ravel(), (1.5 + ratio).ravel()]),
                               rtol=1e-12)
    assert terms[2].describe() == {"type": "ScaledTorqueLimits", "stage": 0, "factor": "f"}


def _tumbler_problem(cons, env=True):
    m = robots.tumbler()
    q0 = robots.tumbler_standing_q(m)
    kw = dict(env=Environment([ground()]),
              contact=ContactParams(stiffness=5e3, damping=100.0, d_on=0.01, d_off=0.0, friction=0.8)) if env else {}
    return MotionProblem(m, ["hip", "shoulder"], t_final=0.2, n_ctrl=6, dt=0.01, q0=q0, constraints=cons,
                         n_path_samples=10, params={"clear": 0.01}, **kw)


def test_contact_distance_sizes_and_selection():
    labels = contact_labels(robots.tumbler(), Environment([ground()]))
    assert len(labels) == 6  # two end spheres of each of three capsules
    p = _tumbler_problem([constraints.ContactDistance("clear", window=(0.05, 0.1)),
                          constraints.ContactDistance(0.0, geoms="legs"),
                          constraints.ContactDistance(0.0, geoms=["arm*", "torso"], window=(0.2, 0.2))])
    t = p.t[p.sample_idx]
    n_win = int(np.sum((t >= 0.05 - 1e-12) & (t <= 0.1 + 1e-12)))
    assert n_win >= 2
    assert p.n_ineq == n_win * 6 + len(t) * 2 + 1 * 4
    assert p.describe()["constraints"][0] == {"type": "ContactDistance", "min_distance": "clear",
                                              "window": (0.05, 0.1), "geoms": None, "stage": 0}


def test_contact_distance_upper_bound_keeps_points_loaded():
    """``max_distance``: ``max - d`` after the lower bounds; alone without a lower bound;
    the values are exactly ``d`` of the recorded contact data."""
    import jax.numpy as jnp

    both = constraints.ContactDistance(0.0, geoms="legs", max_distance=0.008)
    upper = constraints.ContactDistance(max_distance="clear", geoms="legs")
    p = _tumbler_problem([both, upper])
    n = len(p.sample_idx) * 2  # two end spheres of the legs' capsule
    assert p.n_ineq == 2 * n + n
    assert p.describe()["constraints"][0]["max_distance"] == 0.008
    assert p.describe()["constraints"][1]["min_distance"] is None
    d = p.data()
    tr = p.trajectory(jnp.asarray(p.x0), d)
    ci = np.asarray(p.evaluate(jnp.asarray(p.x0), d)["c_in"])
    labels = contact_labels(p.model, p.env)
    legs = [i for i, lab in enumerate(labels) if lab[0] == "legs"]
    dd = np.asarray(tr["contact"].d)[p.sample_idx][:, legs].ravel()
    np.testing.assert_allclose(ci[:n], dd, atol=1e-15)
    np.testing.assert_allclose(ci[n:2 * n], 0.008 - dd, atol=1e-15)
    np.testing.assert_allclose(ci[2 * n:], 0.01 - dd, atol=1e-15)
    with pytest.raises(ProblemError, match="min_distance, max_distance or both"):
        constraints.ContactDistance()


def test_contact_distance_bad_input():
    with pytest.raises(ProblemError, match="no environment"):
        _tumbler_problem([constraints.ContactDistance(0.0)], env=False)
    with pytest.raises(ProblemError, match="window"):
        _tumbler_problem([constraints.ContactDistance(0.0, window=(0.1, 0.5))])
    with pytest.raises(ProblemError, match="window"):
        _tumbler_problem([constraints.ContactDistance(0.0, window=(0.1, 0.05))])
    with pytest.raises(ProblemError, match="no contact point of geoms"):
        _tumbler_problem([constraints.ContactDistance(0.0, geoms="head")])
    with pytest.raises(ProblemError, match="no constraint-grid sample"):
        _tumbler_problem([constraints.ContactDistance(0.0, window=(0.101, 0.109))])
