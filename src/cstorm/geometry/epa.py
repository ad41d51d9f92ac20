"""Expanding Polytope Algorithm (van den Bergen 2001) for the penetration depth of two
convex cores, on fixed-size buffers so that it jits and vmaps.

``epa(support_m, simplex, max_iter, scale)`` starts from GJK's final simplex (which
holds the origin of ``M = A - B``), grows it to a polytope that encloses the origin (a
tetrahedron, or a triangular bipyramid when GJK stopped on a triangle, segment or
point, i.e. when the shapes touch), and repeatedly pushes out the face nearest to the
origin with the support point of M along its outward normal, removing the faces that
point sees and stitching the horizon to it. It stops when the face's support gap is
below tolerance, or after ``max_iter`` steps.

Returns ``(pts, lam, nu, dist)``: the nearest face's three `SupportPoint` s (fields
(3, 3)), the barycentric weights (3,) of the origin's projection on it, its outward unit
normal ``nu`` (3,) and its distance ``dist >= 0`` from the origin. The penetration
depth is ``dist``, the signed distance ``-dist`` and cstorm's normal ``n = -nu``.
Buffers hold ``5 + max_iter`` vertices and twice as many faces; the horizon is found
with a dense directed-edge table (``(V, V)``), no adjacency lists. Faces of area below
``1e-14 scale^2`` are never chosen (their normals are rounding noise: a bipyramid apex
on the plane of GJK's triangle when the shapes touch); among faces at the same distance
(coplanar pieces of one face of M) the one that holds the origin's projection is.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..spatial import safe_norm
from .gjk import Simplex, SupportPoint

_TET = ((0, 1, 2), (0, 3, 1), (0, 2, 3), (1, 3, 2), (0, 0, 0), (0, 0, 0))
_BIPYR = ((0, 1, 3), (1, 2, 3), (2, 0, 3), (1, 0, 4), (2, 1, 4), (0, 2, 4))


def _unit(x):
    n = safe_norm(x)
    return x / jnp.where(n > 0.0, n, 1.0)


def _perp_basis(e):
    """Two unit vectors orthogonal to the unit vector e and each other."""
    a = jnp.where(jnp.abs(e[0]) < 0.6, jnp.array([1.0, 0.0, 0.0]), jnp.array([0.0, 1.0, 0.0]))
    b1 = _unit(jnp.cross(e, a))
    b2 = jnp.cross(e, b1)
    return b1, b2


def _select(c, x, y):
    return jax.tree_util.tree_map(lambda p, q: jnp.where(c, p, q), x, y)


def _stack_pts(lst):
    return SupportPoint(*[jnp.stack(f) for f in zip(*lst)])


def _initial_polytope(support_m, simp: Simplex):
    """(5 vertices as SupportPoint (5, 3), faces (6, 3) int, face mask (6,), count)."""
    order = jnp.argsort(~simp.mask, stable=True)
    P = SupportPoint(*[x[order] for x in simp.pts])
    count = jnp.sum(simp.mask)
    g = lambda i: SupportPoint(*[x[i] for x in P])  # noqa: E731

    # tetrahedron (count 4)
    tet = _stack_pts([g(0), g(1), g(2), g(3), g(3)])
    # triangle + two apexes along its normal (count 3)
    nu = _unit(jnp.cross(P.w[1] - P.w[0], P.w[2] - P.w[0]))
    tri = _stack_pts([g(0), g(1), g(2), support_m(nu), support_m(-nu)])
    # segment as the bipyramid's axis, triangle of perpendicular supports (count 1, 2)
    e0 = jnp.array([0.57735, 0.57735, 0.57735], P.w.dtype)
    q1, q2 = support_m(e0), support_m(-e0)
    far = safe_norm(q1.w - P.w[0]) >= safe_norm(q2.w - P.w[0])
    q_pt = _select(far, q1, q2)
    q_pt = _select(count >= 2, g(1), q_pt)
    ax = _unit(q_pt.w - P.w[0])
    b1, b2 = _perp_basis(ax)
    ring = [support_m(jnp.cos(2 * jnp.pi * k / 3) * b1 + jnp.sin(2 * jnp.pi * k / 3) * b2) for k in range(3)]
    seg = _stack_pts(ring + [g(0), q_pt])

    verts = _select(count == 4, tet, _select(count == 3, tri, seg))
    faces = jnp.where(count == 4, jnp.array(_TET), jnp.array(_BIPYR))
    fmask = jnp.where(count == 4, jnp.array([1, 1, 1, 1, 0, 0], bool), jnp.ones(6, bool))
    nvert = jnp.where(count == 4, 4, 5)
    # orient every face outwards (away from the centroid)
    c = jnp.sum(verts.w * (jnp.arange(5) < nvert)[:, None], axis=0) / nvert
    Vi, Vj, Vk = verts.w[faces[:, 0]], verts.w[faces[:, 1]], verts.w[faces[:, 2]]
    flip = jnp.sum(jnp.cross(Vj - Vi, Vk - Vi) * (c - Vi), axis=-1) > 0.0
    faces = jnp.where(flip[:, None], faces[:, jnp.array([0, 2, 1])], faces)
    return verts, faces, fmask, nvert


def _face_geometry(Vw, F, fvalid, scale):
    Vi, Vj, Vk = Vw[F[:, 0]], Vw[F[:, 1]], Vw[F[:, 2]]
    nrm = jnp.cross(Vj - Vi, Vk - Vi)
    area = safe_norm(nrm)
    good = fvalid & (area > 1e-14 * scale * scale)  # (near-)degenerate faces have no reliable normal
    nu = nrm / jnp.where(good, area, 1.0)[:, None]
    dist = jnp.sum(nu * Vi, axis=-1)
    return nu, dist, good


def epa(support_m, simp: Simplex, max_iter: int, scale, tol=1e-11, _debug=False):
    """See the module docstring. ``tol`` is the support-gap tolerance relative to ``scale``."""
    NV = 5 + max_iter
    NF = 2 * NV
    v0, f0, m0, nv0 = _initial_polytope(support_m, simp)
    dt = v0.w.dtype
    V = SupportPoint(*[jnp.zeros((NV, 3), dt).at[:5].set(x) for x in v0])
    F = jnp.zeros((NF, 3), jnp.int32).at[:6].set(f0.astype(jnp.int32))
    fvalid = jnp.zeros(NF, bool).at[:6].set(m0)
    abs_tol = tol * scale

    def cond(state):
        _, _, _, nv, done, it = state
        return ~done & (it < max_iter)

    def body(state):
        V, F, fvalid, nv, done, it = state
        nu, dist, good = _face_geometry(V.w, F, fvalid, scale)
        f = jnp.argmin(jnp.where(good, dist, jnp.inf))
        sp = support_m(nu[f])
        gap = nu[f] @ sp.w - dist[f]
        conv = (gap <= abs_tol) | (nv >= NV)
        # add the vertex, remove visible faces, stitch the horizon
        V2 = SupportPoint(*[x.at[nv].set(y) for x, y in zip(V, sp)])
        Vi = V.w[F[:, 0]]
        vis = fvalid & (jnp.sum(nu * (sp.w - Vi), axis=-1) > abs_tol)
        vis = vis.at[f].set(True)
        E = jnp.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]], axis=0)  # (3NF, 2)
        evis = jnp.concatenate([vis, vis, vis])
        table = jnp.zeros((NV, NV), jnp.int32).at[E[:, 0], E[:, 1]].add(evis.astype(jnp.int32))
        horizon = evis & (table[E[:, 1], E[:, 0]] == 0)
        fvalid2 = fvalid & ~vis
        free_idx = jnp.nonzero(~fvalid2, size=NF, fill_value=NF)[0]
        rank = jnp.cumsum(horizon) - 1
        slot = jnp.where(horizon, free_idx[jnp.clip(rank, 0, NF - 1)], NF)
        newF = jnp.stack([E[:, 0], E[:, 1], jnp.full(E.shape[0], nv, jnp.int32)], axis=1)
        F2 = F.at[slot].set(newF, mode="drop")
        fvalid2 = fvalid2.at[slot].set(True, mode="drop")
        overflow = jnp.sum(horizon) > jnp.sum(~(fvalid & ~vis))
        stop = conv | overflow
        V = _select(stop, V, V2)
        F = jnp.where(stop, F, F2)
        fvalid = jnp.where(stop, fvalid, fvalid2)
        nv = jnp.where(stop, nv, nv + 1)
        return V, F, fvalid, nv, stop, it + 1

    state = (V, F, fvalid, nv0.astype(jnp.int32), jnp.asarray(False), jnp.asarray(0, jnp.int32))
    V, F, fvalid, nv, done, it = jax.lax.while_loop(cond, body, state)
    if _debug:
        return V, F, fvalid, nv
    nu, dist, good = _face_geometry(V.w, F, fvalid, scale)
    # barycentric weights of the origin's projection dist * nu on every face
    W = V.w[F]  # (NF, 3, 3)
    e1, e2 = W[:, 1] - W[:, 0], W[:, 2] - W[:, 0]
    a11, a12, a22 = jnp.sum(e1 * e1, -1), jnp.sum(e1 * e2, -1), jnp.sum(e2 * e2, -1)
    b1, b2 = -jnp.sum(e1 * W[:, 0], -1), -jnp.sum(e2 * W[:, 0], -1)
    det = a11 * a22 - a12 * a12
    sdet = jnp.where(det > 0.0, det, 1.0)
    l1 = (b1 * a22 - b2 * a12) / sdet
    l2 = (a11 * b2 - a12 * b1) / sdet
    lam = jnp.stack([1.0 - l1 - l2, l1, l2], axis=-1)
    # the nearest face; among coplanar faces at the same distance (touching shapes, where
    # the origin lies on a face of M that EPA triangulated) the one holding the projection
    inside = jnp.all(lam >= -1e-9, axis=-1)
    f = jnp.argmin(jnp.where(good, dist + jnp.where(inside, 0.0, 1e-12 * scale), jnp.inf))
    pts = SupportPoint(*[x[F[f]] for x in V])
    return pts, lam[f], nu[f], dist[f], it
