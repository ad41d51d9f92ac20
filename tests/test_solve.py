"""The solver front end (`cstorm.optimize.solve`) on the acrobot: the swing-up solved to
upright (SLSQP, IPOPT, trust-constr), Ctrl-C returning the best iterate, per-stage
schedules, a diverged final iterate, failed stages refined through midpoints, checkpoint
and resume; and the auto objective scale, which needs no compiled problem.

The acrobot problem and its SLSQP solution are the fixtures ``acrobot_problem`` and
``acrobot_solution`` (tests/conftest.py), built once per test process, so its functions
compile once.
"""

from __future__ import annotations

import importlib

import numpy as np
import pytest

import cstorm as cs
from cstorm import examples
from cstorm.errors import InputError
from cstorm.optimize import solve
from cstorm.optimize.solve import resolve_objective_scale


@pytest.fixture
def problem(acrobot_problem):
    return acrobot_problem


@pytest.fixture
def solution(acrobot_solution):
    return acrobot_solution


def test_acrobot_swing_up_reaches_upright(problem, solution):
    s = solution
    assert s.success and s.status is cs.Status.SOLVED, s.message
    qT, vT = s.trajectory["q"][-1], s.trajectory["v"][-1]
    assert abs(qT[0] - np.pi) < 1e-3 and abs(vT[0]) < 1e-3, (qT, vT)  # shoulder upright, at rest
    assert abs(qT[1]) < 1e-9 and abs(vT[1]) < 1e-9  # elbow: by construction
    assert s.constraint_violation < 1e-6
    assert s.trajectory["q"].shape == (problem.n_steps + 1, 2) and s.trajectory["t"][-1] == pytest.approx(3.0)
    # the reported cost is the integral of tau^2 / 2 (trapezoid check on the grid)
    tau = s.trajectory["tau"][:, 1]
    trap = np.trapezoid(0.5 * tau**2, s.trajectory["t"])
    assert s.cost == pytest.approx(trap, rel=1e-2)
    assert len(s.history) == s.iterations and s.history[-1]["iteration"] == s.iterations
    assert len(s.segments) == 1 and s.segments[0].cost == s.cost


def test_keyboard_interrupt_returns_best_iterate(problem):
    seen = []

    def cb(info):
        seen.append(info)
        if info["iteration"] == 6:
            raise KeyboardInterrupt

    s = solve(problem, callback=cb, max_iter=300)
    assert not s.success and s.status is cs.Status.INTERRUPTED and "interrupted" in s.message
    assert s.iterations == 6 and len(s.history) == 6
    # the best iterate of the interrupted stage: least violation (or lowest feasible cost)
    stage = seen[-1]["stage"]
    in_stage = [h for h in s.history if h["stage"] == stage]
    tol = 1e-6
    feas = [h for h in in_stage if h["violation"] <= tol]
    best = min(feas, key=lambda h: h["cost"]) if feas else min(in_stage, key=lambda h: h["violation"])
    assert s.constraint_violation == pytest.approx(best["violation"], rel=1e-9, abs=1e-12)
    assert np.isfinite(s.cost) and s.trajectory["q"].shape[0] == problem.n_steps + 1


def test_schedule_stage_own_tol_and_max_iter(problem):
    """A schedule stage's ``max_iter`` and ``tol`` replace the solve's (and the
    intermediate ones) for that stage only; unknown stage keys are an error."""
    sched = [dict(params={}, level=0, max_iter=3), dict(params={}, level=0, max_iter=2, tol=1e-3)]
    s = solve(problem, schedule=sched, max_iter=300)
    per_stage = [len([h for h in s.history if h["stage"] == k]) for k in (0, 1)]
    assert per_stage[0] <= 3 and per_stage[1] <= 2, per_stage
    assert [st["iterations"] for st in s.info["stages"]] == per_stage
    # every stage's evaluations are counted: its start, and each iterate that moved
    moved = sum(1 for h in s.history if h["step"] > 0)
    assert s.n_evaluations >= len(per_stage) + moved, (s.n_evaluations, per_stage, moved)
    with pytest.raises(InputError, match="unknown keys"):
        solve(problem, schedule=[dict(params={}, level=0, maxiter=3)])


def test_diverged_final_iterate_keeps_the_last_sound_stage(problem, monkeypatch):
    """When the solver ends a stage where the rollout diverges, `solve` does not raise
    and lose the work: it returns the last stage end whose rollout did not diverge,
    unsuccessful, and says where the final iterate diverged."""
    S = importlib.import_module("cstorm.optimize.solve")  # (cstorm.optimize.solve is the function)
    real = S.run_slsqp
    calls = []

    def run(ev, x, tracker, si, params, it, tol, options):
        calls.append(si)
        x, ok, msg, nit = real(ev, x, tracker, si, params, 3, tol, options)
        if si == 1:  # the second stage "wanders off" to control points that blow up
            x = x + 1e4
        return x, ok, msg, nit

    monkeypatch.setattr(S, "run_slsqp", run)
    s = solve(problem, schedule=[dict(params={}, level=0), dict(params={}, level=0)], max_iter=300)
    assert calls == [0, 1]
    assert not s.success and s.status is cs.Status.DIVERGED
    assert "diverged" in s.message and "end of stage 0" in s.message, s.message
    assert not bool(s.trajectory.get("diverged", False))
    assert np.all(np.isfinite(s.trajectory["q"])) and np.max(np.abs(s.x)) < 1e3


def test_failed_stage_is_refined_through_midpoints(problem, monkeypatch):
    """With ``solve_options["refine"]``, a stage that fails is run again from where it
    started after a stage halfway there (geometric mean of the targets), recursively up
    to the given depth. Here the solver "fails" every stage whose target jumps by more
    than pi/3 over the last one reached: pi/4 -> pi needs two halvings (pi/2, then
    pi/sqrt(2))."""
    S = importlib.import_module("cstorm.optimize.solve")
    real = S.run_slsqp
    reached = []

    def run(ev, x, tracker, si, params, it, tol, options):
        t = float(params["target"])
        if reached and t - reached[-1] > np.pi / 3 + 1e-9:
            return x, False, "SLSQP: (test) too far", 0  # unmoved: violates the new target
        out = real(ev, x, tracker, si, params, it, tol, options)
        reached.append(t)
        return out

    monkeypatch.setattr(S, "run_slsqp", run)
    monkeypatch.setitem(problem.solve_options, "refine", 2)
    s = solve(problem, continuation={"target": [np.pi / 4, np.pi]}, max_iter=300)
    assert s.success, s.message
    np.testing.assert_allclose(reached, [np.pi / 4, np.pi / 2, np.pi / np.sqrt(2), np.pi], rtol=1e-12)
    st = s.info["stages"]
    assert [r["stage"] for r in st] == [0, 1, 1, 1, 1, 1]
    assert [bool(r.get("refined")) for r in st] == [False, True, False, True, False, False]
    assert [r.get("refinement_depth", 0) for r in st] == [0, 0, 1, 1, 2, 2]
    assert abs(s.trajectory["q"][-1][0] - np.pi) < 1e-3
    # without refinement the same solve fails at the jump
    monkeypatch.setitem(problem.solve_options, "refine", 0)
    reached.clear()
    s0 = solve(problem, continuation={"target": [np.pi / 4, np.pi]}, max_iter=300)
    assert not s0.success and "too far" in s0.message


def test_checkpoint_and_resume(problem, solution, tmp_path):
    ck = tmp_path / "ck.npz"

    def stop(info):
        if info["iteration"] == 25:
            raise KeyboardInterrupt

    s1 = solve(problem, checkpoint=str(ck), callback=stop, max_iter=300)
    assert s1.status is cs.Status.INTERRUPTED and ck.exists()
    with np.load(ck, allow_pickle=False) as z:
        assert int(z["iteration"]) == 25
        stage = int(z["stage"])
    s2 = solve(problem, resume=str(ck), max_iter=300)
    assert s2.success, s2.message
    assert s2.history[0]["iteration"] == 26 and s2.history[0]["stage"] == stage
    assert abs(s2.trajectory["q"][-1][0] - np.pi) < 1e-3
    # a checkpoint of another problem is refused
    other = examples.get("acrobot")(t_final=3.0, n_ctrl=15, dt=0.02)
    with pytest.raises(cs.InputError, match="another problem"):
        solve(other, resume=str(ck))


def test_ipopt_swing_up(problem):
    pytest.importorskip("casadi")
    s = solve(problem, method="ipopt", max_iter=500)
    assert s.success, s.message
    qT, vT = s.trajectory["q"][-1], s.trajectory["v"][-1]
    assert abs(qT[0] - np.pi) < 1e-3 and abs(vT[0]) < 1e-3
    # measured: IPOPT (L-BFGS Hessian) finds a cheaper swing-up than SLSQP here (41.5 vs 154)
    assert s.cost < 200.0 and s.info["method"] == "ipopt"


def test_trust_constr_swing_up(problem):
    """scipy's trust-region SQP reaches the same swing-up as SLSQP (measured: cost
    154.285 vs SLSQP's 154.29, violation 2e-15, 391 iterations vs 202)."""
    s = solve(problem, method="trust-constr", max_iter=500)
    assert s.success, s.message
    qT, vT = s.trajectory["q"][-1], s.trajectory["v"][-1]
    assert abs(qT[0] - np.pi) < 1e-6 and abs(vT[0]) < 1e-6
    assert s.info["method"] == "trust-constr" and s.cost == pytest.approx(154.29, rel=1e-3)
    with pytest.raises(cs.InputError, match="method must be one of"):
        solve(problem, method="newton")


def test_first_step_scales_the_auto_objective_scale():
    """``solve_options["first_step"]`` (used by the hopping problems) scales SLSQP's
    first step: the auto objective scale is ``first_step / |grad f|_inf``; None is 1, a
    number is itself, anything else is refused."""

    class Ev:
        def at(self, x):
            return (0.0, None, None, False, np.array([0.5, -4.0]))

    assert resolve_objective_scale("auto", Ev(), None) == pytest.approx(0.25)
    assert resolve_objective_scale("auto", Ev(), None, 0.1) == pytest.approx(0.025)
    assert resolve_objective_scale(None, Ev(), None, 0.1) == 1.0
    assert resolve_objective_scale(3.0, Ev(), None) == 3.0
    with pytest.raises(InputError, match="objective_scale"):
        resolve_objective_scale(-1.0, Ev(), None)
