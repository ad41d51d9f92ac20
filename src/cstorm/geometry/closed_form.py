"""Closed-form signed distances: every shape vs a half-space `Plane`, and the sphere /
capsule / box / cylinder pairs that have one (segment-segment closest points after
Ericson, *Real-Time Collision Detection* 5.1.9; point-box and point-cylinder by
clamping). Differentiated directly by JAX.

Every function takes ``(shape_a, R_a, t_a, shape_b, R_b, t_b)`` with ``R`` (3, 3) and
``t`` (3,) the pose "world from shape" and returns ``(d, p_a, p_b, n)`` in world
coordinates: ``d`` scalar (< 0 when penetrating), witness points ``p_a`` (3,) on a and
``p_b`` (3,) on b, ``n`` (3,) unit normal from b towards a, with ``p_a - p_b = d n``.

Ties (documented choices; values and gradients stay finite):
- a face or edge parallel to a plane (to 1e-12 in the direction cosines): the witness
  is the centre of the tied feature (box face or edge centre, cylinder cap centre or
  side-line midpoint, capsule centre); for a mesh, the lowest-index deepest vertex;
- parallel segments (capsule-capsule): the midpoint of the overlap of their projections,
  or the nearer end when they do not overlap;
- coincident sphere centres / intersecting capsule axes: ``n = cross(axis_a, axis_b)``
  normalized (sign towards a's centre), or world +z when that is zero too;
- a sphere centre inside a box or cylinder at equal depth to several faces: the first
  face in the order x, y, z (box) or side before cap (cylinder).
"""

from __future__ import annotations

import jax.numpy as jnp

from ..spatial import safe_norm
from .shapes import Box, Capsule, ConvexMesh, Cylinder, Plane, Sphere

_EPS_PAR = 1e-10  # 1 - (u_a . u_b)^2 below which two segments are treated as parallel
_EPS_DIST = 1e-14  # distance below which a direction is undefined (tie)


def _unit_or(v, fallback, eps=_EPS_DIST):
    """v / |v| where |v| > eps, else ``fallback`` (gradient-safe)."""
    nv = safe_norm(v)
    ok = nv > eps
    return jnp.where(ok, v / jnp.where(ok, nv, 1.0), fallback), nv


_EPS_TIE = 1e-12  # |component| of a unit direction below which a face or edge is tied


def _sign0(x):
    """+1, -1, or 0 for |x| <= 1e-12 (x a component of a unit direction): the centre of
    a tied feature, so that a face or edge parallel to a plane up to rounding (a
    rotation matrix from floating-point angles) still resolves to its centre."""
    return jnp.where(x > _EPS_TIE, 1.0, jnp.where(x < -_EPS_TIE, -1.0, 0.0))


# ----------------------------------------------------------------------------- plane
def deepest_point(shape, R, t, N):
    """World point of ``shape`` (pose R, t) minimizing ``N . x`` (N unit, world), i.e. the
    support point in direction ``-N``; ties resolve to the centre of the tied feature."""
    u = R.T @ (-N)
    if isinstance(shape, Sphere):
        return t - shape.radius * N
    if isinstance(shape, Capsule):
        local = jnp.stack([0.0 * u[0], 0.0 * u[0], _sign0(u[2]) * 0.5 * shape.length])
        return R @ local + t - shape.radius * N
    if isinstance(shape, Box):
        return R @ (_sign0(u) * shape.half_extents) + t
    if isinstance(shape, Cylinder):
        uxy = u[:2]
        rho = safe_norm(uxy)
        pos = rho > _EPS_TIE
        xy = jnp.where(pos, shape.radius * uxy / jnp.where(pos, rho, 1.0), 0.0)
        local = jnp.concatenate([xy, (_sign0(u[2]) * 0.5 * shape.length)[None]])
        return R @ local + t
    if isinstance(shape, ConvexMesh):
        V = shape.vertices
        return R @ V[jnp.argmax(V @ u)] + t
    raise TypeError(f"no deepest point for {type(shape).__name__}")


def shape_plane(shape_a, R_a, t_a, plane, R_b, t_b):
    """Any bounded shape (a) vs the solid half-space `Plane` (b)."""
    N = R_b @ plane.normal
    off = plane.offset + N @ t_b
    p_a = deepest_point(shape_a, R_a, t_a, N)
    d = N @ p_a - off
    p_b = p_a - d * N
    return d, p_a, p_b, N


# ----------------------------------------------------------------------------- sphere / capsule
def _segment(shape, R, t):
    """(centre (3,), unit axis (3,), half length, radius) of a sphere or capsule."""
    if isinstance(shape, Sphere):
        return t, R[:, 2], jnp.zeros_like(shape.radius), shape.radius
    return t, R[:, 2], 0.5 * shape.length, shape.radius


def segment_segment_params(c_a, u_a, h_a, c_b, u_b, h_b):
    """Parameters (s, t) of closest points ``c_a + s u_a``, ``c_b + t u_b`` of two
    segments (unit axes u, half lengths h >= 0). Parallel segments: the midpoint of the
    overlap of b's projection on a's range (or the nearer end), then t by projection."""
    r = c_a - c_b
    b = u_a @ u_b
    c = u_a @ r
    f = u_b @ r
    denom = 1.0 - b * b
    par = denom < _EPS_PAR
    # general case: unconstrained s, clamp, then t, clamp, then re-solve s
    s_gen = jnp.clip((b * f - c) / jnp.where(par, 1.0, denom), -h_a, h_a)
    # parallel: b's ends project on a's line at -c +- h_b b
    lo = jnp.maximum(-h_a, -c - h_b * jnp.abs(b))
    hi = jnp.minimum(h_a, -c + h_b * jnp.abs(b))
    s_par = jnp.clip(0.5 * (lo + hi), -h_a, h_a)
    s = jnp.where(par, s_par, s_gen)
    t_raw = f + b * s
    t = jnp.clip(t_raw, -h_b, h_b)
    s = jnp.where(t_raw == t, s, jnp.clip(t * b - c, -h_a, h_a))
    return s, t


def capsule_capsule(shape_a, R_a, t_a, shape_b, R_b, t_b):
    """Sphere or capsule (a) vs sphere or capsule (b)."""
    c_a, u_a, h_a, r_a = _segment(shape_a, R_a, t_a)
    c_b, u_b, h_b, r_b = _segment(shape_b, R_b, t_b)
    s, t = segment_segment_params(c_a, u_a, h_a, c_b, u_b, h_b)
    q_a = c_a + s * u_a
    q_b = c_b + t * u_b
    # fallback normal when the core points coincide
    both_round = isinstance(shape_a, Sphere) and isinstance(shape_b, Sphere)
    ez = jnp.array([0.0, 0.0, 1.0], dtype=q_a.dtype)
    if both_round:
        fb = ez
    else:
        cx = jnp.cross(u_a, u_b)
        cx = jnp.where((c_a - c_b) @ cx < 0.0, -cx, cx)
        fb, _ = _unit_or(cx, ez, 1e-9)
    n, dist = _unit_or(q_a - q_b, fb)
    d = dist - r_a - r_b
    return d, q_a - r_a * n, q_b + r_b * n, n


# ----------------------------------------------------------------------------- point-box / point-cylinder
def point_box(x, R_b, t_b, h):
    """Signed distance of the world point ``x`` (3,) to the box of half extents ``h`` (3,)
    at pose ``(R_b, t_b)``: ``(d, p_b, n)`` with ``p_b`` (3,) the nearest surface point,
    ``n`` (3,) the unit outward normal at it (from the box towards ``x``), ``x - p_b = d n``.
    Outside: Euclidean distance to the clamped point (C1 in ``x``). Inside: minus the depth
    below the nearest face (ties: the first face in the order x, y, z; ``+`` side at 0)."""
    q = R_b.T @ (x - t_b)  # the point in the box frame
    cl = jnp.clip(q, -h, h)
    outside = jnp.any(jnp.abs(q) > h)
    n_out, dist = _unit_or(q - cl, jnp.zeros(3, q.dtype))
    depth = h - jnp.abs(q)
    k = jnp.argmin(depth)
    e = jnp.eye(3, dtype=q.dtype)[k]
    sk = jnp.where(q[k] >= 0.0, 1.0, -1.0)
    n_in = sk * e
    surf_in = q + e * (sk * h[k] - q[k])
    n_loc = jnp.where(outside & (dist > _EPS_DIST), n_out, n_in)
    surf = jnp.where(outside, cl, surf_in)
    d = jnp.where(outside, dist, -depth[k])
    return d, R_b @ surf + t_b, R_b @ n_loc


def point_cylinder(x, R_b, t_b, radius, length):
    """Signed distance of the world point ``x`` (3,) to the cylinder (axis local z,
    ``length`` the full length) at pose ``(R_b, t_b)``: ``(d, p_b, n)`` as in `point_box`.
    Ties: on the axis the radial direction is local +x; inside at equal depth to the
    side and a cap, the side."""
    rc, hl = radius, 0.5 * length
    q = R_b.T @ (x - t_b)
    qxy, z = q[:2], q[2]
    ex = jnp.array([1.0, 0.0], dtype=q.dtype)
    radial, rho = _unit_or(qxy, ex)
    out_side = rho > rc
    out_cap = jnp.abs(z) > hl
    outside = out_side | out_cap
    cl = jnp.concatenate([jnp.where(out_side, rc * radial, qxy), jnp.clip(z, -hl, hl)[None]])
    n_out, dist = _unit_or(q - cl, jnp.zeros(3, q.dtype))
    side_depth = rc - rho
    cap_depth = hl - jnp.abs(z)
    sz = jnp.where(z >= 0.0, 1.0, -1.0)
    use_side = side_depth <= cap_depth
    n_in = jnp.where(use_side, jnp.concatenate([radial, jnp.zeros(1, q.dtype)]), jnp.array([0.0, 0.0, 1.0], q.dtype) * sz)
    surf_in = jnp.where(use_side, jnp.concatenate([rc * radial, z[None]]), jnp.concatenate([qxy, (sz * hl)[None]]))
    n_loc = jnp.where(outside & (dist > _EPS_DIST), n_out, n_in)
    surf = jnp.where(outside, cl, surf_in)
    d = jnp.where(outside, dist, -jnp.minimum(side_depth, cap_depth))
    return d, R_b @ surf + t_b, R_b @ n_loc


def point_shape(x, shape, R_b, t_b):
    """Signed distance of the world point ``x`` (3,) to a shape at pose ``(R_b, t_b)``:
    ``(d, p_b, n)``, ``p_b`` the nearest point of the shape's surface, ``n`` the unit
    normal from the shape towards ``x``, ``x - p_b = d n`` (``d < 0`` inside). For a
    `Sphere`, `Capsule`, `Box`, `Cylinder` or `Plane` (closed forms; a point at a
    sphere's centre or on a capsule's axis gets the normal world +z / local +x)."""
    if isinstance(shape, Box):
        return point_box(x, R_b, t_b, shape.half_extents)
    if isinstance(shape, Cylinder):
        return point_cylinder(x, R_b, t_b, shape.radius, shape.length)
    if isinstance(shape, Plane):
        N = R_b @ shape.normal
        d = N @ x - shape.offset - N @ t_b
        return d, x - d * N, N
    if isinstance(shape, (Sphere, Capsule)):
        c, u, hl, r = _segment(shape, R_b, t_b)
        s = jnp.clip(u @ (x - c), -hl, hl)
        fb = jnp.array([0.0, 0.0, 1.0], x.dtype) if isinstance(shape, Sphere) else R_b[:, 0]
        n, dist = _unit_or(x - c - s * u, fb)
        return dist - r, c + s * u + r * n, n
    raise TypeError(f"no point distance for {type(shape).__name__}")


# ----------------------------------------------------------------------------- sphere-box / sphere-cylinder
def sphere_box(sphere, R_a, t_a, box, R_b, t_b):
    """Sphere (a) vs box (b): the centre's signed distance minus the radius."""
    d, p_b, n = point_box(t_a, R_b, t_b, box.half_extents)
    r = sphere.radius
    return d - r, t_a - r * n, p_b, n


def sphere_cylinder(sphere, R_a, t_a, cyl, R_b, t_b):
    """Sphere (a) vs cylinder (b): the centre's signed distance minus the radius."""
    d, p_b, n = point_cylinder(t_a, R_b, t_b, cyl.radius, cyl.length)
    r = sphere.radius
    return d - r, t_a - r * n, p_b, n


def closed_form_for(shape_a, shape_b):
    """The closed-form function for the ordered pair (a, b), or None."""
    round_ = (Sphere, Capsule)
    if isinstance(shape_b, Plane) and not isinstance(shape_a, Plane):
        return shape_plane
    if isinstance(shape_a, round_) and isinstance(shape_b, round_):
        return capsule_capsule
    if isinstance(shape_a, Sphere) and isinstance(shape_b, Box):
        return sphere_box
    if isinstance(shape_a, Sphere) and isinstance(shape_b, Cylinder):
        return sphere_cylinder
    return None
