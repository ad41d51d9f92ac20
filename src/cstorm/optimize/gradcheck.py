"""Exact (JAX) versus central finite-difference gradients of a motion problem's
objective and constraints (DESIGN.md, "What correct means": gradients of the whole
optimization objective agree with central finite differences)."""

from __future__ import annotations

import numpy as np
import jax.numpy as jnp

from .problem import MotionProblem, require_x64

__all__ = ["check_gradients", "SWEEP"]

#: finite-difference steps (relative to ``max(1, |x_j|)``) that ``cstorm
#: check-gradients`` sweeps: truncation error falls and rounding error grows as the step
#: shrinks, and which step balances them differs from row to row
SWEEP = (1e-4, 1e-5, 1e-6, 1e-7)


def check_gradients(problem, x=None, *, eps=1e-6, seed: int = 0, perturbation: float = 0.05, params=None,
                    tol: float = 1e-4) -> dict:
    """Compare the exact Jacobian of ``[f, c_eq, c_in]`` with central differences.

    At ``x`` (default ``problem.x0``) and at a random nearby point ``x + perturbation *
    N(0, 1) * max(1, |x|)`` (seeded). ``eps``: the step, ``eps * max(1, |x_j|)`` per
    variable, or a sequence of such steps in decreasing order (e.g. `SWEEP`), each row
    then judged at the step, or the Richardson extrapolation of two consecutive steps,
    where it agrees best (a wrong derivative disagrees at every step). All perturbed
    points of one point are evaluated in one batched call.

    A `MotionSequence` is checked segment by segment, each at its own initial guess and
    nominal start state; the result then has ``segments`` (one such dict per segment,
    with ``segment``: its name) and the worst of each number.

    Returns a dict:
      ``row_error``: max over output rows (objective, each constraint) and both points of
        ``max_j |J_ij - Jfd_ij| / max_j max(|J_ij|, |Jfd_ij|)``: each row's error
        relative to its own largest entry (rows smaller than 1e-10 of the largest
        entry of the Jacobian count as zero), at the row's best step or extrapolation;
      ``ok``: ``row_error <= tol``; ``worst_row``: ``"objective"``, ``"eq <i>"`` or
        ``"ineq <i>"`` where ``row_error`` is reached;
      ``max_rel_error``: the entrywise ``|g - g_fd| / max(|g_fd|, 1e-6 * scale)``
        (``scale`` the largest ``|g_fd|`` of the entry's row), which reads large where
        an entry is tiny next to its row;
      ``max_abs_error``; ``points`` (per point: ``row_error``, ``max_rel_error``,
        ``objective_rel_error``, ``constraint_rel_error``, ``max_abs_error``,
        ``n_vars``, ``n_outputs``, ``diverged``) and ``x`` (the points checked).
    """
    require_x64("check_gradients")
    from .sequence import MotionSequence

    if isinstance(problem, MotionSequence):
        if x is not None:
            raise ValueError("check_gradients: x is per segment; check a sequence's segments one by one to give it")
        segs = [dict(check_gradients(p, eps=eps, seed=seed, perturbation=perturbation, params=params, tol=tol),
                     segment=p.name) for p in problem.segments]
        worst = max(segs, key=lambda r: r["row_error"])
        return dict(row_error=worst["row_error"], worst_row=f"{worst['segment']}: {worst['worst_row']}",
                    ok=all(r["ok"] for r in segs), max_rel_error=max(r["max_rel_error"] for r in segs),
                    max_abs_error=max(r["max_abs_error"] for r in segs), tol=tol, segments=segs)
    if not isinstance(problem, MotionProblem):
        raise TypeError(f"check_gradients: expected a MotionProblem or MotionSequence, got {type(problem).__name__}")
    steps = tuple(float(e) for e in np.atleast_1d(eps))
    fn = problem.compiled("fun_jac")
    batch = problem.compiled("fun_batch")
    data = problem.data(params=params)
    x0 = np.asarray(problem.x0 if x is None else x, dtype=float)
    rng = np.random.default_rng(seed)
    pts = [x0, x0 + perturbation * rng.normal(size=x0.shape) * np.maximum(1.0, np.abs(x0))]
    n = x0.size
    labels = ["objective"] + [f"eq {i}" for i in range(problem.n_eq)] + [f"ineq {i}" for i in range(problem.n_ineq)]

    out = dict(points=[], x=pts, tol=tol)
    worst, worst_abs, worst_row, worst_label = 0.0, 0.0, 0.0, "objective"
    for xx in pts:
        f, ce, ci, div, g, Je, Ji = (np.asarray(a) for a in fn(jnp.asarray(xx), data))
        J = np.vstack([g[None], Je.reshape(-1, n), Ji.reshape(-1, n)])
        H = np.array([e * max(1.0, abs(xj)) for e in steps for xj in xx])  # (S n,)
        E = np.tile(np.eye(n), (len(steps), 1)) * H[:, None]
        X = np.concatenate([xx + E, xx - E])
        fb, ceb, cib, _ = (np.asarray(a) for a in batch(jnp.asarray(X), data))
        V = np.concatenate([fb[:, None], ceb.reshape(len(X), -1), cib.reshape(len(X), -1)], axis=1)
        V = V.reshape(2, len(steps), n, -1)
        Jfds = (V[0] - V[1]) / (2 * H.reshape(len(steps), n, 1))  # (S, n, m)
        Jfds = np.transpose(Jfds, (0, 2, 1))  # (S, m, n)
        floor = 1e-10 * max(1.0, float(np.max(np.abs(J))) if J.size else 1.0)
        # Richardson extrapolation of each pair of consecutive steps h > h' (central
        # differences err by c h^2 + O(h^4)): stiff contact makes c large
        cands = list(Jfds) + [(r * r * Jfds[i + 1] - Jfds[i]) / (r * r - 1.0)
                              for i in range(len(steps) - 1) for r in [steps[i] / steps[i + 1]] if r > 1.0]
        row_errs = []
        for Jfd in cands:
            big = np.maximum(np.max(np.abs(J), axis=1), np.max(np.abs(Jfd), axis=1))
            row_errs.append(np.where(big > floor, np.max(np.abs(J - Jfd), axis=1) / np.maximum(big, floor), 0.0))
        row_err = np.min(np.array(row_errs), axis=0)  # each row at its best step
        best = int(np.argmin([np.max(r) for r in row_errs[:len(steps)]]))
        Jfd = Jfds[best]
        scale = np.maximum(np.max(np.abs(Jfd), axis=1, keepdims=True), 1e-12)
        rel = np.abs(J - Jfd) / np.maximum(np.abs(Jfd), 1e-6 * scale)
        absd = np.abs(J - Jfd)
        k = int(np.argmax(row_err))
        pt = dict(row_error=float(row_err[k]), worst_row=labels[k], max_rel_error=float(rel.max()),
                  objective_rel_error=float(rel[0].max()),
                  constraint_rel_error=float(rel[1:].max()) if rel.shape[0] > 1 else 0.0,
                  max_abs_error=float(absd.max()), n_vars=int(n), n_outputs=int(J.shape[0]), diverged=bool(div))
        out["points"].append(pt)
        worst, worst_abs = max(worst, pt["max_rel_error"]), max(worst_abs, pt["max_abs_error"])
        if pt["row_error"] >= worst_row:
            worst_row, worst_label = pt["row_error"], pt["worst_row"]
    out.update(max_rel_error=worst, max_abs_error=worst_abs, row_error=worst_row, worst_row=worst_label,
               ok=bool(worst_row <= tol))
    return out
