"""The active joints' torques against their motor limits on every integration step."""

from __future__ import annotations

import numpy as np

from ..model.info import dof_names
from .segments import problem_segments, segment_solutions

__all__ = ["torque_check"]


def torque_check(problem, solution) -> dict:
    """The active joints' torques against the model's effort limits on *every* step of
    every segment's trajectory (not only on the constraint grid of ``TorqueLimits``-style
    constraints, which sample the path: a contact impact between two samples can need far
    more than the limit for a few ms). Joints without a finite limit are skipped.

    Returns ``{"ok", "worst_ratio", "joint", "t", "segment", "message", "segments": [{"segment",
    "ok", "worst_ratio", "joint", "t", "max_abs_tau": {joint: N m}, "ratio": {joint: |tau|/limit}}]}``
    (``ok``: every ratio <= 1 + 1e-6; ``t`` in the segment's own time, s)."""
    out_segs = []
    for prob, sol in zip(problem_segments(problem), segment_solutions(solution)):
        lim = np.asarray(prob.model.effort_limit, float)
        idx = [i for i in prob.layout.va_idx if np.isfinite(lim[i]) and lim[i] > 0]
        names = [dof_names(prob.model, "v")[i] for i in idx]
        a = np.abs(np.asarray(sol.trajectory["tau"], float)[:, idx])  # (N+1, k)
        r = a / lim[idx]
        mx = dict(zip(names, map(float, a.max(axis=0, initial=0.0))))
        ratio = dict(zip(names, map(float, r.max(axis=0, initial=0.0))))
        worst = (0.0, None, None)
        if r.size and r.max() > 0:
            k, j = np.unravel_index(np.argmax(r), r.shape)
            worst = (float(r[k, j]), names[j], float(np.asarray(sol.trajectory["t"], float)[k]))
        out_segs.append(dict(segment=sol.problem or prob.name, ok=bool(worst[0] <= 1 + 1e-6), worst_ratio=worst[0],
                             joint=worst[1], t=worst[2], max_abs_tau=mx, ratio=ratio))
    w = max(out_segs, key=lambda r: r["worst_ratio"]) if out_segs else None
    ok = all(r["ok"] for r in out_segs)
    msg = ("every active joint's torque is within its effort limit on every step" if ok else
           f"{w['segment']}: {w['joint']} needs {w['worst_ratio']:.2f}x its effort limit at t = {w['t']:.3f} s "
           "(between the samples of a sampled torque-limit constraint; TorqueLimits(dense=True) enforces every step)")
    return dict(ok=ok, worst_ratio=w["worst_ratio"] if w else 0.0, joint=w["joint"] if w else None,
                t=w["t"] if w else None, segment=w["segment"] if w else None, message=msg, segments=out_segs)
