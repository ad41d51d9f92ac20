"""Shipped robot models, built with `ModelBuilder`. Every number is documented here.

- ``double_pendulum``: two uniform 0.5 m, 1 kg rods hanging from the world, revolute
  joints about y (planar, x-z plane). Used by the foundation demo.
- ``tumbler``: the paper's planar tumbling robot (numbers of the feasibility study in
  DESIGN.md): three capsule links in a chain, legs - torso - arms, with a passive planar
  base (``root_x``, ``root_z``, ``root_pitch``) on the torso and two active joints,
  ``hip`` (torso-legs) and ``shoulder`` (torso-arms), both about y.

  | link  | length | mass   | capsule radius | notes                          |
  |-------|--------|--------|----------------|--------------------------------|
  | torso | 0.30 m | 1.5 kg | 0.04 m         | base body; axis along body z    |
  | legs  | 0.30 m | 1.0 kg | 0.03 m         | hangs from the hip at -z        |
  | arms  | 0.25 m | 0.5 kg | 0.025 m        | attached at the shoulder, +z    |

  Inertias are those of uniform rods about their centres (m l^2 / 12 about x and y, a
  small 1e-4 kg m^2 about the rod axis). Joint limits: hip [-2.8, 2.8] rad, shoulder
  [-3.0, 3.0] rad (they may fold flat but not pass through the torso); effort limits
  hip 12 N m, shoulder 8 N m (small hobby servos with gearboxes); velocity limits
  10 rad/s. Armature 1e-3 kg m^2 (geared rotor). Upright standing pose: q = 0 with the
  base at z = 0.30 + 0.15 + radius (feet touching the ground).
"""

from __future__ import annotations

import numpy as np

from .geometry.shapes import Capsule, Sphere
from .model.builder import ModelBuilder


def _rod_inertia(m, length, axial=1e-4):
    return (m * length**2 / 12.0, m * length**2 / 12.0, axial)


def double_pendulum():
    """Planar double pendulum hanging from the world origin (angles 0 = hanging down)."""
    b = ModelBuilder("double_pendulum", source="<cstorm.robots.double_pendulum>")
    L, m = 0.5, 1.0
    b.add_body("upper", None, "revolute", joint_name="shoulder", axis=(0, 1, 0), mass=m, com=(0, 0, -L / 2),
               inertia=_rod_inertia(m, L))
    b.add_body("lower", "upper", "revolute", joint_name="elbow", axis=(0, 1, 0), xyz=(0, 0, -L), mass=m,
               com=(0, 0, -L / 2), inertia=_rod_inertia(m, L))
    b.add_geom("upper", Capsule(0.03, L), xyz=(0, 0, -L / 2), name="upper_capsule")
    b.add_geom("lower", Capsule(0.03, L), xyz=(0, 0, -L / 2), name="lower_capsule")
    b.add_geom("lower", Sphere(0.05), xyz=(0, 0, -L), name="tip")
    return b.build()


TUMBLER = dict(
    torso=dict(length=0.30, mass=1.5, radius=0.04),
    legs=dict(length=0.30, mass=1.0, radius=0.03),
    arms=dict(length=0.25, mass=0.5, radius=0.025),
    hip=dict(lower=-2.8, upper=2.8, effort=12.0, velocity=10.0),
    shoulder=dict(lower=-3.0, upper=3.0, effort=8.0, velocity=10.0),
    armature=1e-3,
)


def tumbler(floating_base: str = "planar", feet: bool = False):
    """The planar tumbling robot (see the module docstring for every number).

    ``feet=True`` adds two collision shapes (no extra links, no extra mass: the shapes
    belong to the legs and arms links and their masses are in the numbers above): a
    foot, a capsule of radius 0.03 m and axis length 0.10 m lying along x across the
    bottom of the legs (its end spheres at x = +-0.05 m, level with the legs' end
    sphere), and a palm, a capsule of radius 0.025 m and axis length 0.08 m lying across
    the tip of the arms. With them, standing and a handstand rest on a 0.16 m / 0.13 m
    wide support instead of a single rolling point, so they are statically stable.
    """
    P = TUMBLER
    t, lg, ar = P["torso"], P["legs"], P["arms"]
    b = ModelBuilder("tumbler", source="<cstorm.robots.tumbler>")
    # torso: frame at its centre, axis along z
    b.add_link("torso", mass=t["mass"], inertia=_rod_inertia(t["mass"], t["length"]))
    b.add_geom("torso", Capsule(t["radius"], t["length"]), name="torso")
    # legs hang from the hip (bottom of the torso), pointing along -z at q = 0
    b.add_link("legs", mass=lg["mass"], com=(0, 0, -lg["length"] / 2), inertia=_rod_inertia(lg["mass"], lg["length"]))
    b.add_joint("hip", "revolute", "torso", "legs", xyz=(0, 0, -t["length"] / 2), axis=(0, 1, 0),
                armature=P["armature"], **P["hip"])
    b.add_geom("legs", Capsule(lg["radius"], lg["length"]), xyz=(0, 0, -lg["length"] / 2), name="legs")
    # arms at the shoulder (top of the torso), pointing along +z at q = 0 (arms raised)
    b.add_link("arms", mass=ar["mass"], com=(0, 0, ar["length"] / 2), inertia=_rod_inertia(ar["mass"], ar["length"]))
    b.add_joint("shoulder", "revolute", "torso", "arms", xyz=(0, 0, t["length"] / 2), axis=(0, 1, 0),
                armature=P["armature"], **P["shoulder"])
    b.add_geom("arms", Capsule(ar["radius"], ar["length"]), xyz=(0, 0, ar["length"] / 2), name="arms")
    if feet:
        b.add_geom("legs", Capsule(lg["radius"], 0.10), xyz=(0, 0, -lg["length"]), rpy=(0, np.pi / 2, 0), name="foot")
        b.add_geom("arms", Capsule(ar["radius"], 0.08), xyz=(0, 0, ar["length"]), rpy=(0, np.pi / 2, 0), name="palm")
    b.add_frame("feet", "legs", xyz=(0, 0, -lg["length"]))
    b.add_frame("hands", "arms", xyz=(0, 0, ar["length"]))
    return b.build(floating_base=floating_base)


def tumbler_standing_q(model=None):
    """Standing upright, feet on the ground: (root_x, root_z, root_pitch, hip, shoulder)."""
    P = TUMBLER
    z = P["legs"]["length"] + P["torso"]["length"] / 2 + P["legs"]["radius"]
    return np.array([0.0, z, 0.0, 0.0, 0.0])


REGISTRY = {"double_pendulum": double_pendulum, "tumbler": tumbler}


def names():
    return sorted(REGISTRY)


def get(name: str):
    """A shipped robot model by name."""
    from .errors import ModelError

    try:
        return REGISTRY[name]()
    except KeyError:
        raise ModelError(f"no shipped robot named {name!r}; shipped robots: {names()}") from None
