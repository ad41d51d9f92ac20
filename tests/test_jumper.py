"""Contact-distance path constraints (`constraints.ContactDistance`).

Problem construction only traces the rollout (`jax.eval_shape`), nothing is compiled.
"""

from __future__ import annotations

import numpy as np
import pytest

import cstorm as cs
from cstorm.errors import ProblemError
from cstorm.optimize import MotionProblem, constraints


def _tumbler_problem(cons, env=True):
    m = cs.robots.tumbler()
    q0 = cs.robots.tumbler_standing_q(m)
    kw = dict(env=cs.Environment([cs.ground()]),
              contact=cs.ContactParams(stiffness=5e3, damping=100.0, d_on=0.01, d_off=0.0, friction=0.8)) if env else {}
    return MotionProblem(m, ["hip", "shoulder"], t_final=0.2, n_ctrl=6, dt=0.01, q0=q0, constraints=cons,
                         n_path_samples=10, params={"clear": 0.01}, **kw)


def test_contact_distance_sizes_and_selection():
    labels = cs.contact_labels(cs.robots.tumbler(), cs.Environment([cs.ground()]))
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
    labels = cs.contact_labels(p.model, p.env)
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
