"""Signed distance between two collision shapes, with witness points and normal.

``signed_distance(shape_a, pose_a, shape_b, pose_b, method="auto")``

- ``shape_a``, ``shape_b``: `Sphere`, `Capsule`, `Box`, `Cylinder`, `ConvexMesh` or
  `Plane` (the solid half-space ``{x : n . x <= offset}`` in its frame; at most one of
  the two may be a plane).
- ``pose_a``, ``pose_b``: (4, 4) homogeneous transforms "world from shape".

Returns ``(d, p_a, p_b, n)`` in world coordinates:

- ``d`` scalar: the distance when separated, minus the penetration depth (the length of
  the shortest translation that separates them) when penetrating;
- ``p_a`` (3,), ``p_b`` (3,): witness points on a and on b (when penetrating, the
  deepest point of each inside the other along ``n``), with ``p_a - p_b = d n``;
- ``n`` (3,): unit normal from b towards a: moving a along ``n`` increases ``d``, and
  ``d d / d t_a = n`` for a translation ``t_a`` of a.

Dispatch is static (on the Python types at trace time): closed forms for every shape vs
a plane, sphere/capsule pairs, sphere-box and sphere-cylinder (`closed_form`); GJK/EPA
with implicit-function derivatives for the other pairs (`convex`), spheres and capsules
entering as a point / segment inflated by their radius. ``method="iterative"`` forces
the GJK/EPA path where a closed form exists (tests compare the two). Works under
``jit``, ``vmap``, ``grad``, ``jacfwd``; values and first derivatives are finite at ties
(documented in `closed_form` and `convex`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..errors import ShapeError
from .closed_form import closed_form_for
from .convex import core_signed_distance
from .shapes import Plane, Shape
from .support import core_of


def _split(T):
    T = jnp.asarray(T)
    if T.shape != (4, 4):
        raise ShapeError(f"signed_distance: a pose must have shape (4, 4), got {T.shape}")
    return T[:3, :3], T[:3, 3]


def signed_distance(shape_a, pose_a, shape_b, pose_b, method: str = "auto"):
    """Signed distance ``(d, p_a, p_b, n)`` between two shapes; see the module docstring.

    Compiled once per pair of shape types (and mesh size) and ``method``: a call with
    new sizes or poses reuses the compiled code, so a loop of eager calls over many
    pairs does not compile (and map into memory) new code for each."""
    for name, s in (("shape_a", shape_a), ("shape_b", shape_b)):
        if not isinstance(s, Shape):
            raise ShapeError(f"signed_distance: {name} must be a cstorm shape, got {type(s).__name__}")
    if method not in ("auto", "iterative"):
        raise ShapeError(f"signed_distance: method must be 'auto' or 'iterative', got {method!r}")
    if isinstance(shape_a, Plane) and isinstance(shape_b, Plane):
        raise ShapeError("signed_distance: plane vs plane is not supported (unbounded)")
    return _signed_distance_jit(shape_a, jnp.asarray(pose_a), shape_b, jnp.asarray(pose_b), method=method)


def _signed_distance(shape_a, pose_a, shape_b, pose_b, method):
    if isinstance(shape_a, Plane):
        d, p_b, p_a, n = _signed_distance(shape_b, pose_b, shape_a, pose_a, method)
        return d, p_a, p_b, -n
    Ra, ta = _split(pose_a)
    Rb, tb = _split(pose_b)
    f = closed_form_for(shape_a, shape_b)
    if f is not None and (method == "auto" or isinstance(shape_b, Plane)):
        return f(shape_a, Ra, ta, shape_b, Rb, tb)
    g = closed_form_for(shape_b, shape_a)
    if g is not None and method == "auto":
        d, p_b, p_a, n = g(shape_b, Rb, tb, shape_a, Ra, ta)
        return d, p_a, p_b, -n
    _, r_a = core_of(shape_a)
    _, r_b = core_of(shape_b)
    d, q_a, q_b, n = core_signed_distance(shape_a, pose_a, shape_b, pose_b)
    return d - r_a - r_b, q_a - r_a * n, q_b + r_b * n, n


_signed_distance_jit = jax.jit(_signed_distance, static_argnames=("method",))
