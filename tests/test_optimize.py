"""Motion optimization on the acrobot: exact gradients vs central differences, a fast
swing-up solve reaching upright, solution save/load, Ctrl-C returning the best iterate,
checkpoint + resume, sequences, float64 guard.

One problem object (module fixture) is shared by every test, so its values+Jacobian
function compiles once (its trajectory function once more).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import jax

import cstorm as cs
from cstorm import examples
from cstorm.examples.acrobot import acrobot_model
from cstorm.errors import ProblemError
from cstorm.optimize import MotionProblem, MotionSequence, check_gradients, load_solution, solve, costs, constraints

FAST = dict(t_final=3.0, n_ctrl=16, dt=0.02)


@pytest.fixture(scope="module")
def problem():
    return examples.get("acrobot")(**FAST)


@pytest.fixture(scope="module")
def solution(problem):
    return solve(problem, max_iter=300)


def test_registry():
    assert "acrobot" in examples.names()
    assert examples.get("acrobot") is examples.acrobot
    with pytest.raises(cs.InputError, match="unknown example"):
        examples.get("nope")


def test_gradients_match_central_differences(problem):
    rep = check_gradients(problem)
    # measured: ~1e-9 .. 1e-8 at the initial guess and at a random nearby point
    assert rep["max_rel_error"] < 1e-6, rep["points"]
    assert len(rep["points"]) == 2 and rep["points"][0]["n_outputs"] == 1 + problem.n_eq + problem.n_ineq


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


def test_solution_save_load_round_trip(solution, tmp_path):
    p = solution.save(tmp_path / "sol")
    assert p.endswith(".npz")
    with np.load(p, allow_pickle=False) as z:  # no pickled objects inside
        meta = json.loads(str(z["meta_json"]))
    assert meta["format"] == "cstorm-solution-1"
    s2 = load_solution(p)
    for k in ("success", "message", "cost", "constraint_violation", "iterations", "problem"):
        assert getattr(s2, k) == getattr(solution, k)
    np.testing.assert_array_equal(s2.x, solution.x)
    for k in ("t", "q", "v", "a", "tau", "ctrl"):
        np.testing.assert_array_equal(s2.trajectory[k], solution.trajectory[k])
    assert s2.history == solution.history
    assert len(s2.segments) == 1 and s2.segments[0].cost == solution.cost
    assert not list(tmp_path.glob(".tmp-*"))  # atomic write left no temporary


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
    from cstorm.errors import InputError

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
    import importlib

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
    import importlib

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


def test_sequence_segments_chain(problem, solution):
    seq = MotionSequence([problem, problem], name="twice")
    s = solve(seq, max_iter=2, continuation={"target": [np.pi]})
    assert len(s.segments) == 2
    end0 = s.segments[0].trajectory
    np.testing.assert_allclose(s.segments[1].trajectory["q"][0], end0["q"][-1], atol=1e-12)
    np.testing.assert_allclose(s.segments[1].trajectory["v"][0], end0["v"][-1], atol=1e-12)
    assert s.trajectory["t"][-1] == pytest.approx(6.0)
    assert s.trajectory["q"].shape[0] == 2 * problem.n_steps + 1


def test_sequence_compiles_later_segments_in_the_background(problem):
    """A sequence builds its later segments' compiled functions in a background thread
    while the first one solves; the solve then finds them compiled for the very
    arguments it calls them with (one compiled signature each, none made twice)."""
    other = examples.get("acrobot")(t_final=3.0, n_ctrl=14, dt=0.02)
    s = solve(MotionSequence([problem, other]), max_iter=2, continuation={"target": [np.pi]})
    assert len(s.segments) == 2
    assert {k: other.compiled(k)._cache_size() for k in ("fun_jac", "trajectory")} == {"fun_jac": 1, "trajectory": 1}


def test_problem_validation():
    m = acrobot_model()
    with pytest.raises(ProblemError, match="no joint named"):
        MotionProblem(m, ["wrist"], 1.0, 8, 0.1, np.zeros(2))
    with pytest.raises(ProblemError, match="unknown problem parameter"):
        MotionProblem(m, ["elbow"], 1.0, 8, 0.1, np.zeros(2),
                      constraints=[constraints.TerminalState("shoulder", q="nope")])


def test_float64_required():
    jax.config.update("jax_enable_x64", False)
    try:
        with pytest.raises(ProblemError, match="jax_enable_x64"):
            MotionProblem(acrobot_model(), ["elbow"], 1.0, 8, 0.1, np.zeros(2))
    finally:
        jax.config.update("jax_enable_x64", True)


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


def test_evaluate_records_the_constraint_grid_only():
    """`MotionProblem.evaluate` records the trajectory on the constraint grid only when no
    constraint reads every step (with ``derivatives="parallel"`` only those points'
    Jacobians are evaluated): values and Jacobians equal those of the full recording; a
    dense torque limit keeps the full recording; a term that reads ``samples["steps"]``
    without declaring ``uses_steps`` gets an error that says so."""
    import jax.numpy as jnp
    m = acrobot_model()

    class Steps(constraints.Constraint):
        kind = "ineq"

        def values(self, ctx, end, samples):
            return 3.0 - jnp.abs(samples["steps"]["tau"][:, 1])

    def make(terms):
        return MotionProblem(m, ["elbow"], 0.6, 6, 0.01, np.array([0.3, 0.2]), constraints=terms, n_path_samples=5,
                             derivatives="parallel")

    p = make([constraints.TorqueLimits(limits=2.0, normalized=True), constraints.TerminalState("shoulder", v=0.0)])
    assert p.recorded_rows() == tuple(int(i) for i in p.sample_idx)
    assert make([constraints.TorqueLimits(limits=2.0, dense=True)]).recorded_rows() is None
    p.derivatives = "analytic"  # the other modes differentiate every step: they record all
    assert p.recorded_rows() is None
    p.derivatives = "parallel"
    x = jnp.asarray(p.x0) + jnp.linspace(-0.4, 0.5, p.n_vars)
    grid = p.fun_jac(x, p.data())
    p.record_grid_only = False
    assert p.recorded_rows() is None
    full = p.fun_jac(x, p.data())
    p.record_grid_only = True
    for a, b in zip(grid, full):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-14)
    with pytest.raises(ProblemError, match="uses_steps"):
        make([Steps()]).evaluate(x, p.data())
    Steps.uses_steps = True
    r = make([Steps()]).evaluate(x, p.data())
    assert r["c_in"].shape == (p.n_steps + 1,)
