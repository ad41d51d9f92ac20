"""`MotionSequence` (`cstorm.optimize.sequence`): segments chained end to start, and the
later segments compiled in the background while the first one solves (acrobot).
"""

from __future__ import annotations

import numpy as np
import pytest

from cstorm import examples
from cstorm.optimize import MotionSequence, solve


@pytest.fixture
def problem(acrobot_problem):
    return acrobot_problem


def test_sequence_segments_chain(problem):
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
