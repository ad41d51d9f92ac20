"""Conversion of cstorm shapes to other collision libraries' objects.

`to_coal(shape)`: the equivalent `coal <https://github.com/coal-library/coal>`_ (hpp-fcl)
geometry, for cross-checks and for users who mix cstorm with Pinocchio/coal. Size
conventions differ and are converted here: coal's ``Box`` takes full side lengths
(cstorm: half extents), ``Capsule`` and ``Cylinder`` take ``(radius, full length)`` along
local z (as cstorm), ``Halfspace(n, d)`` is ``{x: n.x <= d}`` (cstorm's `Plane`, a solid
half-space below ``n.x = offset``), and a `ConvexMesh` becomes coal's convex hull of its
vertices. Mind the normal: coal's points from the first shape to the second, cstorm's
from b towards a.
"""

from __future__ import annotations

import numpy as np

from .shapes import Box, Capsule, ConvexMesh, Cylinder, Plane, Sphere

__all__ = ["to_coal"]


def to_coal(shape):
    """The coal geometry equal to ``shape`` (a concrete cstorm shape). Needs ``coal``
    (``pip install coal``; an ImportError says so otherwise)."""
    try:
        import coal
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError("to_coal needs the 'coal' package (pip install coal)") from e
    if isinstance(shape, Sphere):
        return coal.Sphere(float(shape.radius))
    if isinstance(shape, Capsule):
        return coal.Capsule(float(shape.radius), float(shape.length))
    if isinstance(shape, Box):
        return coal.Box(*(2.0 * np.asarray(shape.half_extents, dtype=float)))
    if isinstance(shape, Cylinder):
        return coal.Cylinder(float(shape.radius), float(shape.length))
    if isinstance(shape, Plane):
        return coal.Halfspace(np.asarray(shape.normal, dtype=float), float(shape.offset))
    if isinstance(shape, ConvexMesh):
        pts = coal.StdVec_Vec3s()
        for v in np.asarray(shape.vertices, dtype=float):
            pts.append(v)
        return coal.Convex.convexHull(pts, False, "")
    raise TypeError(f"to_coal: no coal equivalent for {type(shape).__name__}")
