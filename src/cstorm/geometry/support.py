"""Support mappings of collision shapes, split into a polytope-or-cylinder *core* and a
sphere radius (a capsule is a segment inflated by its radius, a sphere a point).

For a convex set ``C`` and a direction ``u``, the support function is
``h_C(u) = max_{x in C} u . x`` and a support point ``s_C(u)`` attains it. Signed
distances of inflated shapes follow from their cores exactly:
``sd(A + ball(r_a), B + ball(r_b)) = sd(A, B) - r_a - r_b`` with the same normal, both
when separated and when penetrating (the support function of ``C + ball(r)`` is
``h_C(u) + r |u|``).

Everything here is in the shape's local frame: ``u`` (3,) is a local direction and the
support point (3,) is in local coordinates. Ties (``u`` orthogonal to an edge or face)
pick the vertex on the ``+`` side, so support points of polytopes are always vertices.

A `Core` is a static ``kind`` plus array ``params``:

======== =============================== ==========================================
kind     params                          set
======== =============================== ==========================================
point    ()                              the origin
segment  (half_length,)                  ``{(0, 0, z) : |z| <= half_length}``
box      (half_extents (3,),)            ``{|x_i| <= h_i}``
cylinder (radius, half_length)           ``{x^2 + y^2 <= r^2, |z| <= half_length}``
mesh     (vertices (k, 3),)              convex hull of the vertices
======== =============================== ==========================================
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp

from ..spatial import safe_norm
from .shapes import Box, Capsule, ConvexMesh, Cylinder, Plane, Sphere
from ..errors import ShapeError

POLYTOPE_KINDS = ("point", "segment", "box", "mesh")
FLAT_KINDS = ("point", "segment")  # cores without interior: Minkowski differences of two
# such cores are at most 2-dimensional, so they never need EPA


@dataclass(frozen=True)
class Core:
    kind: str
    params: tuple

    @property
    def curved(self) -> bool:
        return self.kind == "cylinder"


def core_of(shape):
    """(Core, inflation radius) of a shape; the radius is a scalar array (0 for polytopes
    and cylinders)."""
    if isinstance(shape, Sphere):
        return Core("point", ()), shape.radius
    if isinstance(shape, Capsule):
        return Core("segment", (0.5 * shape.length,)), shape.radius
    if isinstance(shape, Box):
        return Core("box", (shape.half_extents,)), jnp.zeros_like(shape.half_extents[0])
    if isinstance(shape, Cylinder):
        return Core("cylinder", (shape.radius, 0.5 * shape.length)), jnp.zeros_like(shape.radius)
    if isinstance(shape, ConvexMesh):
        return Core("mesh", (shape.vertices,)), jnp.zeros_like(shape.vertices[0, 0])
    if isinstance(shape, Plane):
        raise ShapeError("Plane has no bounded core; planes are handled in closed form")
    raise ShapeError(f"unsupported shape type {type(shape).__name__}")


def _pm(u, h):
    """+h where u >= 0, -h elsewhere (elementwise)."""
    return jnp.where(u >= 0.0, h, -h)


def bounding_radius(core: Core):
    """Radius of a ball about the local origin containing the core (scalar)."""
    k, p = core.kind, core.params
    if k == "point":
        return jnp.zeros(())
    if k == "segment":
        return p[0]
    if k == "box":
        return safe_norm(p[0])
    if k == "cylinder":
        return jnp.sqrt(p[0] ** 2 + p[1] ** 2)
    return jnp.max(safe_norm(p[0], axis=-1))


def support(core: Core, u):
    """Local support point (3,) of the core in local direction u (3,)."""
    k, p = core.kind, core.params
    dt = u.dtype
    if k == "point":
        return jnp.zeros(3, dt)
    if k == "segment":
        return jnp.stack([jnp.zeros((), dt), jnp.zeros((), dt), _pm(u[2], p[0])])
    if k == "box":
        return _pm(u, p[0])
    if k == "cylinder":
        return _cylinder_point(p[0], p[1], u[:2], u[2])
    if k == "mesh":
        V = p[0]
        return V[jnp.argmax(V @ u)]
    raise ShapeError(f"unknown core kind {k}")


def _cylinder_point(r, hl, uxy, uz):
    rho = safe_norm(uxy)
    pos = rho > 0.0
    xy = jnp.where(pos, r * uxy / jnp.where(pos, rho, 1.0), 0.0)
    return jnp.concatenate([xy, _pm(uz, hl)[None]])


def support_keyed(core: Core, ref, follow_dir, follow):
    """The support point of the feature selected by the (non-differentiated) local
    direction ``ref`` (3,). For a cylinder with ``follow`` true the point slides along the
    curved surface with ``follow_dir`` (3,) (its angle about the axis follows
    ``follow_dir``; which rim, top or bottom, stays that of ``ref``); otherwise it is the
    body-fixed point ``support(core, ref)``. Used by the implicit derivatives."""
    if core.kind != "cylinder":
        return support(core, ref)
    r, hl = core.params
    fixed = _cylinder_point(r, hl, ref[:2], ref[2])
    slid = _cylinder_point(r, hl, follow_dir[:2], ref[2])
    return jnp.where(follow, slid, fixed)
