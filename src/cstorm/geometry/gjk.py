"""GJK distance between two convex cores (Gilbert, Johnson & Keerthi 1988), with a
branch-free distance sub-algorithm that enumerates the 15 faces of a tetrahedron.

``gjk(support_m, w0, max_iter, scale)`` works on the Minkowski difference
``M = A - B`` through ``support_m(dvec) -> SupportPoint`` (the support point of M in the
world direction ``dvec`` (3,), i.e. ``s_A(dvec) - s_B(-dvec)``). It returns a `Simplex`
of up to 4 points (arrays padded to 4 with a boolean mask) whose active points' convex
combination ``v = sum lam_i w_i`` is the point of M closest to the origin, and a status:

- ``SEPARATED`` (1): converged, ``|v|`` is the distance (up to ``rel_tol``);
- ``CONTAINS`` (2): the origin lies in the simplex (penetration or touching; EPA next);
- ``MAX_ITER`` (3): iterations ran out; ``v`` is the best point found (curved shapes:
  the caller polishes it by Newton's method on the optimality conditions).

No Python-side data-dependent control: a `lax.while_loop` with a bounded count.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

SEPARATED, CONTAINS, MAX_ITER = 1, 2, 3


class SupportPoint(NamedTuple):
    w: jnp.ndarray  # (..., 3) point of M = a - b (world)
    a: jnp.ndarray  # (..., 3) support point of A (world)
    b: jnp.ndarray  # (..., 3) support point of B (world)
    ref_a: jnp.ndarray  # (..., 3) local direction that selected a (its feature key)
    ref_b: jnp.ndarray  # (..., 3) local direction that selected b


class Simplex(NamedTuple):
    pts: SupportPoint  # each field (4, 3)
    mask: jnp.ndarray  # (4,) bool, active points
    lam: jnp.ndarray  # (4,) barycentric weights (0 for inactive points)
    v: jnp.ndarray  # (3,) closest point of the simplex to the origin


_EDGES = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))
_FACES = ((0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3))


def closest_on_simplex(W, mask):
    """Closest point to the origin of the convex hull of the active rows of W (4, 3).

    Returns ``(v (3,), lam (4,), sub_mask (4,))``: ``sub_mask`` marks the smallest face
    whose relative interior holds ``v`` (the reduced simplex), ``lam`` its weights.
    """
    dt = W.dtype
    cands_lam, cands_d2 = [], []
    inf = jnp.asarray(jnp.inf, dt)
    scale2 = jnp.max(jnp.sum(W * W, axis=-1)) + jnp.asarray(1e-300, dt)
    # vertices
    for i in range(4):
        lam = jnp.zeros(4, dt).at[i].set(1.0)
        cands_lam.append(lam)
        cands_d2.append(jnp.where(mask[i], W[i] @ W[i], inf))
    # edges
    for i, j in _EDGES:
        e = W[j] - W[i]
        ee = e @ e
        ok = mask[i] & mask[j] & (ee > 1e-24 * scale2)
        t = -(W[i] @ e) / jnp.where(ok, ee, 1.0)
        ok = ok & (t > 0.0) & (t < 1.0)
        lam = jnp.zeros(4, dt).at[i].set(1.0 - t).at[j].set(t)
        p = W[i] + t * e
        cands_lam.append(lam)
        cands_d2.append(jnp.where(ok, p @ p, inf))
    # triangles
    for i, j, k in _FACES:
        e1, e2 = W[j] - W[i], W[k] - W[i]
        a11, a12, a22 = e1 @ e1, e1 @ e2, e2 @ e2
        b1, b2 = -(e1 @ W[i]), -(e2 @ W[i])
        det = a11 * a22 - a12 * a12
        ok = mask[i] & mask[j] & mask[k] & (det > 1e-20 * a11 * a22) & (det > 0.0)
        sdet = jnp.where(ok, det, 1.0)
        lj = (b1 * a22 - b2 * a12) / sdet
        lk = (a11 * b2 - a12 * b1) / sdet
        li = 1.0 - lj - lk
        ok = ok & (li > 0.0) & (lj > 0.0) & (lk > 0.0)
        lam = jnp.zeros(4, dt).at[i].set(li).at[j].set(lj).at[k].set(lk)
        p = W[i] + lj * e1 + lk * e2
        cands_lam.append(lam)
        cands_d2.append(jnp.where(ok, p @ p, inf))
    # tetrahedron: origin inside
    E = jnp.stack([W[1] - W[0], W[2] - W[0], W[3] - W[0]], axis=1)
    det = jnp.linalg.det(E)
    norms = jnp.prod(jnp.sqrt(jnp.sum(E * E, axis=0)))
    ok = jnp.all(mask) & (jnp.abs(det) > 1e-14 * norms)
    Es = jnp.where(ok, E, jnp.eye(3, dtype=dt))
    x = jnp.linalg.solve(Es, -W[0])
    l0 = 1.0 - jnp.sum(x)
    ok = ok & jnp.all(x >= 0.0) & (l0 >= 0.0)
    cands_lam.append(jnp.concatenate([l0[None], x]))
    cands_d2.append(jnp.where(ok, jnp.zeros((), dt), inf))

    L = jnp.stack(cands_lam)
    D2 = jnp.stack(cands_d2)
    best = jnp.argmin(D2)
    lam = L[best]
    sub = lam > 0.0
    lam = jnp.where(sub, lam, 0.0)
    v = lam @ W
    return v, lam, sub


def gjk(support_m, w0: SupportPoint, max_iter: int, scale, rel_tol=1e-12):
    """Run GJK from the initial support point ``w0``. ``scale`` (scalar) is a length of
    the problem (for the absolute containment tolerance). Returns ``(Simplex, status,
    iterations)``."""
    dt = w0.w.dtype
    pts = SupportPoint(*[jnp.zeros((4, 3), dt).at[0].set(x) for x in w0])
    mask = jnp.zeros(4, bool).at[0].set(True)
    lam = jnp.zeros(4, dt).at[0].set(1.0)
    abs_tol2 = (1e-12 * scale) ** 2

    init = (Simplex(pts, mask, lam, w0.w), jnp.asarray(0, jnp.int32), jnp.asarray(0, jnp.int32))

    def cond(state):
        _, status, it = state
        return (status == 0) & (it < max_iter)

    def body(state):
        simp, status, it = state
        v = simp.v
        vv = v @ v
        sp = support_m(-v)
        gap = vv - v @ sp.w
        converged = gap <= rel_tol * vv
        slot = jnp.argmin(simp.mask)  # first free slot (the simplex has < 4 points here)
        new_pts = SupportPoint(*[x.at[slot].set(y) for x, y in zip(simp.pts, sp)])
        new_mask = simp.mask.at[slot].set(True)
        v2, lam2, sub2 = closest_on_simplex(new_pts.w, new_mask)
        vv2 = v2 @ v2
        contains = vv2 <= abs_tol2
        no_progress = vv2 >= vv  # numerical stall: keep the previous simplex
        accept = ~converged & ~no_progress
        simp_new = Simplex(new_pts, sub2, lam2, v2)
        simp = jax.tree_util.tree_map(lambda n, o: jnp.where(accept, n, o), simp_new, simp)
        status = jnp.where(converged | no_progress, SEPARATED, jnp.where(contains, CONTAINS, 0))
        status = jnp.where(vv <= abs_tol2, CONTAINS, status)
        return simp, status.astype(jnp.int32), it + 1

    simp, status, it = jax.lax.while_loop(cond, body, init)
    status = jnp.where(status == 0, MAX_ITER, status)
    # a converged / stalled simplex that touches the origin counts as contact
    status = jnp.where((status != CONTAINS) & (simp.v @ simp.v <= abs_tol2), CONTAINS, status)
    return simp, status, it
