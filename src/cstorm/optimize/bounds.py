"""Box bounds on a `MotionProblem`'s decision vector: the joint limits on the control
points, a problem's own ``x_bounds``, and the moving trust region of a solve stage."""

from __future__ import annotations

import numpy as np

from ..errors import InputError

__all__ = ["variable_bounds", "stage_bounds", "clip_into"]


def variable_bounds(problem):
    """Box bounds ``(lb, ub)`` (each (n_vars,)) on the decision vector given to the solver.

    The free control points of an active joint's spline lie within the joint's position
    limits (``model.q_lower``/``q_upper``; +-inf where unlimited). A clamped B-spline lies
    in the convex hull of its control points, so these bounds keep the whole path within
    the limits, and they stop a quasi-Newton step from throwing the controls to absurd
    values (SLSQP otherwise may, far from the solution). A problem may override them with
    an attribute ``x_bounds = (lb, ub)``; variables past the spline's (e.g. free initial
    states) are unbounded unless the problem says otherwise.
    """
    custom = getattr(problem, "x_bounds", None)
    if custom is not None:
        lb, ub = (np.broadcast_to(np.asarray(b, float), (problem.n_vars,)).copy() for b in custom)
        return lb, ub
    lb, ub = np.full(problem.n_vars, -np.inf), np.full(problem.n_vars, np.inf)
    m, lay = problem.model, problem.layout
    nf = problem.n_free
    lo, hi = np.asarray(m.q_lower, float), np.asarray(m.q_upper, float)
    for j, qi in enumerate(lay.qa_idx):
        lb[j * nf:(j + 1) * nf], ub[j * nf:(j + 1) * nf] = lo[qi], hi[qi]
    return lb, ub


def stage_bounds(problem, x, r=None):
    """The variable bounds of one stage that starts at ``x``: `variable_bounds`, and with
    a trust radius ``r`` (``problem.solve_options["trust_region"]`` unless given, e.g. by
    a schedule stage's ``"trust_region"``; same units as ``x``; a number or one radius
    per variable, e.g. smaller for multiple-shooting nodes of a body resting on a stiff
    contact) also within ``r`` of ``x`` (a box trust region per stage that moves with the
    solve: SLSQP's linearized constraints otherwise throw a warm start radians away; a
    continuation plan can still travel far, ``r`` per stage). ``x`` is first moved into
    the bounds."""
    lb, ub = variable_bounds(problem)
    r = problem.solve_options.get("trust_region") if r is None else r
    if r is None:
        return lb, ub
    xc = clip_into(np.asarray(x, float), lb, ub)
    r = np.asarray(r, float)
    if r.shape not in ((), xc.shape):
        raise InputError(f"solve: solve_options['trust_region'] must be a number or have shape {xc.shape} (one "
                         f"radius per variable), got shape {r.shape}")
    return np.maximum(lb, xc - r), np.minimum(ub, xc + r)


def clip_into(x, lb, ub):
    """``x`` (n,) moved into the box ``lb <= x <= ub`` (each (n,)): an initial guess
    outside it would be rejected by SLSQP."""
    return np.minimum(np.maximum(x, lb), ub)
