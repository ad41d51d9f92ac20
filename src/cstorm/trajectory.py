"""Clamped quintic B-splines on a uniform knot vector (de Boor, "A Practical Guide to
Splines", ch. IX-X; Piegl & Tiller, "The NURBS Book", ch. 2-3).

The active joint paths ``q_a(t)`` of a motion are quintic B-splines whose control points
are the optimizer's decision variables (DESIGN.md, "The method", item 5).

Conventions
-----------
- Degree ``p = 5``; ``n = n_ctrl >= 6`` control points; time ``t`` in seconds on
  ``[0, t_final]``.
- Knots: ``t_0 = ... = t_5 = 0``, ``t_{n} = ... = t_{n+5} = t_final`` (clamped), with
  ``n - 6`` uniform interior knots, so there are ``n - 5`` spans of width
  ``h = t_final / (n - 5)``.
- Control points ``ctrl`` have shape ``(n,)`` (one joint) or ``(n, k)`` (``k`` joints,
  one column each). Values have the units of the control points (rad or m); the first
  and second derivatives are per second and per second squared.
- Clamping makes ``q(0) = ctrl[0]`` and ``q(t_final) = ctrl[-1]``;
  ``q'(0)`` depends on ``ctrl[0:2]`` only and ``q''(0)`` on ``ctrl[0:3]`` only (likewise
  at the end with the last two / three). Hence three equal leading control points give
  zero velocity and acceleration at ``t = 0``.

Two ways to evaluate
--------------------
- ``B0, B1, B2 = spl.basis(t_grid)``: numpy basis matrices ``(len(t), n)`` computed once
  on the host (scipy); then ``q = B0 @ ctrl`` etc. is one matmul per rollout.
- ``spl.evaluate(ctrl, t, nu)`` / ``spl.evaluate_all(ctrl, t)``: pure JAX evaluation at
  arbitrary (traced) times, from a precomputed piecewise-polynomial form of the basis;
  works under ``jit``, ``vmap``, ``grad`` (w.r.t. ``ctrl`` and ``t``).

Boundary conditions by construction
-----------------------------------
``spl.expand(free, q0=..., v0=..., a0=..., q1=..., v1=..., a1=..., rest_start=...,
rest_end=...)`` maps a vector of free parameters to control points so that each
prescribed boundary value (position ``q``, velocity ``v``, acceleration ``a`` at
``t = 0`` (suffix 0) or ``t = t_final`` (suffix 1)) holds exactly. Each prescribed
quantity removes one free parameter (``spl.n_free(...)`` tells how many remain);
``rest_start=True`` is shorthand for ``v0 = a0 = 0`` (``rest_end``: ``v1 = a1 = 0``).
The map is affine, ``ctrl = A @ free + G @ values`` (one matmul, differentiable in both).
The free parameters are the control points that are not fixed, in order:
``spl.reduce(ctrl, ...)`` extracts them, ``spl.fixed_indices(...)`` names the others.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import jax.numpy as jnp
from scipy.interpolate import BSpline

from .errors import InputError

DEGREE = 5
_BC_NAMES = ("q0", "v0", "a0", "q1", "v1", "a1")


class QuinticBSpline:
    """Clamped quintic B-spline space on ``[0, t_final]`` with ``n_ctrl`` uniform
    control points.

    Args:
      n_ctrl: number of control points, an int ``>= 6``.
      t_final: duration in s, ``> 0``.

    Attributes:
      n_ctrl, t_final, degree (= 5), n_spans (= n_ctrl - 5), h (= t_final / n_spans, s),
      knots (numpy ``(n_ctrl + 6,)``), greville (numpy ``(n_ctrl,)``: knot averages, the
      times each control point "belongs to"; ``ctrl = f(greville)`` is a cheap guess).

    The object is immutable and hashable (by ``(n_ctrl, t_final)``), so it can be closed
    over or passed as a static argument to ``jax.jit``.
    """

    degree = DEGREE

    def __init__(self, n_ctrl: int, t_final: float):
        if isinstance(n_ctrl, bool) or not isinstance(n_ctrl, (int, np.integer)) or n_ctrl < DEGREE + 1:
            raise InputError(f"QuinticBSpline: n_ctrl must be an int >= {DEGREE + 1}, got {n_ctrl!r}")
        try:
            T = float(t_final)
        except (TypeError, ValueError):
            raise InputError(f"QuinticBSpline: t_final must be a positive number, got {t_final!r}") from None
        if not (math.isfinite(T) and T > 0.0):
            raise InputError(f"QuinticBSpline: t_final must be finite and > 0, got {t_final!r}")
        n = int(n_ctrl)
        object.__setattr__(self, "n_ctrl", n)
        object.__setattr__(self, "t_final", T)
        object.__setattr__(self, "n_spans", n - DEGREE)
        object.__setattr__(self, "h", T / (n - DEGREE))
        breaks = np.linspace(0.0, T, n - DEGREE + 1)
        knots = np.concatenate([np.zeros(DEGREE), breaks, np.full(DEGREE, T)])
        knots.setflags(write=False)
        object.__setattr__(self, "knots", knots)
        grev = np.array([knots[i + 1:i + DEGREE + 1].mean() for i in range(n)])
        grev.setflags(write=False)
        object.__setattr__(self, "greville", grev)
        object.__setattr__(self, "_bspl", BSpline(knots, np.eye(n), DEGREE, extrapolate=True))
        # Piecewise-polynomial form: on span j (t in [j h, (j+1) h], u = t/h - j in [0, 1])
        # the six non-zero basis functions N_{j..j+5} are sum_m C[j, i, m] u^m.
        left = breaks[:-1]
        C = np.empty((self.n_spans, DEGREE + 1, DEGREE + 1))
        j = np.arange(self.n_spans)
        for m in range(DEGREE + 1):
            D = self._bspl(left, nu=m)  # (n_spans, n): right limits at the left breakpoints
            for i in range(DEGREE + 1):
                C[:, i, m] = D[j, j + i] * self.h**m / math.factorial(m)
        C.setflags(write=False)
        object.__setattr__(self, "_coef", C)

    def __setattr__(self, name, value):
        raise AttributeError("QuinticBSpline is immutable")

    def __repr__(self):
        return f"QuinticBSpline(n_ctrl={self.n_ctrl}, t_final={self.t_final!r})"

    def __eq__(self, other):
        return isinstance(other, QuinticBSpline) and (self.n_ctrl, self.t_final) == (other.n_ctrl, other.t_final)

    def __hash__(self):
        return hash(("QuinticBSpline", self.n_ctrl, self.t_final))

    # ------------------------------------------------------------------ host-side basis
    def _check_times(self, t, who):
        t = np.asarray(t, dtype=float)
        if t.ndim != 1:
            raise InputError(f"QuinticBSpline.{who}: t must be a 1-D array of times, got shape {t.shape}")
        if not np.all(np.isfinite(t)):
            raise InputError(f"QuinticBSpline.{who}: t contains NaN or inf")
        tol = 1e-9 * self.t_final
        if t.size and (t.min() < -tol or t.max() > self.t_final + tol):
            raise InputError(
                f"QuinticBSpline.{who}: times must lie in [0, t_final={self.t_final}], "
                f"got range [{t.min()}, {t.max()}]"
            )
        return np.clip(t, 0.0, self.t_final)

    def basis_matrix(self, t, nu: int = 0) -> np.ndarray:
        """Basis functions (or their ``nu``-th time derivatives, 1/s^nu) at times ``t``.

        Args:
          t: ``(m,)`` times in ``[0, t_final]`` s (host data).
          nu: derivative order, ``0 <= nu <= 5``.
        Returns:
          numpy ``(m, n_ctrl)``; ``basis_matrix(t, nu) @ ctrl`` is the ``nu``-th derivative.
        """
        if not (isinstance(nu, (int, np.integer)) and 0 <= nu <= DEGREE):
            raise InputError(f"QuinticBSpline.basis_matrix: nu must be an int in [0, {DEGREE}], got {nu!r}")
        t = self._check_times(t, "basis_matrix")
        return np.ascontiguousarray(self._bspl(t, nu=int(nu)))

    def basis(self, t):
        """``(B0, B1, B2)``: value, first and second time-derivative basis matrices at
        times ``t`` (``(m,)`` in ``[0, t_final]`` s), each numpy ``(m, n_ctrl)``, so that
        ``q = B0 @ ctrl``, ``qdot = B1 @ ctrl``, ``qddot = B2 @ ctrl``."""
        return tuple(self.basis_matrix(t, nu) for nu in range(3))

    # ------------------------------------------------------------------ JAX evaluation
    def evaluate(self, ctrl, t, nu: int = 0):
        """The ``nu``-th time derivative of the spline at times ``t`` (pure JAX).

        Args:
          ctrl: control points ``(n_ctrl,)`` or ``(n_ctrl, k)``.
          t: times in s, any shape (scalar, ``(m,)``, ...); may be traced. Outside
            ``[0, t_final]`` the end spans' polynomials are extrapolated.
          nu: static derivative order, ``0 <= nu <= 5``.
        Returns:
          ``t.shape + ctrl.shape[1:]`` (units of ``ctrl`` per s^nu).
        """
        if not (isinstance(nu, (int, np.integer)) and 0 <= nu <= DEGREE):
            raise InputError(f"QuinticBSpline.evaluate: nu must be an int in [0, {DEGREE}], got {nu!r}")
        ctrl = self._check_ctrl(ctrl, "evaluate")
        j, u = self._span(t)
        return self._eval_span(ctrl, j, u, int(nu))

    def evaluate_all(self, ctrl, t):
        """``(q, qdot, qddot)`` at times ``t``; shapes and units as in `evaluate`."""
        ctrl = self._check_ctrl(ctrl, "evaluate_all")
        j, u = self._span(t)
        return tuple(self._eval_span(ctrl, j, u, nu) for nu in range(3))

    def __call__(self, ctrl, t, nu: int = 0):
        """Same as `evaluate`."""
        return self.evaluate(ctrl, t, nu)

    def _check_ctrl(self, ctrl, who):
        ctrl = jnp.asarray(ctrl)
        if ctrl.ndim not in (1, 2) or ctrl.shape[0] != self.n_ctrl:
            raise InputError(
                f"QuinticBSpline.{who}: ctrl must have shape ({self.n_ctrl},) or ({self.n_ctrl}, k), got {ctrl.shape}"
            )
        return ctrl

    def _span(self, t):
        x = jnp.asarray(t) / self.h
        j = jnp.clip(jnp.floor(x), 0, self.n_spans - 1)
        u = x - j  # d u / d t = 1 / h
        return j.astype(jnp.int32), u

    def _eval_span(self, ctrl, j, u, nu):
        coef = jnp.asarray(self._coef)[j]  # t.shape + (6, 6)
        # d^nu/du^nu of u^m = m!/(m-nu)! u^(m-nu), times (1/h)^nu for d/dt.
        cols = []
        for m in range(DEGREE + 1):
            if m < nu:
                cols.append(jnp.zeros_like(u))
            else:
                cols.append(math.factorial(m) / math.factorial(m - nu) * u ** (m - nu))
        P = jnp.stack(cols, axis=-1) / self.h**nu  # t.shape + (6,)
        w = jnp.einsum("...im,...m->...i", coef, P)  # t.shape + (6,)
        idx = j[..., None] + jnp.arange(DEGREE + 1)  # t.shape + (6,)
        local = ctrl[idx]  # t.shape + (6,) + ctrl.shape[1:]
        if ctrl.ndim == 2:
            w = w[..., None]
        return jnp.sum(w * local, axis=u.ndim)

    # ------------------------------------------------------------------ boundary conditions
    def _bc_key(self, bc, who):
        bad = set(bc) - set(_BC_NAMES) - {"rest_start", "rest_end"}
        if bad:
            raise InputError(f"QuinticBSpline.{who}: unknown boundary condition(s) {sorted(bad)}")
        vals = {k: bc.get(k) for k in _BC_NAMES}
        for flag, (vk, ak) in (("rest_start", ("v0", "a0")), ("rest_end", ("v1", "a1"))):
            if bc.get(flag, False):
                for k in (vk, ak):
                    if vals[k] is not None:
                        raise InputError(f"QuinticBSpline.{who}: {flag}=True already sets {k} = 0; do not pass {k}")
                    vals[k] = 0.0
        key = tuple(vals[k] is not None for k in _BC_NAMES)
        given = [vals[k] for k, on in zip(_BC_NAMES, key) if on]
        return key, given

    @functools.lru_cache(maxsize=64)
    def _affine(self, key):
        """(A (n, n_free), G (n, n_given), free_idx, fixed_idx) for a static prescription
        pattern ``key`` (six bools, in the order of _BC_NAMES)."""
        n = self.n_ctrl
        ends = np.array([0.0, self.t_final])
        M = [self._bspl(ends, nu=r) for r in range(3)]  # each (2, n)
        fixed = set()
        for e, idxs in ((0, (0, 1, 2)), (1, (n - 1, n - 2, n - 3))):
            for r in range(3):
                if key[3 * e + r]:
                    fixed.add(idxs[r])
        free_idx = tuple(i for i in range(n) if i not in fixed)
        fixed_idx = tuple(sorted(fixed))
        n_free, n_given = len(free_idx), sum(key)
        # Each control point as a row over [free; given].
        R = np.zeros((n, n_free + n_given))
        for col, i in enumerate(free_idx):
            R[i, col] = 1.0
        g = n_free
        for e, idxs in ((0, (0, 1, 2)), (1, (n - 1, n - 2, n - 3))):
            for r in range(3):
                if not key[3 * e + r]:
                    continue
                # row r of the boundary system: sum_{s <= r} M[r][e, idxs[s]] c_{idxs[s]} = value
                row = np.zeros(n_free + n_given)
                row[g] = 1.0
                for s in range(r):
                    row -= M[r][e, idxs[s]] * R[idxs[s]]
                R[idxs[r]] = row / M[r][e, idxs[r]]
                g += 1
        A, G = R[:, :n_free].copy(), R[:, n_free:].copy()
        for a in (A, G):
            a.setflags(write=False)
        return A, G, free_idx, fixed_idx

    def n_free(self, **bc) -> int:
        """Number of free parameters left by the boundary conditions ``bc`` (keywords
        as in `expand`; only which ones are given matters)."""
        key, _ = self._bc_key(bc, "n_free")
        return len(self._affine(key)[2])

    def free_indices(self, **bc) -> tuple:
        """Indices of the control points that are free parameters under ``bc``."""
        key, _ = self._bc_key(bc, "free_indices")
        return self._affine(key)[2]

    def fixed_indices(self, **bc) -> tuple:
        """Indices of the control points determined by the boundary conditions ``bc``."""
        key, _ = self._bc_key(bc, "fixed_indices")
        return self._affine(key)[3]

    def expand(self, free, **bc):
        """Control points from free parameters, with boundary conditions built in.

        Args:
          free: ``(n_free,)`` or ``(n_free, k)``, ``n_free = self.n_free(**bc)``; the values
            of the free control points (`free_indices`), in order.
          q0, v0, a0: optional position, velocity (1/s) and acceleration (1/s^2) at
            ``t = 0``; scalars or ``(k,)`` arrays (may be traced). ``None``: not prescribed.
          q1, v1, a1: the same at ``t = t_final``.
          rest_start, rest_end: static bools; ``True`` prescribes ``v = a = 0`` at that end.
        Returns:
          ``ctrl`` ``(n_ctrl,)`` or ``(n_ctrl, k)`` such that the spline meets every
          prescribed value exactly; affine in ``free`` and in the prescribed values.

        Example: ``spl.expand(free, q0=qa_start, q1=qa_end, rest_start=True,
        rest_end=True)`` fixes the first three control points to ``qa_start`` and the last
        three to ``qa_end``; ``n_free = n_ctrl - 6``.
        """
        key, given = self._bc_key(bc, "expand")
        A, G, free_idx, _ = self._affine(key)
        free = jnp.asarray(free)
        if free.ndim not in (1, 2) or free.shape[0] != len(free_idx):
            raise InputError(
                f"QuinticBSpline.expand: free must have shape ({len(free_idx)},) or ({len(free_idx)}, k) "
                f"for these boundary conditions, got {free.shape}"
            )
        ctrl = jnp.asarray(A) @ free
        if given:
            tail = free.shape[1:]
            vals = jnp.stack([jnp.broadcast_to(jnp.asarray(v, dtype=ctrl.dtype), tail) for v in given])
            ctrl = ctrl + jnp.asarray(G) @ vals
        return ctrl

    def reduce(self, ctrl, **bc):
        """The free parameters of ``ctrl`` under ``bc`` (``ctrl[free_indices]``); the
        inverse of `expand` for control points that satisfy ``bc``."""
        ctrl = self._check_ctrl(ctrl, "reduce")
        return ctrl[np.asarray(self.free_indices(**bc), dtype=int)]

    # ------------------------------------------------------------------ fitting
    def fit(self, t, values, **bc) -> np.ndarray:
        """Least-squares control points for samples ``values`` at times ``t`` (host-side,
        for initial guesses), meeting the boundary conditions ``bc`` (as in `expand`,
        concrete values) exactly.

        Args:
          t: ``(m,)`` times in ``[0, t_final]`` s; they must determine every free control
            point (e.g. ``m >= n_ctrl`` times spread over the whole interval).
          values: ``(m,)`` or ``(m, k)`` samples.
        Returns:
          numpy ``ctrl`` ``(n_ctrl,)`` or ``(n_ctrl, k)``; use ``spl.reduce(ctrl, **bc)``
          for the free parameters. Polynomials of degree <= 5 are reproduced exactly.
        Raises:
          InputError on mismatched shapes or when the samples leave a free control point
          undetermined (rank-deficient least-squares problem).
        """
        t = self._check_times(t, "fit")
        y = np.asarray(values, dtype=float)
        if y.ndim not in (1, 2) or y.shape[0] != t.shape[0]:
            raise InputError(f"QuinticBSpline.fit: values must have shape ({t.shape[0]},) or ({t.shape[0]}, k), got {y.shape}")
        if not np.all(np.isfinite(y)):
            raise InputError("QuinticBSpline.fit: values contain NaN or inf")
        key, given = self._bc_key(bc, "fit")
        A, G, free_idx, _ = self._affine(key)
        B0 = self.basis_matrix(t, 0)
        rhs = y.copy()
        if given:
            vals = np.stack([np.broadcast_to(np.asarray(v, dtype=float), y.shape[1:]) for v in given])
            fixed_part = G @ vals
            rhs = rhs - B0 @ fixed_part
        else:
            fixed_part = 0.0
        K = B0 @ A
        sol, _, rank, sv = np.linalg.lstsq(K, rhs, rcond=None)
        if rank < K.shape[1]:
            raise InputError(
                f"QuinticBSpline.fit: the {t.shape[0]} sample times leave {K.shape[1] - rank} of the "
                f"{K.shape[1]} free control points undetermined; sample the whole interval [0, {self.t_final}] "
                f"more densely (at least n_ctrl = {self.n_ctrl} distinct times)"
            )
        return A @ sol + fixed_part
