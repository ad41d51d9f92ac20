"""The walker example and the periodic-motion machinery it needs.

- the walker model against Gymnasium's ``walker2d.xml`` in MuJoCo (mass matrix, bias and
  passive forces at random states) and against ``cs.load_mjcf`` of the same file;
- ``MotionProblem(free_initial=...)``, `constraints.Periodic` and
  `constraints.AverageSpeed` on a tiny acrobot problem: layout of ``x``, the start state
  the rollout uses, constraint values, exact gradients vs central differences,
  validation;
- a short walker variant with contact: exact gradients vs central differences and the
  problem's structure; the full gait-cycle solve is marked slow.
"""

from __future__ import annotations

import importlib
import os

import numpy as np
import pytest
import jax.numpy as jnp

import cstorm as cs
from cstorm.errors import ProblemError
from cstorm.examples.acrobot import acrobot_model
from cstorm.optimize import MotionProblem, MotionSequence, check_gradients, constraints, costs

W = importlib.import_module("cstorm.examples.walker")


def _walker2d_xml():
    gym = pytest.importorskip("gymnasium")
    path = os.path.join(os.path.dirname(gym.__file__), "envs", "mujoco", "assets", "walker2d.xml")
    if not os.path.exists(path):
        pytest.skip("gymnasium's walker2d.xml is not installed")
    return path


# ---------------------------------------------------------------------------------------
# the model
# ---------------------------------------------------------------------------------------
def test_walker_model_matches_mujoco():
    mujoco = pytest.importorskip("mujoco")
    xml = _walker2d_xml()
    m = mujoco.MjModel.from_xml_path(xml)
    d = mujoco.MjData(m)
    ours = W.walker_model(hip_upper=0.0)  # Gymnasium's hip range
    loaded = cs.load_mjcf(xml)
    assert ours.nq == ours.nv == m.nv == 9
    assert float(np.sum(np.asarray(ours.mass))) == pytest.approx(float(np.sum(m.body_mass)), rel=1e-12)
    # same joint order as MuJoCo: root x, z, pitch, then right hip/knee/ankle, left
    assert ours.joint_names == ("root_x", "root_z", "root_pitch") + W.ACTIVE
    np.testing.assert_allclose(np.asarray(ours.q_lower)[3:], m.jnt_range[3:, 0], atol=1e-12)
    np.testing.assert_allclose(np.asarray(ours.q_upper)[3:], m.jnt_range[3:, 1], atol=1e-12)
    np.testing.assert_allclose(np.asarray(ours.effort_limit)[3:], 100.0)
    rng = np.random.default_rng(0)
    for _ in range(4):
        q = rng.uniform(-1.0, 1.0, 9)
        q[1] += 1.25
        v = rng.normal(size=9)
        d.qpos[:], d.qvel[:] = q, v
        mujoco.mj_forward(m, d)
        M = np.zeros((9, 9))
        mujoco.mj_fullM(m, d, M)
        Mo = np.asarray(cs.mass_matrix(ours, jnp.asarray(q)))
        bo = np.asarray(cs.bias_forces(ours, jnp.asarray(q), jnp.asarray(v)))
        po = np.asarray(cs.passive_forces(ours, jnp.asarray(q), jnp.asarray(v)))
        np.testing.assert_allclose(Mo, M, atol=1e-12 * max(1.0, np.abs(M).max()))
        np.testing.assert_allclose(bo, d.qfrc_bias, atol=1e-11 * max(1.0, np.abs(d.qfrc_bias).max()))
        np.testing.assert_allclose(po, d.qfrc_passive, atol=1e-12)
        # and the MJCF loader's model of the same file
        np.testing.assert_allclose(np.asarray(cs.mass_matrix(loaded, jnp.asarray(q))), Mo, atol=1e-12)


def test_walker_model_structure():
    m = W.walker_model()
    q = np.zeros(9)
    q[1] = 1.25
    # symmetric legs: at q = 0 the CoM lies on the torso axis, total mass as documented
    com = np.asarray(cs.center_of_mass(m, jnp.asarray(q)))
    assert float(np.sum(np.asarray(m.mass))) == pytest.approx(23.677, abs=1e-3)
    assert abs(com[1]) < 1e-12
    # the feet stick out forward (toes at +x) so the CoM is slightly ahead of the torso axis
    assert 0.0 < com[0] < 0.05
    # left/right legs are mirror images: swapping them leaves M unchanged
    rng = np.random.default_rng(1)
    qa = rng.uniform(-0.5, 0.5, 9)
    qb = qa.copy()
    qb[3:6], qb[6:9] = qa[6:9], qa[3:6]
    P = np.eye(9)[[0, 1, 2, 6, 7, 8, 3, 4, 5]]
    Ma, Mb = (np.asarray(cs.mass_matrix(m, jnp.asarray(x))) for x in (qa, qb))
    np.testing.assert_allclose(P @ Ma @ P.T, Mb, atol=1e-12)
    # Gymnasium's hip range by default; the walking problem widens the upper limit
    assert np.asarray(m.q_upper)[3] == 0.0
    assert np.asarray(W.walker_model(hip_upper=np.radians(60.0)).q_upper)[[3, 6]] == pytest.approx(np.radians(60.0))
    # the guess posture: feet level, 6 mm above the ground
    qp = W.posture()
    T = np.asarray(cs.forward_kinematics(m, jnp.asarray(qp)))
    for s in ("r", "l"):
        Rf = T[m.body_names.index(f"foot_{s}")][:3, :3]
        assert abs(Rf[2, 0]) < 1e-12  # the foot's x axis is horizontal
    d = cs.contact_forces(m, cs.Environment([cs.ground()], pairs=[("foot_*", "ground")]), W.walker_contact(),
                          jnp.asarray(qp), jnp.zeros(9)).d
    assert float(np.min(np.asarray(d))) == pytest.approx(0.006, abs=1e-9)


# ---------------------------------------------------------------------------------------
# free initial state, Periodic, AverageSpeed on a tiny problem
# ---------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def tiny():
    model = acrobot_model()
    return MotionProblem(
        model, active=["elbow"], t_final=1.0, n_ctrl=7, dt=0.05, q0=np.array([0.3, -0.2]),
        v0=np.array([0.1, 0.5]), costs=[costs.TorqueSquared()],
        constraints=[constraints.Periodic(), constraints.Periodic(exclude="shoulder"),
                     constraints.Periodic(exclude="shoulder", exclude_velocity="shoulder", which="v"),
                     constraints.AverageSpeed("w", joint="shoulder", kind="ineq")],
        params={"w": 0.1}, free_initial={"shoulder": "qv", "elbow": "qv"}, name="tiny")


def test_free_initial_layout_and_start_state(tiny):
    p = tiny
    assert p.n_spline_vars == 5 and p.n_vars == 5 + 4  # 7 ctrl - q0, v0 fixed; dq0 (2), dv0 (2)
    assert np.all(p.x0[5:] == 0.0)
    x = p.x0.copy()
    x[5:] = [0.1, -0.05, 0.2, -0.3]  # dq(shoulder, elbow), dv(shoulder, elbow)
    data = p.data()
    q0, v0 = p.initial_state(jnp.asarray(x), data)
    np.testing.assert_allclose(np.asarray(q0), [0.4, -0.25])
    np.testing.assert_allclose(np.asarray(v0), [0.3, 0.2])
    tr = p.trajectory(jnp.asarray(x), data)
    # the rollout starts from the offset state; the active spline starts there too
    np.testing.assert_allclose(np.asarray(tr["q"][0]), [0.4, -0.25], atol=1e-12)
    np.testing.assert_allclose(np.asarray(tr["v"][0]), [0.3, 0.2], atol=1e-12)
    r = p.evaluate(jnp.asarray(x), data)
    qT, vT = np.asarray(tr["q"][-1]), np.asarray(tr["v"][-1])
    # Periodic(): q, v of both; exclude="shoulder": q elbow, v of both (an excluded
    # position's velocity stays periodic); which="v" without the shoulder: v elbow
    expect_eq = np.concatenate([qT - [0.4, -0.25], vT - [0.3, 0.2], [qT[1] + 0.25], vT - [0.3, 0.2], [vT[1] - 0.2]])
    np.testing.assert_allclose(np.asarray(r["c_eq"]), expect_eq, atol=1e-12)
    np.testing.assert_allclose(np.asarray(r["c_in"]), [(qT[0] - 0.4) / 1.0 - 0.1], atol=1e-12)
    assert p.describe()["free_initial"] == {"shoulder": "qv", "elbow": "qv"}


def test_free_initial_gradients_match_central_differences(tiny):
    # eps 1e-4: some exact entries are 0 (e.g. d v_elbow(T)-v_elbow(0) / d dq0_elbow) and the
    # metric's floor is 1e-6 x the row's scale; at eps 1e-6 the FD round-off there (1e-10)
    # (one ulp / 2 eps) reads as 1e-5 "relative" error, at 1e-5 still 1e-6. Measured: ~1e-8.
    rep = check_gradients(tiny, eps=1e-4, perturbation=0.1)
    assert rep["max_rel_error"] < 1e-6, rep["points"]


def test_free_initial_on_a_free_joint():
    b = cs.ModelBuilder("flyer")
    b.add_link("base", mass=1.0, inertia=(0.1, 0.1, 0.1))
    b.add_link("arm", mass=0.5, com=(0.0, 0.0, -0.2), inertia=(0.01, 0.01, 0.001))
    b.add_joint("j", "revolute", "base", "arm", axis=(0.0, 1.0, 0.0))
    model = b.build(floating_base="free")
    q0 = np.array([0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.2])
    p = MotionProblem(model, active=["j"], t_final=0.2, n_ctrl=6, dt=0.05, q0=q0,
                      free_initial={"root": "q", "j": "v"})
    assert p.n_vars == p.n_spline_vars + 6 + 1
    x = p.x0.copy()
    dq = np.array([0.1, -0.2, 0.3, 0.01, 0.02, -0.03])
    x[p.n_spline_vars: p.n_spline_vars + 6] = dq
    x[-1] = 0.7
    q, v = p.initial_state(jnp.asarray(x), p.data())
    expect = np.asarray(cs.integrate(model, jnp.asarray(q0), jnp.asarray(np.concatenate([dq, [0.0]]))))
    np.testing.assert_allclose(np.asarray(q), expect, atol=1e-14)  # on the manifold
    np.testing.assert_allclose(np.asarray(v), [0, 0, 0, 0, 0, 0, 0.7], atol=0)


def test_periodic_swap_values():
    model = acrobot_model()
    p = MotionProblem(model, active=["elbow"], t_final=0.2, n_ctrl=6, dt=0.05, q0=np.array([0.3, -0.2]),
                      constraints=[constraints.Periodic(swap=[("shoulder", "elbow")])])
    tr = p.trajectory(jnp.asarray(p.x0), p.data())
    r = p.evaluate(jnp.asarray(p.x0), p.data())
    q, v = np.asarray(tr["q"]), np.asarray(tr["v"])
    np.testing.assert_allclose(np.asarray(r["c_eq"]), [q[-1, 0] - q[0, 1], q[-1, 1] - q[0, 0],
                                                        v[-1, 0] - v[0, 1], v[-1, 1] - v[0, 0]], atol=1e-12)


def test_free_initial_validation():
    model = acrobot_model()
    kw = dict(active=["elbow"], t_final=0.2, n_ctrl=6, dt=0.05, q0=np.zeros(2))
    with pytest.raises(ProblemError, match="not a joint"):
        MotionProblem(model, **kw, free_initial={"hip": "q"})
    with pytest.raises(ProblemError, match="'q', 'v' or 'qv'"):
        MotionProblem(model, **kw, free_initial={"elbow": "a"})
    with pytest.raises(ProblemError, match="must be a dict"):
        MotionProblem(model, **kw, free_initial=["elbow"])
    with pytest.raises(ProblemError, match="rest_start"):
        MotionProblem(model, **kw, rest_start=True, free_initial={"elbow": "v"})
    with pytest.raises(ProblemError, match="not a joint"):
        MotionProblem(model, **kw, constraints=[constraints.Periodic(exclude=("nope",))])
    with pytest.raises(ProblemError, match="more than one swap pair"):
        MotionProblem(model, **kw, constraints=[constraints.Periodic(swap=[("shoulder", "elbow"),
                                                                             ("elbow", "shoulder")])])
    with pytest.raises(ProblemError, match="every joint is excluded"):
        MotionProblem(model, **kw, constraints=[constraints.Periodic(exclude=("shoulder", "elbow"), which="q")])
    with pytest.raises(ProblemError, match="not 1-DoF|no joint"):
        MotionProblem(model, **kw, constraints=[constraints.AverageSpeed(1.0, joint="x")])
    a = MotionProblem(model, **kw)
    b = MotionProblem(model, **kw, free_initial={"shoulder": "q"})
    with pytest.raises(ProblemError, match="segment 1 has free_initial"):
        MotionSequence([a, b])
    MotionSequence([b, a])  # the first segment may have a free start


# ---------------------------------------------------------------------------------------
# the walking problem's structure (no solve)
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("shooting", [1, 4])
def test_walker_problem_structure(shooting):
    p = W.walker(shooting=shooting)
    lb, ub = p.x_bounds
    assert lb.shape == ub.shape == (p.n_vars,)
    assert np.all(lb <= p.x0) and np.all(p.x0 <= ub)
    g = p.variable_groups()
    assert len(g["spline"]) + len(g["initial_q"]) + len(g["initial_v"]) + len(g["node_q"]) + len(g["node_v"]) \
        == p.n_vars
    assert p.shooting == shooting and len(g["node_q"]) == 3 * (shooting - 1)
    if shooting > 1:
        # the node guess: the guess posture carried forward at the average speed
        q, v = p.node_guess(0.3)
        assert q[0] == pytest.approx(0.3 * p.params["speed"]) and v[0] == pytest.approx(p.params["speed"])
        np.testing.assert_allclose(q[1:], W.posture(split=W.SPLIT)[1:])
    assert "continuation" in p.solve_options


def test_walker_fast_variant_walks_one_periodic_step():
    """CI's variant of `cstorm solve walker` (`walker.fast_variant`: 0.4 m/s, 7 control
    points, no speed ramp): from the default posture guess, a periodic step at the
    average speed with each foot swinging clear of the ground, no foot through the floor,
    every constraint met. The full plan is the slow test below."""
    p = W.fast_variant()
    sol = cs.solve(p)
    assert sol.success, sol.message
    crit = p.success_criteria(sol)
    assert {"periodicity", "average_speed_error", "swing_time_r", "swing_time_l"} <= set(crit)
    assert all(c["ok"] for c in crit.values()), crit


@pytest.mark.slow
def test_walker_solve_meets_criteria():
    """The shipped plan (multiple shooting, speed ramp, swing clearance last) from the
    default posture guess: solved, every success criterion and the fidelity check hold
    (measured 412 iterations, ~11 min incl. compile on 2 loaded cores)."""
    from cstorm import report

    p = cs.examples.get("walker")()
    sol = cs.solve(p)
    assert sol.success, sol.message
    crit, _ = report.all_criteria(p, sol)
    assert all(c["ok"] for c in crit.values()), crit
    fid = report.fidelity(p, sol)
    assert fid["ok"], fid["flags"]
