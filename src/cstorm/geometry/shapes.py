"""Collision shapes: convex solids (and the solid half-space `Plane`) in their own frame.

Frames and conventions
----------------------
- Every shape is described in its local frame; a pose is a (4, 4) homogeneous transform
  "world from shape" (see `cstorm.spatial`).
- `Capsule` and `Cylinder` have their axis along local z, centred at the origin; `length`
  is the full length of the capsule's axis segment / of the cylinder.
- `Box` has half extents (3,) along the local axes.
- `Plane(normal, offset)` is the solid half-space ``{x : n . x <= offset}`` with
  ``n = normal / |normal|`` (the constructor stores the unit normal).
- `ConvexMesh(vertices)` is the convex hull of its (k, 3) vertices.

Sizes are JAX array leaves (differentiable: design optimization); the class is static.
Constructors validate concrete inputs and raise `cstorm.ShapeError` naming the shape and
the argument at fault.
"""

from __future__ import annotations

import numpy as np
import jax.numpy as jnp

from .._pytree import pytree_dataclass, is_concrete
from ..errors import ShapeError


def _positive(shape_name, arg, value, allow_zero=False):
    if is_concrete(value):
        a = np.asarray(value, dtype=float)
        bad = (a < 0) if allow_zero else (a <= 0)
        if not np.all(np.isfinite(a)) or np.any(bad):
            rel = ">= 0" if allow_zero else "> 0"
            raise ShapeError(f"{shape_name}: {arg} must be finite and {rel}, got {a.tolist()}")
    return jnp.asarray(value, dtype=float)


class Shape:
    """Base class of collision shapes (abstract)."""

    kind: str = "shape"


@pytree_dataclass
class Sphere(Shape):
    radius: jnp.ndarray
    kind = "sphere"

    def __post_init__(self):
        object.__setattr__(self, "radius", _positive("Sphere", "radius", self.radius))


@pytree_dataclass
class Capsule(Shape):
    radius: jnp.ndarray
    length: jnp.ndarray
    kind = "capsule"

    def __post_init__(self):
        object.__setattr__(self, "radius", _positive("Capsule", "radius", self.radius))
        object.__setattr__(self, "length", _positive("Capsule", "length", self.length, allow_zero=True))


@pytree_dataclass
class Box(Shape):
    half_extents: jnp.ndarray
    kind = "box"

    def __post_init__(self):
        h = self.half_extents
        if is_concrete(h) and np.shape(h) != (3,):
            raise ShapeError(f"Box: half_extents must have shape (3,), got {np.shape(h)}")
        object.__setattr__(self, "half_extents", _positive("Box", "half_extents", h))


@pytree_dataclass
class Cylinder(Shape):
    radius: jnp.ndarray
    length: jnp.ndarray
    kind = "cylinder"

    def __post_init__(self):
        object.__setattr__(self, "radius", _positive("Cylinder", "radius", self.radius))
        object.__setattr__(self, "length", _positive("Cylinder", "length", self.length))


@pytree_dataclass
class Plane(Shape):
    normal: jnp.ndarray
    offset: jnp.ndarray
    kind = "plane"

    def __post_init__(self):
        n, off = self.normal, self.offset
        if is_concrete(n, off):
            a = np.asarray(n, dtype=float)
            if a.shape != (3,):
                raise ShapeError(f"Plane: normal must have shape (3,), got {a.shape}")
            nn = np.linalg.norm(a)
            if not np.isfinite(nn) or nn < 1e-12:
                raise ShapeError(f"Plane: normal must be a non-zero finite vector, got {a.tolist()}")
            if not np.isfinite(float(off)):
                raise ShapeError(f"Plane: offset must be finite, got {off}")
            object.__setattr__(self, "normal", jnp.asarray(a / nn))
            object.__setattr__(self, "offset", jnp.asarray(float(off)))


@pytree_dataclass
class ConvexMesh(Shape):
    vertices: jnp.ndarray
    kind = "mesh"

    def __post_init__(self):
        v = self.vertices
        if is_concrete(v):
            a = np.asarray(v, dtype=float)
            if a.ndim != 2 or a.shape[1] != 3:
                raise ShapeError(f"ConvexMesh: vertices must have shape (k, 3), got {a.shape}")
            if not np.all(np.isfinite(a)):
                raise ShapeError("ConvexMesh: vertices contain NaN or inf")
            if a.shape[0] < 4 or np.linalg.matrix_rank(a[1:] - a[0], tol=1e-9 * max(1.0, np.abs(a).max())) < 3:
                raise ShapeError(
                    f"ConvexMesh: needs at least four non-coplanar vertices, got {a.shape[0]} "
                    "spanning fewer than three dimensions"
                )
            object.__setattr__(self, "vertices", jnp.asarray(a))


def describe(shape: Shape) -> str:
    """One-line human description used by `cstorm info`."""
    if isinstance(shape, Sphere):
        return f"sphere r={float(shape.radius):.4g}"
    if isinstance(shape, Capsule):
        return f"capsule r={float(shape.radius):.4g} length={float(shape.length):.4g}"
    if isinstance(shape, Box):
        return "box half_extents=" + np.array2string(np.asarray(shape.half_extents), precision=4)
    if isinstance(shape, Cylinder):
        return f"cylinder r={float(shape.radius):.4g} length={float(shape.length):.4g}"
    if isinstance(shape, Plane):
        return "plane n=" + np.array2string(np.asarray(shape.normal), precision=3) + f" offset={float(shape.offset):.4g}"
    if isinstance(shape, ConvexMesh):
        return f"convex mesh with {shape.vertices.shape[0]} vertices"
    return type(shape).__name__
