"""Signed distance between two convex cores by GJK (separated) then EPA (penetrating),
polished by Newton's method on the KKT conditions for curved cores, with a
`jax.custom_jvp` whose tangents come from the implicit function theorem (`kkt`).

``core_signed_distance(shape_a, pose_a, shape_b, pose_b)`` -> ``(d, p_a, p_b, n)`` of the
*cores* (`support.core_of`: spheres as points, capsules as segments; boxes, cylinders and
meshes as themselves), world frame, same conventions as `signed_distance`. The caller
inflates by the radii.

Touching or flat cases (documented choices, finite values and tangents):
- when GJK ends within 1e-8 (relative to the shapes' size) of the origin without
  containing it, the shapes count as touching and EPA decides (its face normal); when
  it ends on a simplex smaller than the supporting face of the Minkowski difference (a
  symmetric tie), the face's other vertices are added (`_complete_face`), so that the
  tangents keep the witnesses on the whole face;
- cores whose Minkowski difference is flat (point/segment vs point/segment) never run
  EPA: when they touch, ``d = 0`` and ``n`` is the unit centre-to-centre direction (a to
  b reversed), or world +z when the centres coincide; its tangent is zero there;
- shapes touching exactly (GJK stops on a lower-dimensional simplex through the origin)
  are handed to EPA from a bipyramid around that simplex; ``d`` is then ~0 with EPA's
  face normal.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from ..spatial import safe_norm
from .gjk import CONTAINS, SupportPoint, gjk
from .epa import epa
from .kkt import FIXED, PEN_FACE, PEN_Z, SEP, Keys, implicit_tangent, merge_duplicates, newton_polish, outputs
from .support import FLAT_KINDS, bounding_radius, core_of, support


def _unit(x):
    nx = safe_norm(x)
    return x / jnp.where(nx > 0.0, nx, 1.0)


def _make_support(core_a, Ra, ta, core_b, Rb, tb):
    def support_m(dvec):
        ra = Ra.T @ dvec
        rb = Rb.T @ (-dvec)
        a = Ra @ support(core_a, ra) + ta
        b = Rb @ support(core_b, rb) + tb
        return SupportPoint(a - b, a, b, ra, rb)

    return support_m


_TOUCH = 1e-8  # |z| / scale below which GJK's result counts as contact (EPA decides)
_TILT = 1e-6  # rad: tilt of the probe directions that find the other vertices of a face


def _complete_face(sm, pts, mask, n, zlen, scale):
    """Complete GJK's reduced simplex (compacted in 3 slots, ``mask``) to the supporting
    face of the Minkowski difference M when that face is larger than the simplex.

    GJK reduces its simplex to the smallest one holding the closest point ``z`` (here
    ``zlen n``); at a symmetric tie (``z`` on a diagonal of a face of M, e.g. a sphere
    above a box face's centre) that is a segment that is not a face of M, and the
    implicit tangent would then keep ``z`` on that segment. Probing the support of M in
    directions ``-n`` tilted by ``_TILT`` finds the other vertices of the face
    ``{w : w . n = |z|}``; those on it (to 1e-10 scale) and affinely independent of the
    simplex are added with weight 0. Returns ``(pts, mask)``."""
    a = jnp.where(jnp.abs(n[0]) < 0.6, jnp.array([1.0, 0.0, 0.0], n.dtype), jnp.array([0.0, 1.0, 0.0], n.dtype))
    b1 = _unit(jnp.cross(n, a))
    b2 = jnp.cross(n, b1)
    for e in (b1, b2, -b1, -b2):
        c = sm(-n + _TILT * e)
        cnt = jnp.sum(mask)
        W = pts.w
        on = c.w @ n - zlen <= 1e-10 * scale
        indep1 = safe_norm(c.w - W[0]) > 1e-9 * scale
        indep2 = safe_norm(jnp.cross(W[1] - W[0], c.w - W[0])) > 1e-9 * scale * scale
        ok = on & (((cnt == 1) & indep1) | ((cnt == 2) & indep2))
        slot = jnp.minimum(cnt, 2)
        pts = SupportPoint(*[jnp.where(ok, x.at[slot].set(y), x) for x, y in zip(pts, c)])
        mask = mask.at[slot].set(mask[slot] | ok)
    return pts, mask


@functools.lru_cache(maxsize=None)
def _config(kind_a, kind_b):
    curved = "cylinder" in (kind_a, kind_b)
    return dict(
        gjk_iter=64 if curved else 32,
        epa_iter=32 if curved else 40,
        polish=6 if curved else 0,
        flat=(kind_a in FLAT_KINDS and kind_b in FLAT_KINDS),
    )


def _solve(theta):
    """(x (7,), Keys) at the solution; no gradients flow through here."""
    theta = jax.lax.stop_gradient(theta)
    shape_a, Ta, shape_b, Tb = theta
    core_a, _ = core_of(shape_a)
    core_b, _ = core_of(shape_b)
    cfg = _config(core_a.kind, core_b.kind)
    Ra, ta, Rb, tb = Ta[:3, :3], Ta[:3, 3], Tb[:3, :3], Tb[:3, 3]
    dt = Ta.dtype
    scale = jnp.maximum(bounding_radius(core_a) + bounding_radius(core_b), 1e-3)
    sm = _make_support(core_a, Ra, ta, core_b, Rb, tb)
    cdir = tb - ta
    cdir = jnp.where(safe_norm(cdir) > 1e-12 * scale, cdir, jnp.array([1.0, 0.0, 0.0], dt))
    simp, status, _ = gjk(sm, sm(cdir), cfg["gjk_iter"], scale)

    # separated (or stopped): the reduced simplex, compacted to 3 slots
    order = jnp.argsort(~simp.mask, stable=True)[:3]
    s_pts = SupportPoint(*[x[order] for x in simp.pts])
    s_mask = simp.mask[order]
    s_lam = simp.lam[order]
    z = simp.v
    contact = status == CONTAINS
    if not cfg["flat"]:
        # GJK that stalls within 1e-8 scale of the origin has reached the surface (touching
        # or a sliver of overlap) and the direction of its z is rounding noise: let EPA
        # find the face there
        contact = contact | (safe_norm(z) <= _TOUCH * scale)
        s_pts, s_mask = _complete_face(sm, s_pts, s_mask, _unit(z), safe_norm(z), scale)
    ex = jnp.array([0.0, 0.0, 1.0], dt)

    if cfg["flat"]:
        fb = _unit(ta - tb)
        fb = jnp.where(safe_norm(ta - tb) > 1e-12 * scale, fb, ex)
        n = jnp.where(contact, fb, _unit(z))
        mode = jnp.where(contact, FIXED, SEP)
        pts, mask, lam, orient = s_pts, s_mask, s_lam, jnp.ones((), dt)
    else:
        e_pts, e_lam, nu, dist, _ = epa(sm, simp, cfg["epa_iter"], scale)
        n = jnp.where(contact, -nu, _unit(z))
        pts = jax.tree_util.tree_map(lambda p, q: jnp.where(contact, p, q), e_pts, s_pts)
        mask = jnp.where(contact, jnp.ones(3, bool), s_mask)
        lam = jnp.where(contact, e_lam, s_lam)
        W = e_pts.w
        cr = jnp.cross(W[1] - W[0], W[2] - W[0])
        orient = jnp.where(cr @ nu >= 0.0, 1.0, -1.0).astype(dt)
        mode = jnp.where(contact, PEN_Z, SEP)

    lam = jnp.where(mask, lam, 0.0)
    follow_a = jnp.asarray(core_a.curved) & (safe_norm((Ra.T @ n)[:2]) > 1e-6)
    follow_b = jnp.asarray(core_b.curved) & (safe_norm((Rb.T @ n)[:2]) > 1e-6)
    keys = Keys(pts.ref_a, pts.ref_b, mask, follow_a, follow_b, jnp.asarray(mode, jnp.int32), orient, n,
                1.0 / (scale * scale))
    if not cfg["flat"]:
        # how a penetrating normal is determined: from z when the depth gives a direction,
        # from the (non-degenerate) face when shallow, else held fixed
        Wf = pts.w
        area = safe_norm(jnp.cross(Wf[1] - Wf[0], Wf[2] - Wf[0]))
        deep = safe_norm(lam @ Wf) > 1e-9 * scale
        face_ok = (area > 1e-10 * scale * scale) & ~(follow_a | follow_b)
        pen_mode = jnp.where(deep, PEN_Z, jnp.where(face_ok, PEN_FACE, FIXED))
        keys = keys._replace(mode=jnp.where(contact, pen_mode, SEP).astype(jnp.int32))
    mu = jnp.sum(jnp.where(mask, pts.w @ (lam @ pts.w), 0.0)) / jnp.maximum(jnp.sum(mask), 1)
    x = jnp.concatenate([lam, mu[None], n])
    x, keys = merge_duplicates(x, theta, keys)
    if cfg["polish"]:
        x, keys = newton_polish(x, theta, keys, cfg["polish"])
    return x, keys


@jax.custom_jvp
def core_signed_distance(shape_a, pose_a, shape_b, pose_b):
    theta = (shape_a, pose_a, shape_b, pose_b)
    x, keys = _solve(theta)
    return outputs(x, theta, keys)


@core_signed_distance.defjvp
def _core_signed_distance_jvp(primals, tangents):
    theta = tuple(primals)
    x, keys = _solve(theta)
    dx = implicit_tangent(x, theta, keys, tuple(tangents))
    return jax.jvp(lambda x_, th: outputs(x_, th, keys), (x, theta), (dx, tuple(tangents)))
