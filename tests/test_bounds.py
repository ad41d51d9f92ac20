"""Box bounds on the decision vector (`cstorm.optimize.bounds`): the joint limits on the
control points, a stage's trust region, moving a point into the box."""

from __future__ import annotations

import numpy as np
import pytest

import cstorm as cs
from cstorm.optimize import MotionProblem
from cstorm.optimize.bounds import clip_into, stage_bounds, variable_bounds


def test_variable_bounds_follow_joint_limits():
    """Free control points are boxed by the active joints' position limits (a clamped
    B-spline stays in the convex hull of its control points); unlimited joints are
    unbounded."""
    m = cs.robots.tumbler()
    q0 = cs.robots.tumbler_standing_q()
    p = MotionProblem(m, ["shoulder", "hip"], 1.0, 8, 0.05, q0)
    lb, ub = variable_bounds(p)
    nf = p.n_free
    assert lb.shape == ub.shape == (p.n_vars,)
    # layout order is model order: hip first, then shoulder
    assert p.active == ("hip", "shoulder")
    np.testing.assert_allclose(lb[:nf], -2.8)
    np.testing.assert_allclose(ub[nf:], 3.0)
    a = cs.examples.get("acrobot")(t_final=3.0, n_ctrl=16, dt=0.02)
    lb, ub = variable_bounds(a)
    assert np.all(np.isinf(lb)) and np.all(np.isinf(ub))


def test_stage_trust_region_bounds():
    """``solve_options["trust_region"]``: each stage's variable bounds are the joint-limit
    bounds intersected with a box of that radius around the stage's start (moved into
    the limits first)."""
    p = MotionProblem(cs.robots.tumbler(), ["hip", "shoulder"], 1.0, 8, 0.05, cs.robots.tumbler_standing_q())
    lb, ub = variable_bounds(p)
    x = np.asarray(p.x0, float).copy()
    x[0] = ub[0] + 1.0  # outside the limits: clipped first
    p.solve_options["trust_region"] = 0.2
    slb, sub = stage_bounds(p, x)
    xc = np.clip(x, lb, ub)
    np.testing.assert_allclose(slb, np.maximum(lb, xc - 0.2))
    np.testing.assert_allclose(sub, np.minimum(ub, xc + 0.2))
    assert np.all(slb <= xc) and np.all(xc <= sub)
    r = np.linspace(0.01, 0.3, p.n_vars)  # one radius per variable
    p.solve_options["trust_region"] = r
    slb, sub = stage_bounds(p, x)
    np.testing.assert_allclose(slb, np.maximum(lb, xc - r))
    np.testing.assert_allclose(sub, np.minimum(ub, xc + r))
    p.solve_options["trust_region"] = np.ones(3)
    with pytest.raises(cs.InputError, match="trust_region"):
        stage_bounds(p, x)
    p.solve_options.pop("trust_region")
    for a, b in zip(stage_bounds(p, x), (lb, ub)):
        np.testing.assert_array_equal(a, b)


def test_clip_into():
    np.testing.assert_array_equal(clip_into(np.array([-2.0, 0.5, 3.0]), -np.ones(3), np.ones(3)), [-1.0, 0.5, 1.0])
