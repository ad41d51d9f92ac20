"""`Solution` (`cstorm.optimize.solution`): save and load round trip of a solved acrobot
swing-up (the fixture ``acrobot_solution``, tests/conftest.py, built once per test process).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from cstorm.optimize import load_solution


@pytest.fixture
def solution(acrobot_solution):
    return acrobot_solution


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
