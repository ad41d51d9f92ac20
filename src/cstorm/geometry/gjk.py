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

import numpy as np
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


_EI = np.array(_EDGES)  # numpy: no JAX computation (backend start) at import
_FI = np.array(_FACES)


def closest_on_simplex(W, mask):
    """Closest point to the origin of the convex hull of the active rows of W (4, 3).

    Enumerates the 4 vertices, 6 edges, 4 triangles and the tetrahedron (vectorized),
    keeps the candidates whose projection of the origin lies in their relative interior
    and takes the nearest (the lowest-dimensional on exact ties). Returns ``(v (3,),
    lam (4,), sub_mask (4,))``: ``sub_mask`` marks that smallest face (the reduced
    simplex), ``lam`` its weights.
    """
    dt = W.dtype
    inf = jnp.asarray(jnp.inf, dt)
    scale2 = jnp.max(jnp.sum(W * W, axis=-1)) + jnp.asarray(1e-300, dt)
    eye4 = jnp.eye(4, dtype=dt)
    # vertices
    L_v = eye4
    D_v = jnp.where(mask, jnp.sum(W * W, axis=-1), inf)
    # edges (6)
    Wi, Wj = W[_EI[:, 0]], W[_EI[:, 1]]
    e = Wj - Wi
    ee = jnp.sum(e * e, -1)
    ok = mask[_EI[:, 0]] & mask[_EI[:, 1]] & (ee > 1e-24 * scale2)
    t = -jnp.sum(Wi * e, -1) / jnp.where(ok, ee, 1.0)
    ok = ok & (t > 0.0) & (t < 1.0)
    L_e = (1.0 - t)[:, None] * eye4[_EI[:, 0]] + t[:, None] * eye4[_EI[:, 1]]
    p = Wi + t[:, None] * e
    D_e = jnp.where(ok, jnp.sum(p * p, -1), inf)
    # triangles (4)
    Wi, Wj, Wk = W[_FI[:, 0]], W[_FI[:, 1]], W[_FI[:, 2]]
    e1, e2 = Wj - Wi, Wk - Wi
    a11, a12, a22 = jnp.sum(e1 * e1, -1), jnp.sum(e1 * e2, -1), jnp.sum(e2 * e2, -1)
    b1, b2 = -jnp.sum(e1 * Wi, -1), -jnp.sum(e2 * Wi, -1)
    det = a11 * a22 - a12 * a12
    ok = mask[_FI[:, 0]] & mask[_FI[:, 1]] & mask[_FI[:, 2]] & (det > 1e-20 * a11 * a22) & (det > 0.0)
    sdet = jnp.where(ok, det, 1.0)
    lj = (b1 * a22 - b2 * a12) / sdet
    lk = (a11 * b2 - a12 * b1) / sdet
    li = 1.0 - lj - lk
    ok = ok & (li > 0.0) & (lj > 0.0) & (lk > 0.0)
    L_f = li[:, None] * eye4[_FI[:, 0]] + lj[:, None] * eye4[_FI[:, 1]] + lk[:, None] * eye4[_FI[:, 2]]
    p = Wi + lj[:, None] * e1 + lk[:, None] * e2
    D_f = jnp.where(ok, jnp.sum(p * p, -1), inf)
    # tetrahedron: origin inside (Cramer's rule on the edge matrix)
    E1, E2, E3 = W[1] - W[0], W[2] - W[0], W[3] - W[0]
    c23, c31, c12 = jnp.cross(E2, E3), jnp.cross(E3, E1), jnp.cross(E1, E2)
    det = E1 @ c23
    norms = jnp.sqrt((E1 @ E1) * (E2 @ E2) * (E3 @ E3))
    ok = jnp.all(mask) & (jnp.abs(det) > 1e-14 * norms)
    sdet = jnp.where(ok, det, 1.0)
    x = -jnp.stack([W[0] @ c23, W[0] @ c31, W[0] @ c12]) / sdet
    l0 = 1.0 - jnp.sum(x)
    ok = ok & jnp.all(x >= 0.0) & (l0 >= 0.0)
    L_t = jnp.concatenate([l0[None], x])[None]
    D_t = jnp.where(ok, jnp.zeros((1,), dt), inf)

    L = jnp.concatenate([L_v, L_e, L_f, L_t])
    D2 = jnp.concatenate([D_v, D_e, D_f, D_t])
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
