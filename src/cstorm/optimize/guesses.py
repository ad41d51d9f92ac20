"""Initial guesses for a `MotionProblem`'s active joints, in the form its
``initial_guess`` takes: ``{joint: (t, values)}`` samples that the problem fits with its
splines."""

from __future__ import annotations

import numpy as np

__all__ = ["keyframe_guess"]


def keyframe_guess(keyframes, t_final, names):
    """Keyframe postures joined by smoothstep ramps, sampled for ``initial_guess``.

    ``keyframes``: a sequence of ``(fraction of t_final, (angle per joint))``, fractions
    increasing from 0 to 1, one angle (rad, or m for a prismatic joint) per name in
    ``names``; ``t_final`` (s). Between two keyframes each joint follows ``3 s^2 - 2 s^3``
    of the local time ``s`` in [0, 1], so the motion is at rest at every keyframe. Returns
    ``{name: (t (400,), values (400,))}`` on 400 evenly spaced points of ``[0, t_final]``."""
    ts = np.array([k[0] for k in keyframes], float) * float(t_final)
    P = np.array([k[1] for k in keyframes], dtype=float)
    tt = np.linspace(0.0, float(t_final), 400)
    k = np.clip(np.searchsorted(ts, tt, side="right") - 1, 0, len(ts) - 2)
    s = np.clip((tt - ts[k]) / (ts[k + 1] - ts[k]), 0.0, 1.0)
    w = (s * s * (3.0 - 2.0 * s))[:, None]
    vals = P[k] + (P[k + 1] - P[k]) * w
    return {n: (tt, vals[:, j]) for j, n in enumerate(names)}
