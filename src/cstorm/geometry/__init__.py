"""Collision geometry: shapes and the signed distance between them (with witness points,
normal and exact derivatives)."""

from .shapes import Shape, Sphere, Capsule, Box, Cylinder, Plane, ConvexMesh
from .distance import signed_distance

__all__ = ["Shape", "Sphere", "Capsule", "Box", "Cylinder", "Plane", "ConvexMesh", "signed_distance"]
