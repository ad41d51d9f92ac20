"""The robot's surroundings: static obstacle shapes placed in the world, and which robot
geoms may touch which obstacles (DESIGN.md, "The method", item 3).

An `Environment` is a JAX pytree: obstacle kinds, names and the pair selection are
static (they key compilation); obstacle poses and sizes are array leaves, so gradients
w.r.t. e.g. a step height or an incline angle's normal come for free, and many
environments of one structure (say, inclines of several angles) can be stacked and
``vmap``-ed through one compiled function.

Frames and conventions
----------------------
- An obstacle is a shape (`Sphere`, `Capsule`, `Box`, `Cylinder`, `ConvexMesh`, `Plane`)
  at a (4, 4) pose "world from shape" (see `cstorm.spatial`). A `Plane` is the solid
  half-space ``{x : n . x <= offset}`` in its frame.
- Obstacles are static (zero velocity). Names are unique within an environment.
- Pair selection (``pairs``): ``None`` means every robot geom (of a moving body) against
  every obstacle. Otherwise a sequence of ``(geom, obstacle)`` name patterns,
  shell-style (``fnmatch``: ``"*"``, ``"foot*"``, ``"?"``), matched case-sensitively
  against ``model.geom_names`` and the obstacle names; the selected pairs are the union
  over entries, each pair once, in (geom order, obstacle order). An obstacle pattern
  that matches no obstacle raises `InputError` here; a geom pattern that matches no
  geom of the model raises `InputError` in `cstorm.contact_forces` (the environment does
  not know the model).
- Self-collision is off by default; ``self_collision`` opts in per pair of robot geom
  name patterns ``(geom_a, geom_b)``. Pairs of geoms on the same body are never used.
- Geoms attached to the world (``geom_bodies == -1``) and robot geoms that are planes
  are ignored by the default selection; naming them explicitly in ``pairs`` is an error.
- How an obstacle makes contact (`Obstacle`'s ``contact``, static): ``"features"`` — each
  contact feature of a robot shape (capsule end spheres, box corners, cylinder rim
  points, mesh vertices, a sphere's centre) gets its own force from its signed distance
  to the obstacle, so a flat robot face resting on a flat obstacle face (the ground, a
  platform top, a step) is held at several points; ``"near_point"`` — one near-point
  pair between the robot shape and the obstacle (`cstorm.signed_distance`);
  ``"both"`` — the two together. Defaults: features for planes (the only choice) and
  boxes, a near-point pair for every other obstacle. Features see only the robot's
  feature points: a capsule lying across a box's edge between its end spheres, or a box
  corner pressing into the middle of a robot face, is felt only with ``"both"`` or
  ``"near_point"`` (``"both"`` counts a flat rest twice: the features and the near-point
  pair each push).
"""

from __future__ import annotations

import fnmatch

import numpy as np
import jax.numpy as jnp

from .._pytree import pytree_dataclass, is_concrete
from ..errors import InputError
from ..geometry.shapes import Box, Capsule, Cylinder, Plane, Shape, Sphere

__all__ = ["Obstacle", "Environment", "ground", "incline", "box", "platform", "step", "sphere"]


def _pose(pose=None, xyz=None, R=None, where="obstacle"):
    """(4, 4) world-from-shape pose from ``pose`` or ``xyz`` (3,) and ``R`` (3, 3)."""
    if pose is not None:
        if xyz is not None or R is not None:
            raise InputError(f"{where}: give either pose or xyz/R, not both")
        if is_concrete(pose):
            P = np.asarray(pose, dtype=float)
            if P.shape != (4, 4):
                raise InputError(f"{where}: pose must have shape (4, 4), got {P.shape}")
            if not np.all(np.isfinite(P)):
                raise InputError(f"{where}: pose has NaN or inf entries")
            if not np.allclose(P[:3, :3] @ P[:3, :3].T, np.eye(3), atol=1e-8) or np.linalg.det(P[:3, :3]) < 0:
                raise InputError(f"{where}: the rotation block of pose is not a rotation matrix")
            if not np.allclose(P[3], [0.0, 0.0, 0.0, 1.0]):
                raise InputError(f"{where}: the last row of pose must be (0, 0, 0, 1), got {P[3].tolist()}")
            return jnp.asarray(P)
        return jnp.asarray(pose)
    P = np.eye(4)
    if xyz is not None:
        t = np.asarray(xyz, dtype=float)
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise InputError(f"{where}: position must be a finite 3-vector, got {xyz!r}")
        P[:3, 3] = t
    if R is not None:
        Rm = np.asarray(R, dtype=float)
        if Rm.shape != (3, 3) or not np.allclose(Rm @ Rm.T, np.eye(3), atol=1e-8) or np.linalg.det(Rm) < 0:
            raise InputError(f"{where}: R must be a (3, 3) rotation matrix")
        P[:3, :3] = Rm
    return jnp.asarray(P)


def _rotation(axis, angle):
    """Rotation matrix (3, 3) by ``angle`` (rad) about the unit of ``axis`` (Rodrigues)."""
    a = np.asarray(axis, dtype=float)
    na = np.linalg.norm(a) if a.shape == (3,) else 0.0
    if not np.isfinite(na) or na < 1e-12:
        raise InputError(f"axis must be a non-zero 3-vector, got {axis!r}")
    a = a / na
    K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


CONTACT_MODES = ("features", "near_point", "both")
_FEATURE_OBSTACLES = (Plane, Box, Sphere, Capsule, Cylinder)  # closed-form point distances


@pytree_dataclass(meta=("name", "contact"))
class Obstacle:
    """A static shape placed in the world (a JAX pytree).

    Args:
      shape: a cstorm shape (`Sphere`, `Capsule`, `Box`, `Cylinder`, `ConvexMesh`,
        `Plane`), in its own frame.
      pose: (4, 4) world from shape (default identity).
      name: unique within an `Environment` (static).
      contact: static, how robot shapes touch it: ``"features"``, ``"near_point"`` or
        ``"both"`` (see the module docstring); None (default) picks ``"features"`` for a
        `Plane` or `Box`, ``"near_point"`` otherwise. A `Plane` takes only
        ``"features"``; a `ConvexMesh` obstacle only ``"near_point"``.
    """

    shape: Shape
    pose: jnp.ndarray = None
    name: str = "obstacle"
    contact: str = None

    def __post_init__(self):
        if not isinstance(self.shape, Shape):
            raise InputError(f"Obstacle {self.name!r}: shape must be a cstorm shape, got {type(self.shape).__name__}")
        if not isinstance(self.name, str) or not self.name:
            raise InputError(f"Obstacle: name must be a non-empty string, got {self.name!r}")
        mode = self.contact
        if mode is None:
            mode = "features" if isinstance(self.shape, (Plane, Box)) else "near_point"
        if mode not in CONTACT_MODES:
            raise InputError(f"Obstacle {self.name!r}: contact must be one of {CONTACT_MODES} or None, got {mode!r}")
        if isinstance(self.shape, Plane) and mode != "features":
            raise InputError(f"Obstacle {self.name!r}: a Plane obstacle takes contact='features' only, got {mode!r}")
        if mode != "near_point" and not isinstance(self.shape, _FEATURE_OBSTACLES):
            raise InputError(f"Obstacle {self.name!r}: contact={mode!r} needs a Plane, Box, Sphere, Capsule or "
                             f"Cylinder obstacle, got a {type(self.shape).__name__}; use 'near_point'")
        object.__setattr__(self, "contact", mode)
        object.__setattr__(self, "pose", _pose(np.eye(4) if self.pose is None else self.pose,
                                               where=f"Obstacle {self.name!r}"))


def _as_pairs(spec, argname):
    if spec is None:
        return None
    if isinstance(spec, tuple) and len(spec) == 2 and all(isinstance(s, str) for s in spec):
        spec = [spec]  # a single pair
    out = []
    for p in spec:
        if not (isinstance(p, (tuple, list)) and len(p) == 2 and all(isinstance(s, str) for s in p)):
            raise InputError(f"Environment: each entry of {argname} must be a pair of names (str, str), got {p!r}")
        out.append((p[0], p[1]))
    return tuple(out)


@pytree_dataclass(meta=("pairs", "self_collision", "cylinder_rim_points"))
class Environment:
    """Obstacles and the pair selection for `cstorm.contact_forces` (a JAX pytree).

    Args:
      obstacles: sequence of `Obstacle` (e.g. from `ground`, `incline`, `box`,
        `platform`, `step`, `sphere`), or bare shapes (placed at the identity pose and
        named ``"obstacle0"``, ``"obstacle1"``, ...). Names must be unique.
      pairs: None (default: every robot geom against every obstacle) or a sequence of
        ``(geom_pattern, obstacle_pattern)`` (see the module docstring), e.g.
        ``[("foot", "ground"), ("hand_*", "*")]``.
      self_collision: None (default, off) or a sequence of ``(geom_pattern,
        geom_pattern)`` robot geom pairs that may touch each other.
      cylinder_rim_points: points per end circle of a robot `Cylinder` against a plane
        (default 8, so 16 per cylinder); see `cstorm.contact`.

    Attributes: ``obstacles`` (tuple of `Obstacle`), ``names`` (tuple of str).
    """

    obstacles: tuple = ()
    pairs: tuple = None
    self_collision: tuple = None
    cylinder_rim_points: int = 8

    def __post_init__(self):
        obs = []
        for i, o in enumerate(self.obstacles):
            if isinstance(o, Shape):
                o = Obstacle(o, name=f"obstacle{i}")
            if not isinstance(o, Obstacle):
                raise InputError(f"Environment: obstacles[{i}] must be an Obstacle or a shape, got {type(o).__name__}")
            obs.append(o)
        names = [o.name for o in obs]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise InputError(f"Environment: obstacle names must be unique; repeated: {dup}")
        object.__setattr__(self, "obstacles", tuple(obs))
        pairs = _as_pairs(self.pairs, "pairs")
        if pairs is not None:
            bad = [ob for _, ob in pairs if not any(fnmatch.fnmatchcase(n, ob) for n in names)]
            if bad:
                raise InputError(f"Environment: pairs name unknown obstacles {bad}; obstacles are {names}")
        object.__setattr__(self, "pairs", pairs)
        object.__setattr__(self, "self_collision", _as_pairs(self.self_collision, "self_collision") or ())
        n = self.cylinder_rim_points
        if not isinstance(n, (int, np.integer)) or isinstance(n, bool) or n < 3:
            raise InputError(f"Environment: cylinder_rim_points must be an int >= 3, got {n!r}")
        object.__setattr__(self, "cylinder_rim_points", int(n))

    @property
    def names(self) -> tuple:
        return tuple(o.name for o in self.obstacles)

    def __repr__(self):
        kinds = ", ".join(f"{o.name}: {o.shape.kind}" for o in self.obstacles)
        return f"Environment([{kinds}], pairs={self.pairs}, self_collision={self.self_collision or None})"


# ---------------------------------------------------------------------------------------
# Convenience constructors (each returns an `Obstacle`)
# ---------------------------------------------------------------------------------------


def ground(height=0.0, normal=(0.0, 0.0, 1.0), name: str = "ground") -> Obstacle:
    """The solid half-space below the plane through ``(0, 0, height)`` with unit normal
    ``normal`` (world; default +z, i.e. ``{x : z <= height}``). ``height`` in m."""
    n = np.asarray(normal, dtype=float)
    return Obstacle(Plane(n, 0.0), pose=_pose(xyz=(0.0, 0.0, float(height)), where=f"ground {name!r}"), name=name)


def incline(angle, axis=(0.0, 1.0, 0.0), height=0.0, name: str = "incline") -> Obstacle:
    """The ground rotated by ``angle`` (rad) about ``axis`` (world) through the point
    ``(0, 0, height)``: its normal is ``R(axis, angle) e_z``. With the default
    ``axis = +y`` and ``angle > 0`` the normal is ``(sin angle, 0, cos angle)`` and the
    slope goes down towards +x (the downhill direction is ``(cos angle, 0, -sin angle)``).
    """
    R = _rotation(axis, float(angle))
    return Obstacle(Plane(np.array([0.0, 0.0, 1.0]), 0.0), pose=_pose(xyz=(0.0, 0.0, float(height)), R=R),
                    name=name)


def box(half_extents, position=(0.0, 0.0, 0.0), R=None, name: str = "box", contact: str = "features") -> Obstacle:
    """A box obstacle: half extents (3,) m along its axes, centre at ``position`` (3,)
    world, orientation ``R`` (3, 3) world from box (default identity). ``contact``: see
    `Obstacle` (default ``"features"``: one force per robot contact feature)."""
    return Obstacle(Box(np.asarray(half_extents, dtype=float)), pose=_pose(xyz=position, R=R, where=f"box {name!r}"),
                    name=name, contact=contact)


def platform(height, center=(0.0, 0.0), size=(1.0, 1.0), depth=None, name: str = "platform",
             contact: str = "features") -> Obstacle:
    """An axis-aligned box whose top face is at ``z = height`` (m), centred at ``center``
    (x, y) with full side lengths ``size`` (x, y); it extends ``depth`` below its top
    (default ``height``, i.e. down to z = 0, or 1 m if ``height <= 0``). ``contact``: see
    `Obstacle` (default ``"features"``)."""
    h = float(height)
    dp = float(depth) if depth is not None else (h if h > 0 else 1.0)
    if dp <= 0:
        raise InputError(f"platform {name!r}: depth must be > 0, got {dp}")
    sx, sy = (float(s) for s in size)
    return box((0.5 * sx, 0.5 * sy, 0.5 * dp), (float(center[0]), float(center[1]), h - 0.5 * dp), name=name,
               contact=contact)


def step(height, x=0.0, length=2.0, width=2.0, name: str = "step", contact: str = "features") -> Obstacle:
    """A step up of ``height`` (m) whose edge runs along y at ``x`` (m): the box
    ``x <= X <= x + length``, ``|Y| <= width/2``, ``0 <= Z <= height`` (with the ground,
    a step; alone, a block). ``contact``: see `Obstacle` (default ``"features"``)."""
    return platform(height, center=(float(x) + 0.5 * float(length), 0.0), size=(length, width), name=name,
                    contact=contact)


def sphere(radius, center=(0.0, 0.0, 0.0), name: str = "sphere", contact: str = "near_point") -> Obstacle:
    """A sphere obstacle of ``radius`` (m) centred at ``center`` (3,) world. ``contact``:
    see `Obstacle` (default ``"near_point"``)."""
    return Obstacle(Sphere(radius), pose=_pose(xyz=center, where=f"sphere {name!r}"), name=name, contact=contact)
