"""`MotionProblem` (`cstorm.optimize.problem`) on the acrobot: argument validation, the
float64 guard, exact gradients against central differences (`check_gradients`), and the
trajectory recorded on the constraint grid only.

The acrobot problem is the fixture ``acrobot_problem`` (tests/conftest.py), built once per
test process, so its functions compile once.
"""

from __future__ import annotations

import numpy as np
import pytest
import jax

from cstorm.examples.acrobot import acrobot_model
from cstorm.errors import ProblemError
from cstorm.optimize import MotionProblem, check_gradients, constraints


@pytest.fixture
def problem(acrobot_problem):
    return acrobot_problem


def test_gradients_match_central_differences(problem):
    rep = check_gradients(problem)
    # measured: ~1e-9 .. 1e-8 at the initial guess and at a random nearby point
    assert rep["max_rel_error"] < 1e-6, rep["points"]
    assert len(rep["points"]) == 2 and rep["points"][0]["n_outputs"] == 1 + problem.n_eq + problem.n_ineq


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
