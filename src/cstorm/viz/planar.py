"""Side-view (x-z plane) drawings of a model's collision shapes with matplotlib.

Shapes are drawn as their outline projected on the world x-z plane: capsules as stadiums,
spheres as discs, boxes and cylinders as their projected hull. Planes (the ground) are
drawn as a hatched band.
"""

from __future__ import annotations

import numpy as np

from ..dynamics.kinematics import forward_kinematics
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


# ---------------------------------------------------------------------------------------
# Helpers for plots and animations of whole motions (precomputed body poses)
# ---------------------------------------------------------------------------------------
def robot_outlines(model, poses, n=24):
    """Outlines (list of (k, 2) arrays, x-z) of the model's non-plane collision shapes
    for body poses ``poses`` (n_bodies, 4, 4) (world from body)."""
    out = []
    Tg_all = np.asarray(model.geom_poses)
    for shape, b, Tg in zip(model.geoms, model.geom_bodies, Tg_all):
        if isinstance(shape, Plane):
            continue
        T = (poses[b] if b >= 0 else np.eye(4)) @ Tg
        out.append(shape_outline(shape, T, n=n))
    return out


def robot_extent(model):
    """A length scale of the robot (m): the largest collision-shape size, summed over
    bodies (the diameter of the robot stretched out), at least 0.1."""
    total = 0.0
    for shape in model.geoms:
        if isinstance(shape, Sphere):
            total += 2 * float(shape.radius)
        elif isinstance(shape, (Capsule, Cylinder)):
            total += float(shape.length) + 2 * float(shape.radius)
        elif isinstance(shape, Box):
            total += 2 * float(np.max(np.asarray(shape.half_extents)))
        elif isinstance(shape, ConvexMesh):
            v = np.asarray(shape.vertices)
            total += float(np.max(np.ptp(v, axis=0)))
    return max(total, 0.1)


def plane_polygon(obstacle, xlim, zlim):
    """The solid side of a `Plane` obstacle clipped to the box ``xlim x zlim`` in the
    x-z plane (y = 0): (k, 2) polygon, or None if it misses the box. Also returns the
    boundary segment ((2, 2) or None)."""
    T = np.asarray(obstacle.pose)
    n_local = np.asarray(obstacle.shape.normal, float)
    n = T[:3, :3] @ (n_local / np.linalg.norm(n_local))
    c = float(obstacle.shape.offset) + float(n @ T[:3, 3])
    a, b = n[0], n[2]
    if abs(a) < 1e-12 and abs(b) < 1e-12:
        return None, None
    box = [(xlim[0], zlim[0]), (xlim[1], zlim[0]), (xlim[1], zlim[1]), (xlim[0], zlim[1])]
    inside = lambda p: a * p[0] + b * p[1] <= c + 1e-12
    poly, edge = [], []
    for i in range(4):
        p, q = box[i], box[(i + 1) % 4]
        ip, iq = inside(p), inside(q)
        if ip:
            poly.append(p)
        if ip != iq:
            fp, fq = a * p[0] + b * p[1] - c, a * q[0] + b * q[1] - c
            s = fp / (fp - fq)
            x = (p[0] + s * (q[0] - p[0]), p[1] + s * (q[1] - p[1]))
            poly.append(x), edge.append(x)
    if len(poly) < 3:
        return None, None
    return np.array(poly), (np.array(edge[:2]) if len(edge) >= 2 else None)


def draw_obstacles(ax, obstacles, xlim, zlim):
    """Draw obstacles (x-z projection): planes as hatched solid regions with their
    boundary line, bounded shapes as grey polygons. Returns the artists."""
    from matplotlib.patches import Polygon

    arts = []
    for o in obstacles:
        if isinstance(o.shape, Plane):
            poly, edge = plane_polygon(o, xlim, zlim)
            if poly is None:
                continue
            arts.append(ax.add_patch(Polygon(poly, closed=True, facecolor="0.88", edgecolor="none", hatch="///",
                                             zorder=0.5)))
            if edge is not None:
                arts += ax.plot(edge[:, 0], edge[:, 1], color="0.25", lw=1.2, zorder=0.6)
        else:
            pts = shape_outline(o.shape, np.asarray(o.pose))
            arts.append(ax.add_patch(Polygon(pts, closed=True, facecolor="0.8", edgecolor="0.3", lw=1.0,
                                             hatch="..", zorder=0.5)))
    return arts


def skeleton(model, poses):
    """The robot's kinematic skeleton in x-z for body poses (n_bodies, 4, 4): returns
    ``(segments (m, 2, 2), joints (j, 2), anchors (a, 2))``. Segments join each body's
    origin to its children's origins (bodies hanging from a massless parent, such as
    the planar base's virtual ``root_x``/``root_z`` bodies, are not joined to it) and, for
    bodies without children, to the body's named frames (or, with none, to the mirror
    image of the body origin through its CoM: the far end of a rod). ``joints``: origins
    of bodies with a 1-DoF joint whose parent has mass; ``anchors``: origins of bodies
    jointed directly to the world by a 1-DoF joint (e.g. the acrobot's shoulder)."""
    mass = np.asarray(model.mass)
    com = np.asarray(model.com)
    segs, joints, anchors = [], [], []
    o = poses[:, :3, 3]
    kids = {i: [] for i in range(model.n_bodies)}
    for i, p in enumerate(model.parents):
        if p >= 0:
            kids[p].append(i)
    frames = {}
    fposes = np.asarray(model.frame_poses) if len(model.frame_names) else np.zeros((0, 4, 4))
    for b, Tf in zip(model.frame_bodies, fposes):
        if b >= 0:
            frames.setdefault(b, []).append((poses[b] @ Tf)[:3, 3])
    for i, p in enumerate(model.parents):
        one_dof = model.joints[i].nv == 1
        if p >= 0 and mass[p] > 0:
            segs.append((o[p], o[i]))
            if one_dof:
                joints.append(o[i])
        elif p < 0 and one_dof and mass[i] > 0:
            anchors.append(o[i])
        if mass[i] > 0 and not kids[i]:
            ends = frames.get(i) or [poses[i, :3, :3] @ (2 * com[i]) + o[i]]
            segs += [(o[i], e) for e in ends if np.linalg.norm(e - o[i]) > 1e-9]
    seg = np.array([[a[[0, 2]], b[[0, 2]]] for a, b in segs]).reshape(-1, 2, 2)
    J = np.array([x[[0, 2]] for x in joints]).reshape(-1, 2)
    A = np.array([x[[0, 2]] for x in anchors]).reshape(-1, 2)
    return seg, J, A
