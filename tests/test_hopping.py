"""The hopping examples `hopper` and `luxo` (issue 6): registration, their stored rest
states are equilibria with the contact active, the problems build, a rollout of the
default initial guess is sane (finite, no limb through the floor), the values and
Jacobian at the guess are finite, the criteria are reported; the full solves are slow.

Each problem is built once per module (fixture) so that its trajectory and values+Jacobian
functions compile once.
"""

from __future__ import annotations

import functools
import importlib

import numpy as np
import pytest

import cstorm as cs
from cstorm.examples.hopping import flight_time
from cstorm.examples.planar import longest_run

NAMES = ("hopper", "luxo")


def _module(name):
    return importlib.import_module(f"cstorm.examples.{name}")


@functools.lru_cache(maxsize=None)
def _problem(name):
    """One problem object per example for the whole module: its compiled functions are
    kept on it, so the fixture's tests and the solves below compile them once."""
    return cs.examples.get(name)()


@pytest.fixture(scope="module", params=NAMES)
def problem(request):
    return _problem(request.param)


def test_registered():
    for n in NAMES:
        assert n in cs.examples.names()
        assert cs.examples.get(n) is getattr(cs.examples, n)


def test_problem_structure(problem):
    m = _module(problem.name)
    assert problem.model.joint_names[:3] == ("root_x", "root_z", "root_pitch")
    assert problem.active == m.ACTIVE
    assert callable(problem.success_criteria)
    # the plan ends with the real problem: every constraint level, the full distance, the
    # motor limits unrelaxed on every step
    sched = problem.solve_options["schedule"]
    assert sched[-1]["level"] == problem.n_levels - 1
    assert sched[-1]["params"]["distance"] == pytest.approx(problem.params["distance"])
    assert sched[-1]["params"]["tau_factor"] == 1.0
    assert any(c.describe().get("dense") for c in problem.constraints)
    q0 = np.asarray(problem.q0)
    assert q0[1] == pytest.approx(m.REST_Z) and q0[2] == pytest.approx(m.REST_PITCH)


def test_guess_rollout_is_sane(problem):
    """The default initial guess starts at rest in the contact equilibrium (the base does
    not move before the legs do), stays finite and keeps every contact point within 1 cm
    of the ground surface (no limb through the floor). With multiple shooting: as
    `cs.solve` starts it, the nodes on the guess's own rollout (`shoot_nodes`)."""
    x0 = problem.x0 if problem.shooting == 1 else problem.shoot_nodes(problem.x0, problem.data())
    tr = problem.compiled("trajectory")(x0, problem.data())
    q, v = np.asarray(tr["q"]), np.asarray(tr["v"])
    d = np.asarray(tr["contact"].d)
    assert not bool(tr["diverged"])
    assert np.all(np.isfinite(q)) and np.all(np.isfinite(v))
    # rest_start (zero initial joint acceleration) from the stored equilibrium: the base
    # does not accelerate at t = 0
    assert np.max(np.abs(np.asarray(tr["a"])[0, :3])) < 1e-8
    assert np.min(d) > -0.01
    # the rest state: every contact force balances gravity
    N = np.asarray(tr["contact"].normal_magnitude)[0]
    weight = float(np.sum(np.asarray(problem.model.mass))) * 9.81
    assert np.sum(N) == pytest.approx(weight, rel=1e-6)


def test_values_and_jacobian_finite(problem):
    f, ce, ci, div, g, Je, Ji = problem.compiled("fun_jac")(problem.x0, problem.data())
    assert not bool(div)
    for a in (f, ce, ci, g, Je, Ji):
        assert np.all(np.isfinite(np.asarray(a)))
    assert np.asarray(Ji).shape == (problem.n_ineq, problem.n_vars)
    assert np.linalg.norm(np.asarray(g)) > 0


def test_flight_time_and_longest_run():
    t = np.linspace(0.0, 1.0, 11)
    flag = np.array([0, 1, 1, 1, 0, 0, 1, 1, 0, 0, 0], bool)
    assert longest_run(t, flag) == pytest.approx((0.3, 0.2))
    d = np.where(flag[:, None], 0.05, 0.0) * np.ones((11, 3))
    assert flight_time(t, d, 0.01) == pytest.approx((0.3, 0.2))


def _solve_and_check(name):
    from cstorm import report

    p = _problem(name)
    sol = cs.solve(p)
    assert sol.success, sol.message
    crit = p.success_criteria(sol)
    assert all(c["ok"] for c in crit.values()), crit
    fid = report.fidelity(p, sol)
    assert fid["ok"], fid["flags"]
    return p, sol, fid


def test_luxo_solves_lands_at_rest_and_is_resolved_by_its_step():
    """`cstorm solve luxo` (in CI): the solve plan converges from
    the default guess, every success criterion holds (0.16 m forward, a flight, landing at
    rest: base speed <= 1e-3, acceleration <= 1e-2), and the landing's rest is the
    dynamics', not the integrator's: re-simulated at dt/4 and with DOP853 the final
    velocities agree with the plan to < 1e-2 m/s and < 1 deg/s (a step past RK4's
    stability limit gives 0.024 m/s and 14 deg/s), and dt is inside RK4's stability
    limit along the solution. The
    criteria include the motor limits on every step (``torque_limits``; the dense
    constraint's stages), which `report.torque_check` confirms independently."""
    from cstorm import report

    p, sol, fid = _solve_and_check("luxo")
    assert "torque_limits" in p.success_criteria(sol)
    tq = report.torque_check(p, sol)
    assert tq["ok"], tq["message"]
    assert fid["velocity_m_s"] < 1e-2 and fid["angular_velocity_deg_s"] < 1.0, fid
    ts = cs.check_time_step(p, along=sol)
    assert ts["ok"], ts["message"]


def test_hopper_fast_variant_hops_and_lands():
    """CI's variant of `cstorm solve hopper` (`hopper.fast_variant`: the plan's first
    stages, a short hop, then a polish at tolerance 1e-6), on the module's hopper problem
    (its compiled functions are shared): from the default posture guess the hopper leaves
    the ground (a flight of >= 0.05 s), lands at least 0.05 m ahead and ends nearly at
    rest, no foot through the floor, every constraint of the stage met to 1e-6. The full
    plan is the slow test below."""
    base = _problem("hopper")
    p = _module("hopper").fast_variant(base)
    assert p.compiled("fun_jac") is base.compiled("fun_jac") and base.solve_options["schedule"] != p.solve_options["schedule"]
    sol = cs.solve(p)
    assert sol.success, sol.message
    crit = p.success_criteria(sol)
    assert {"forward_distance", "flight_time", "final_base_speed", "max_penetration"} <= set(crit)
    assert all(c["ok"] for c in crit.values()), crit


@pytest.mark.slow
def test_hopper_full_solve_meets_criteria():
    """`cstorm solve hopper`: the solve plan converges from the default guess and every
    success criterion (the hold test and the motor limits on every step included) and
    the fidelity check hold."""
    p, sol, fid = _solve_and_check("hopper")
    crit = p.success_criteria(sol)
    assert {"holds_still_pitch", "holds_still_position", "still_after_hold", "torque_limits"} <= set(crit)


def test_hold_test_at_the_standing_rest(problem):
    """`planar.hold_test` from the stored standing equilibrium at rest: the base does not
    move (< 1e-6 rad, m) and stays still."""
    from types import SimpleNamespace

    from cstorm.examples.planar import hold_test

    q0 = np.asarray(problem.q0)
    sol = SimpleNamespace(trajectory=dict(q=q0[None], v=np.zeros((1, problem.model.nv))))
    dev, pos, vend = hold_test(problem, sol, 0.5)
    assert dev < 1e-6 and pos < 1e-6 and vend < 1e-6, (dev, pos, vend)
