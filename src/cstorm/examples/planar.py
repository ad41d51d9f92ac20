"""Pieces shared by the examples on planar robots (`hopper`, `walker`, `luxo`,
`tumbler`): contact distances read from a solution's trajectory, one success-criterion
entry, the longest run of a condition over a time grid, and the hold test of a motion
that ends at rest.

Not an example itself: it registers no problem (no ``EXAMPLES``).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import DivergenceError, ProblemError
from ..simulate import simulate

__all__ = ["trajectory_contact_d", "criterion", "longest_run", "hold_test"]

def trajectory_contact_d(tr, who="criteria"):
    """(N+1, k) signed contact distances (m) of a solution's trajectory dict ``tr`` (its
    ``contact`` entry: contact data, or a dict as loaded from ``solution.npz``). Raises
    `ProblemError` (prefixed ``who``) when the trajectory has none."""
    c = tr.get("contact")
    if c is None:
        raise ProblemError(f"{who}: the solution's trajectory has no contact data")
    if isinstance(c, dict):
        for k in ("d", "contact/d"):
            if k in c:
                return np.asarray(c[k])
        raise ProblemError(f"{who}: no contact distances in the trajectory (keys {sorted(c)})")
    return np.asarray(c.d)


def criterion(value, tol, ok, op="<="):
    """One success-criterion entry, as `cstorm.report` writes them: ``{"value", "tol",
    "op", "ok"}``."""
    return dict(value=float(value), tol=float(tol), op=op, ok=bool(ok))


def longest_run(t, flag):
    """Total and longest duration (s) over which ``flag`` (N+1,) bools holds at both ends
    of a step of the grid ``t`` (N+1,): ``(total, longest)``."""
    t, flag = np.asarray(t, float), np.asarray(flag, bool)
    dt = np.diff(t)
    seg = flag[:-1] & flag[1:]
    total, longest, run = float(np.sum(dt[seg])), 0.0, 0.0
    for ok, h in zip(seg, dt):
        run = run + h if ok else 0.0
        longest = max(longest, run)
    return total, longest


def hold_test(problem, solution, duration=1.0):
    """What "at rest" means physically: from the solution's final state, simulate
    ``duration`` s more with the active joints locked (zero active accelerations, same
    RK4 step, contact and environment) and measure how far the planar base (``root_x,
    root_z, root_pitch``, the first three coordinates) moves. Returns ``(pitch_dev,
    pos_dev, v_end)``: the largest pitch deviation from the final value (rad), the
    largest x-z displacement (m), and the largest base speed at the end of the hold (m/s,
    rad/s); all ``inf`` if the hold diverges."""
    p = problem
    qT, vT = np.asarray(solution.trajectory["q"][-1]), np.asarray(solution.trajectory["v"][-1])
    try:
        h = simulate(p.model, qT, vT, t_final=duration, dt=p.dt, active=p.active, env=p.env, contact=p.contact,
                     check=False)
    except DivergenceError:  # a diverging hold is a failed hold
        return math.inf, math.inf, math.inf
    q, v = np.asarray(h.q), np.asarray(h.v)
    pitch_dev = float(np.max(np.abs(q[:, 2] - qT[2])))
    pos_dev = float(np.max(np.linalg.norm(q[:, :2] - qT[:2], axis=1)))
    return pitch_dev, pos_dev, float(np.max(np.abs(v[-1, :3])))
