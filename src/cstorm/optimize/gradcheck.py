"""Exact (JAX) versus central finite-difference gradients of a motion problem's
objective and constraints (DESIGN.md, "What correct means": gradients of the whole
optimization objective agree with central finite differences)."""

from __future__ import annotations

import numpy as np
import jax.numpy as jnp

from .problem import MotionProblem, require_x64

__all__ = ["check_gradients"]


def check_gradients(problem: MotionProblem, x=None, *, eps: float = 1e-6, seed: int = 0, perturbation: float = 0.05,
                    params=None) -> dict:
    """Compare the exact Jacobian of ``[f, c_eq, c_in]`` with central differences.

    At ``x`` (default ``problem.x0``) and at a random nearby point ``x + perturbation *
    N(0, 1) * max(1, |x|)`` (seeded). The step is ``eps * max(1, |x_j|)`` per variable.

    Returns a dict: ``max_rel_error`` (max over all entries and both points of
    ``|g - g_fd| / max(|g_fd|, 1e-6 * scale)``, ``scale`` = the largest ``|g_fd|`` of that
    output row, at least 1e-12), ``max_abs_error``, ``points`` (per point: ``max_rel_error``,
    ``objective_rel_error``, ``constraint_rel_error``, ``n_vars``, ``n_outputs``) and the
    arrays ``x`` (the points checked).
    """
    require_x64("check_gradients")
    fn = problem.compiled("fun_jac")
    data = problem.data(params=params)
    x0 = np.asarray(problem.x0 if x is None else x, dtype=float)
    rng = np.random.default_rng(seed)
    pts = [x0, x0 + perturbation * rng.normal(size=x0.shape) * np.maximum(1.0, np.abs(x0))]

    def vals(xx):
        f, ce, ci, *_ = fn(jnp.asarray(xx), data)
        return np.concatenate([[float(f)], np.asarray(ce), np.asarray(ci)])

    out = dict(points=[], x=pts)
    worst, worst_abs = 0.0, 0.0
    for xx in pts:
        f, ce, ci, div, g, Je, Ji = (np.asarray(a) for a in fn(jnp.asarray(xx), data))
        J = np.vstack([g[None], Je.reshape(-1, xx.size), Ji.reshape(-1, xx.size)])
        Jfd = np.zeros_like(J)
        for j in range(xx.size):
            h = eps * max(1.0, abs(xx[j]))
            e = np.zeros_like(xx)
            e[j] = h
            Jfd[:, j] = (vals(xx + e) - vals(xx - e)) / (2 * h)
        scale = np.maximum(np.max(np.abs(Jfd), axis=1, keepdims=True), 1e-12)
        rel = np.abs(J - Jfd) / np.maximum(np.abs(Jfd), 1e-6 * scale)
        absd = np.abs(J - Jfd)
        pt = dict(max_rel_error=float(rel.max()), objective_rel_error=float(rel[0].max()),
                  constraint_rel_error=float(rel[1:].max()) if rel.shape[0] > 1 else 0.0,
                  max_abs_error=float(absd.max()), n_vars=int(xx.size), n_outputs=int(J.shape[0]),
                  diverged=bool(div))
        out["points"].append(pt)
        worst, worst_abs = max(worst, pt["max_rel_error"]), max(worst_abs, pt["max_abs_error"])
    out["max_rel_error"] = worst
    out["max_abs_error"] = worst_abs
    return out
