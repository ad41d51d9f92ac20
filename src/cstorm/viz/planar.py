"""Side-view (x-z plane) drawings of a model's collision shapes with matplotlib.

Shapes are drawn as their outline projected on the world x-z plane: capsules as stadiums,
spheres as discs, boxes and cylinders as their projected hull. Planes (the ground) are
drawn as a hatched band.
"""

from __future__ import annotations

import numpy as np

from ..geometry.shapes import Box, Capsule, ConvexMesh, Cylinder, Plane, Sphere


def _hull2d(pts):
    from scipy.spatial import ConvexHull

    try:
        h = ConvexHull(pts)
        return pts[h.vertices]
    except Exception:  # degenerate (e.g. all collinear): draw the points' bounding segment
        return pts


def shape_outline(shape, T, n=24):
    """(k, 2) outline of a shape at pose T (4, 4), projected onto x-z."""
    R, p = T[:3, :3], T[:3, 3]
    if isinstance(shape, Sphere):
        ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
        r = float(shape.radius)
        return np.stack([p[0] + r * np.cos(ang), p[2] + r * np.sin(ang)], 1)
    if isinstance(shape, Capsule):
        r, half = float(shape.radius), 0.5 * float(shape.length)
        ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
        circ = np.stack([np.cos(ang), np.zeros_like(ang), np.sin(ang)], 1) * r
        pts = []
        for s in (-1.0, 1.0):
            c = p + R @ np.array([0, 0, s * half])
            pts.append(c + circ)
        return _hull2d(np.concatenate(pts)[:, [0, 2]])
    if isinstance(shape, (Box, Cylinder, ConvexMesh)):
        if isinstance(shape, Box):
            h = np.asarray(shape.half_extents)
            local = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * h
        elif isinstance(shape, Cylinder):
            ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
            r, half = float(shape.radius), 0.5 * float(shape.length)
            ring = np.stack([r * np.cos(ang), r * np.sin(ang), np.zeros_like(ang)], 1)
            local = np.concatenate([ring + [0, 0, -half], ring + [0, 0, half]])
        else:
            local = np.asarray(shape.vertices)
        world = local @ R.T + p
        return _hull2d(world[:, [0, 2]])
    raise TypeError(f"cannot draw {type(shape).__name__}")


def draw_model(ax, model, q, *, color="C0", alpha=1.0, lw=1.0):
    """Draw the model's collision shapes at configuration q on a matplotlib axis."""
    from matplotlib.patches import Polygon
    from ..dynamics.kinematics import forward_kinematics

    Tb = np.asarray(forward_kinematics(model, q))
    artists = []
    for shape, b, Tg in zip(model.geoms, model.geom_bodies, np.asarray(model.geom_poses)):
        if isinstance(shape, Plane):
            continue
        T = (Tb[b] if b >= 0 else np.eye(4)) @ Tg
        poly = Polygon(shape_outline(shape, T), closed=True, facecolor=color, edgecolor="k", alpha=alpha, lw=lw)
        ax.add_patch(poly)
        artists.append(poly)
    return artists


def draw_ground(ax, height=0.0, xlim=(-1, 1)):
    ax.axhline(height, color="k", lw=1.0)
    ax.fill_between(list(xlim), height - 0.05, height, color="0.85", hatch="///", edgecolor="0.6", lw=0)
