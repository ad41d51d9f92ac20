"""Every shipped robot model, built with `ModelBuilder`; every number is documented at
the function that builds it. ``cs.robots`` is this module.

| function             | robot                                                         |
|----------------------|---------------------------------------------------------------|
| `double_pendulum`    | two rods hanging from the world (the foundation demo)         |
| `tumbler`            | the paper's planar tumbling robot, passive planar base        |
| `acrobot_model`      | Spong's acrobot: shoulder passive, elbow actuated             |
| `hopper_model`       | Gymnasium's one-legged hopper (``Hopper-v5``)                 |
| `walker_model`       | Gymnasium's planar biped (``Walker2d-v5``)                    |
| `luxo_model`         | a planar Luxo desk lamp                                       |
| `jumper_model`       | a small planar one-legged jumper                              |

`get` builds a registered robot by name (`names`: ``double_pendulum``, ``tumbler``), as
``cstorm info`` and problem files' ``[robot] name`` do. The example problems
(`cstorm.examples`) take their robots from here.

Why builder models and not ``cs.load_mjcf(hopper.xml)`` for Gymnasium's robots: the
problems must run from a plain install (MuJoCo and Gymnasium are test extras).
``tests/test_hopper.py`` and ``tests/test_walker.py`` load Gymnasium's XML with MuJoCo
and with ``cs.load_mjcf`` and check that these models' mass matrices, bias forces and
passive forces agree with MuJoCo's at random states (to ~1e-12).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import ModelError
from ..geometry.shapes import Capsule, Sphere
from ..model.builder import ModelBuilder

__all__ = ["DENSITY", "capsule_inertia", "double_pendulum", "TUMBLER", "tumbler", "tumbler_standing_q",
           "acrobot_model", "HOPPER", "hopper_model", "WALKER", "walker_model", "LUXO", "luxo_model", "JUMPER",
           "jumper_model", "REGISTRY", "names", "get"]


DENSITY = 1000.0  # kg/m^3, MuJoCo's default geom density


def capsule_inertia(radius, length, density=DENSITY, mass=None):
    """Mass (kg) and principal inertias ``(I_perp, I_perp, I_axial)`` (kg m^2, about the
    centre, axis along z) of a uniform solid capsule: a cylinder of ``length`` (m, the
    axis segment) plus two hemispheres of ``radius`` (m). The density is ``density``
    (kg/m^3; MuJoCo's ``inertiafromgeom``), or, with ``mass`` (kg) given, the density
    that gives that mass."""
    r, h = float(radius), float(length)
    vc, vs = math.pi * r * r * h, 4.0 / 3.0 * math.pi * r ** 3  # cylinder, the two hemispheres
    rho = float(density) if mass is None else float(mass) / (vc + vs)
    mc, ms = rho * vc, rho * vs
    # the two hemispheres about the capsule centre: each 83/320 m r^2 about its own CoM,
    # which lies 3r/8 from its flat face, i.e. h/2 + 3r/8 from the centre
    perp = mc * (3 * r * r + h * h) / 12.0 + ms * (2 * r * r / 5 + h * h / 4 + 3 * r * h / 8)
    axial = mc * r * r / 2 + ms * 2 * r * r / 5
    return mc + ms, (perp, perp, axial)


def _rod_inertia(m, length, axial=1e-4):
    return (m * length**2 / 12.0, m * length**2 / 12.0, axial)


def double_pendulum():
    """Planar double pendulum hanging from the world origin (angles 0 = hanging down): two
    uniform 0.5 m, 1 kg rods, revolute joints ``shoulder`` and ``elbow`` about y (x-z
    plane); capsule geoms and a 0.05 m sphere ``tip``."""
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
    """The paper's planar tumbling robot (`TUMBLER`; the numbers of the feasibility study
    in DESIGN.md): three capsule links in a chain, legs - torso - arms, with a passive
    planar base (``root_x``, ``root_z``, ``root_pitch``; ``floating_base``, see
    `ModelBuilder.build`) on the torso and two active joints, ``hip`` (torso-legs) and
    ``shoulder`` (torso-arms), both about y; frames ``feet``, ``hands``.

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
    """The tumbler standing upright, feet on the ground: ``q`` (5,) = (root_x, root_z,
    root_pitch, hip, shoulder) (m, rad). ``model`` is not used."""
    P = TUMBLER
    z = P["legs"]["length"] + P["torso"]["length"] / 2 + P["legs"]["radius"]
    return np.array([0.0, z, 0.0, 0.0, 0.0])


def acrobot_model(length: float = 1.0, mass: float = 1.0, gravity: float = 9.81):
    """The acrobot (Spong 1995, "The swing up control problem for the Acrobot"): two links
    in a vertical plane, 2 revolute joints about y, ``shoulder`` and ``elbow``; links
    ``link1``, ``link2``; frame ``tip``. ``length`` (m), ``mass`` (kg) and ``gravity``
    (m/s^2) change Spong's values.

    Model (Spong's parameters): links of length ``l = 1 m`` and mass ``m = 1 kg``, CoM at
    the link's middle (0.5 m), inertia ``m l^2 / 12`` about the CoM, gravity 9.81 m/s^2 along
    -z. Both joints rotate about the world/link y axis; at ``q = (0, 0)`` both links hang
    straight down, at ``q = (pi, 0)`` the acrobot stands upright. Joints: ``shoulder`` (world
    -> link1, at the origin), ``elbow`` (link1 -> link2, at the tip of link 1).
    """
    L, m = float(length), float(mass)
    Ic = m * L * L / 12.0
    inertia = np.diag([Ic, Ic, 1e-6 * Ic])  # a thin rod along z
    b = ModelBuilder("acrobot", gravity=(0.0, 0.0, -float(gravity)))
    b.add_body("link1", None, "revolute", joint_name="shoulder", mass=m, com=(0.0, 0.0, -L / 2), inertia=inertia,
               axis=(0.0, 1.0, 0.0))
    b.add_body("link2", "link1", "revolute", joint_name="elbow", mass=m, com=(0.0, 0.0, -L / 2), inertia=inertia,
               axis=(0.0, 1.0, 0.0), xyz=(0.0, 0.0, -L))
    b.add_frame("tip", "link2", xyz=(0.0, 0.0, -L))
    return b.build()


# (radius, full axis length) of each capsule; Gymnasium's size="radius half-length"
HOPPER = dict(
    torso=dict(radius=0.05, length=0.40),
    thigh=dict(radius=0.05, length=0.45),
    leg=dict(radius=0.04, length=0.50),
    foot=dict(radius=0.06, length=0.39),
    foot_offset=0.065,  # foot capsule centre ahead of the ankle, m
    thigh_joint=dict(lower=-math.radians(150), upper=0.0),
    leg_joint=dict(lower=-math.radians(150), upper=0.0),
    foot_joint=dict(lower=-math.radians(45), upper=math.radians(45)),
    effort=200.0,  # N m: gear 200 x ctrlrange 1
    armature=1.0,  # kg m^2
    damping=1.0,  # N m s/rad
)


def hopper_model(armature: float | None = None, damping: float | None = None, effort: float | None = None):
    """The planar one-legged hopper of MuJoCo/Gymnasium (``Hopper-v5``'s ``hopper.xml``;
    every number is Gymnasium's unless said otherwise, `HOPPER`). Keyword arguments
    override Gymnasium's armature (kg m^2), damping (N m s/rad) and effort limit (N m) of
    the three hinges. Joints: ``root_x, root_z, root_pitch, thigh_joint, leg_joint,
    foot_joint``; geoms ``torso_geom, thigh_geom, leg_geom, foot_geom``; frames ``heel``,
    ``toe``.

    Four capsules in a chain, torso - thigh - leg - foot, in the x-z plane, gravity 9.81
    m/s^2 along -z. Masses and inertias are MuJoCo's ``inertiafromgeom``: uniform density
    1000 kg/m^3 over each capsule (a cylinder plus two hemispheres, `capsule_inertia`).

    | link  | capsule radius | axis length (= 2 x half-length) | mass (kg) | axis        |
    |-------|----------------|----------------------------------|-----------|-------------|
    | torso | 0.05 m         | 0.40 m                           | 3.6652    | vertical    |
    | thigh | 0.05 m         | 0.45 m                           | 4.0579    | vertical    |
    | leg   | 0.04 m         | 0.50 m                           | 2.7814    | vertical    |
    | foot  | 0.06 m         | 0.39 m                           | 5.3156    | horizontal  |

    Total 15.820 kg. Principal inertias about the capsule centres (kg m^2): torso
    (0.069246, 0.069246, 0.004451), thigh (0.093299, 0.093299, 0.004941), leg (0.072303,
    0.072303, 0.002182), foot (0.103523, 0.103523, 0.009242) (the last entry about the
    capsule axis).

    Frames and joints at ``q = 0`` (standing straight, torso centre at ``root_z`` above the
    ground, world x forward; cstorm puts each link frame at its joint's anchor):

    - passive planar base on the torso centre: ``root_x`` (prismatic x), ``root_z``
      (prismatic z), ``root_pitch`` (revolute about +y), MuJoCo's ``rootx, rootz, rooty``
      (``q`` equals MuJoCo's ``qpos``: ``root_z`` is the torso centre's height, Gymnasium's
      ``ref = 1.25``). No armature, damping or limits on the base.
    - ``thigh_joint``: torso -> thigh, at the torso's lower end (0, 0, -0.2) (the torso
      capsule's end-sphere centre); thigh capsule centre 0.225 m below the joint.
    - ``leg_joint``: thigh -> leg, 0.45 m below the thigh joint; leg capsule centre 0.25 m
      below it.
    - ``foot_joint`` (ankle): leg -> foot, 0.5 m below the leg joint (the leg capsule's
      lower end-sphere centre); the foot capsule lies along x, centred 0.065 m ahead of the
      ankle at ankle height: heel end-sphere centre at x = -0.13, toe at x = +0.26.
    - The three hinges turn about -y (MuJoCo ``axis="0 -1 0"``): a positive angle turns the
      child's lower end forward (+x). Ranges: thigh [-150, 0] deg, leg [-150, 0] deg, foot
      [-45, 45] deg (``q = 0`` is the upper limit of thigh and leg: straight). Armature 1
      kg m^2 and viscous damping 1 N m s/rad on each (Gymnasium's ``<default>``; the motor
      also supplies the damping torque). Effort limit 200 N m (motor ``gear = 200``,
      ``ctrlrange = [-1, 1]``). No velocity limits (Gymnasium has none).
    - Standing at ``q = 0`` the ankle is 1.15 m below the torso centre and the foot capsule's
      underside 1.21 m below it (Gymnasium starts the torso at 1.25 m, 4 cm up in the air).
    """
    P = HOPPER
    arm = P["armature"] if armature is None else float(armature)
    damp = P["damping"] if damping is None else float(damping)
    eff = P["effort"] if effort is None else float(effort)
    b = ModelBuilder("hopper", source="<cstorm.robots.hopper_model>")
    hinge = dict(axis=(0.0, -1.0, 0.0), armature=arm, damping=damp, effort=eff)
    t, th, lg, ft = P["torso"], P["thigh"], P["leg"], P["foot"]

    m, I = capsule_inertia(t["radius"], t["length"])
    b.add_link("torso", mass=m, inertia=I)
    b.add_geom("torso", Capsule(t["radius"], t["length"]), name="torso_geom")

    m, I = capsule_inertia(th["radius"], th["length"])
    c = (0.0, 0.0, -th["length"] / 2)
    b.add_link("thigh", mass=m, com=c, inertia=I)
    b.add_joint("thigh_joint", "revolute", "torso", "thigh", xyz=(0.0, 0.0, -t["length"] / 2), **hinge,
                **P["thigh_joint"])
    b.add_geom("thigh", Capsule(th["radius"], th["length"]), xyz=c, name="thigh_geom")

    m, I = capsule_inertia(lg["radius"], lg["length"])
    c = (0.0, 0.0, -lg["length"] / 2)
    b.add_link("leg", mass=m, com=c, inertia=I)
    b.add_joint("leg_joint", "revolute", "thigh", "leg", xyz=(0.0, 0.0, -th["length"]), **hinge, **P["leg_joint"])
    b.add_geom("leg", Capsule(lg["radius"], lg["length"]), xyz=c, name="leg_geom")

    m, (Ip, _, Ia) = capsule_inertia(ft["radius"], ft["length"])
    c = (P["foot_offset"], 0.0, 0.0)
    b.add_link("foot", mass=m, com=c, inertia=(Ia, Ip, Ip))  # capsule axis along x
    b.add_joint("foot_joint", "revolute", "leg", "foot", xyz=(0.0, 0.0, -lg["length"]), **hinge, **P["foot_joint"])
    b.add_geom("foot", Capsule(ft["radius"], ft["length"]), xyz=c, rpy=(0.0, -math.pi / 2, 0.0), name="foot_geom")
    b.add_frame("heel", "foot", xyz=(P["foot_offset"] - ft["length"] / 2, 0.0, -ft["radius"]))
    b.add_frame("toe", "foot", xyz=(P["foot_offset"] + ft["length"] / 2, 0.0, -ft["radius"]))
    return b.build(floating_base="planar")


# (radius, full axis length) of each capsule; Gymnasium's size="radius half-length"
WALKER = dict(
    torso=dict(radius=0.05, length=0.40),
    thigh=dict(radius=0.05, length=0.45),
    shin=dict(radius=0.04, length=0.50),
    foot=dict(radius=0.06, length=0.20),
    foot_offset=0.10,  # foot capsule centre ahead of the ankle, m
    hip=dict(lower=-math.radians(150), upper=0.0),
    knee=dict(lower=-math.radians(150), upper=0.0),
    ankle=dict(lower=-math.radians(45), upper=math.radians(45)),
    effort=100.0,  # N m: gear 100 x ctrlrange 1
    armature=0.01,  # kg m^2
    damping=0.1,  # N m s/rad
)


def walker_model(armature: float | None = None, damping: float | None = None, effort: float | None = None,
                 hip_upper: float | None = None):
    """The planar biped of Gymnasium's ``Walker2d-v5`` (``walker2d.xml``; every number is
    Gymnasium's unless said otherwise, `WALKER`). Keyword arguments override Gymnasium's
    armature (kg m^2), damping (N m s/rad), effort limit (N m) and the hips' upper limit
    (rad, Gymnasium 0). Joints: ``root_x, root_z, root_pitch, hip_r, knee_r, ankle_r,
    hip_l, knee_l, ankle_l`` (MuJoCo's order); geoms ``torso_geom``,
    ``{thigh,shin,foot}_{r,l}_geom``; frames ``heel_{r,l}``, ``toe_{r,l}`` (the foot
    capsules' end-sphere centres).

    Seven capsules, a torso and two legs of thigh - shin - foot, in the x-z plane; gravity
    9.81 m/s^2 along -z. Masses and inertias are MuJoCo's ``inertiafromgeom``: uniform density
    1000 kg/m^3 over each capsule (a cylinder plus two hemispheres, `capsule_inertia`).

    | link (ours)       | Gymnasium body    | radius | axis length | mass (kg) | axis       |
    |-------------------|-------------------|--------|-------------|-----------|------------|
    | torso             | torso             | 0.05 m | 0.40 m      | 3.6652    | vertical   |
    | thigh_r, thigh_l  | thigh, thigh_left | 0.05 m | 0.45 m      | 4.0579    | vertical   |
    | shin_r, shin_l    | leg, leg_left     | 0.04 m | 0.50 m      | 2.7814    | vertical   |
    | foot_r, foot_l    | foot, foot_left   | 0.06 m | 0.20 m      | 3.1667    | horizontal |

    Total 23.677 kg. Principal inertias about the capsule centres (kg m^2): torso (0.069246,
    0.069246, 0.004451), thigh (0.093299, 0.093299, 0.004941), shin (0.072303, 0.072303,
    0.002182), foot (0.023998, 0.023998, 0.005374) (the last entry about the capsule axis).

    Frames and joints at ``q = 0`` (standing straight, torso centre at ``root_z`` above the
    ground, world x forward; cstorm puts each link frame at its joint's anchor):

    - passive planar base on the torso centre: ``root_x`` (prismatic x), ``root_z``
      (prismatic z), ``root_pitch`` (revolute about +y; a positive pitch tips the torso's top
      forward, +x), Gymnasium's ``rootx, rootz, rooty`` (``q`` equals MuJoCo's ``qpos``;
      ``root_z`` is the torso centre's height). No armature, damping or limits on the base.
    - ``hip_r`` / ``hip_l`` (Gymnasium ``thigh_joint`` / ``thigh_left_joint``): torso ->
      thigh at the torso's lower end-sphere centre (0, 0, -0.2); thigh capsule centre 0.225 m
      below the hip.
    - ``knee_r`` / ``knee_l`` (``leg_joint`` / ``leg_left_joint``): thigh -> shin, 0.45 m
      below the hip; shin capsule centre 0.25 m below the knee.
    - ``ankle_r`` / ``ankle_l`` (``foot_joint`` / ``foot_left_joint``): shin -> foot, 0.5 m
      below the knee (the shin capsule's lower end-sphere centre). The foot capsule lies along
      x at ankle height from the ankle forward: heel end-sphere centre at the ankle, toe
      end-sphere centre 0.2 m ahead; foot CoM 0.1 m ahead of the ankle.
    - The six hinges turn about -y (MuJoCo ``axis="0 -1 0"``): a positive angle turns the
      child's points below the joint forward (+x) and its points ahead of the joint up. So
      a hip at a negative angle swings its thigh back, a knee bends by going negative (the
      shin swings back) and a positive ankle angle lifts the toe (dorsiflexion). Ranges
      (Gymnasium's): hips [-150, 0] deg, knees [-150, 0] deg, ankles [-45, 45] deg. ``q = 0``
      is the upper limit of hips and knees: a hip cannot swing its thigh forward of the
      torso's axis, so a walking robot leans its torso forward (positive pitch).
    - Armature 0.01 kg m^2 and viscous damping 0.1 N m s/rad on each hinge (Gymnasium's
      ``<default>``; the motor also supplies the damping torque). Effort limit 100 N m
      (motor ``gear = 100``, ``ctrlrange = [-1, 1]``). No velocity limits (Gymnasium has none).
    - Standing straight, the ankles are 1.15 m below the torso centre and the foot capsules'
      undersides 1.21 m below it (Gymnasium starts the torso at 1.25 m).
    """
    P = WALKER
    arm = P["armature"] if armature is None else float(armature)
    damp = P["damping"] if damping is None else float(damping)
    eff = P["effort"] if effort is None else float(effort)
    hinge = dict(axis=(0.0, -1.0, 0.0), armature=arm, damping=damp, effort=eff)
    hip = dict(P["hip"])
    if hip_upper is not None:
        hip["upper"] = float(hip_upper)
    b = ModelBuilder("walker", source="<cstorm.robots.walker_model>")
    t, th, sh, ft = P["torso"], P["thigh"], P["shin"], P["foot"]

    m, I = capsule_inertia(t["radius"], t["length"])
    b.add_link("torso", mass=m, inertia=I)
    b.add_geom("torso", Capsule(t["radius"], t["length"]), name="torso_geom")
    for s in ("r", "l"):
        m, I = capsule_inertia(th["radius"], th["length"])
        c = (0.0, 0.0, -th["length"] / 2)
        b.add_link(f"thigh_{s}", mass=m, com=c, inertia=I)
        b.add_joint(f"hip_{s}", "revolute", "torso", f"thigh_{s}", xyz=(0.0, 0.0, -t["length"] / 2), **hinge, **hip)
        b.add_geom(f"thigh_{s}", Capsule(th["radius"], th["length"]), xyz=c, name=f"thigh_{s}_geom")

        m, I = capsule_inertia(sh["radius"], sh["length"])
        c = (0.0, 0.0, -sh["length"] / 2)
        b.add_link(f"shin_{s}", mass=m, com=c, inertia=I)
        b.add_joint(f"knee_{s}", "revolute", f"thigh_{s}", f"shin_{s}", xyz=(0.0, 0.0, -th["length"]), **hinge,
                    **P["knee"])
        b.add_geom(f"shin_{s}", Capsule(sh["radius"], sh["length"]), xyz=c, name=f"shin_{s}_geom")

        m, (Ip, _, Ia) = capsule_inertia(ft["radius"], ft["length"])
        c = (P["foot_offset"], 0.0, 0.0)
        b.add_link(f"foot_{s}", mass=m, com=c, inertia=(Ia, Ip, Ip))  # capsule axis along x
        b.add_joint(f"ankle_{s}", "revolute", f"shin_{s}", f"foot_{s}", xyz=(0.0, 0.0, -sh["length"]), **hinge,
                    **P["ankle"])
        b.add_geom(f"foot_{s}", Capsule(ft["radius"], ft["length"]), xyz=c, rpy=(0.0, -math.pi / 2, 0.0),
                   name=f"foot_{s}_geom")
        b.add_frame(f"heel_{s}", f"foot_{s}", xyz=(P["foot_offset"] - ft["length"] / 2, 0.0, 0.0))
        b.add_frame(f"toe_{s}", f"foot_{s}", xyz=(P["foot_offset"] + ft["length"] / 2, 0.0, 0.0))
    return b.build(floating_base="planar")


LUXO = dict(
    foot=dict(radius=0.020, length=0.12, mass=0.60),
    lower_arm=dict(radius=0.012, length=0.20, mass=0.20),
    upper_arm=dict(radius=0.012, length=0.20, mass=0.20),
    head=dict(radius=0.040, length=0.08, mass=0.35, offset=0.06),
    base=dict(lower=math.radians(-70), upper=math.radians(70), effort=6.0, velocity=12.0),
    elbow=dict(lower=math.radians(-150), upper=math.radians(30), effort=6.0, velocity=12.0),
    neck=dict(lower=math.radians(-60), upper=math.radians(120), effort=2.0, velocity=12.0),
    armature=1e-3,
)

def luxo_model():
    """A planar Luxo lamp (the desk lamp of Pixar's "Luxo Jr."; numbers chosen for a small
    desk lamp, 1.35 kg in all, `LUXO`). Joints ``root_x, root_z, root_pitch, base, elbow,
    neck``; geoms ``foot, lower_arm, upper_arm, head``; frames ``heel``, ``toe``.

    Four capsules in a chain, foot - lower arm - upper arm - head, in the x-z plane; gravity
    9.81 m/s^2 along -z. Links are uniform solid capsules: CoM at the capsule centre,
    inertia of a cylinder plus two hemispheres of the link's mass (`capsule_inertia` with
    the density that gives the stated mass).

    | link      | capsule radius | axis length | mass   | notes                                     |
    |-----------|----------------|-------------|--------|-------------------------------------------|
    | foot      | 0.020 m        | 0.12 m      | 0.60 kg| weighted base, axis along x; 0.16 m long  |
    | lower_arm | 0.012 m        | 0.20 m      | 0.20 kg| axis along its z, from the base joint up  |
    | upper_arm | 0.012 m        | 0.20 m      | 0.20 kg| from the elbow up                         |
    | head      | 0.040 m        | 0.08 m      | 0.35 kg| lamp shade, axis along its x (forward)     |

    Frames and joints (cstorm puts each link frame at its joint's anchor; every hinge turns
    about +y, so a positive angle tips the child's far end forward, +x, or down for a link
    pointing forward):

    - passive planar base on the foot's centre: ``root_x``, ``root_z`` (the foot axis'
      height), ``root_pitch``; no armature, damping or limits.
    - ``base`` (foot -> lower arm) on the foot's axis at its centre; the lower arm points up
      (+z) at 0. Range [-70, 70] deg.
    - ``elbow`` (lower -> upper arm) at the lower arm's top (0.20 m); the upper arm continues
      up at 0. Range [-150, 30] deg (folds backwards, the Luxo "Z").
    - ``neck`` (upper arm -> head) at the upper arm's top (0.20 m); the shade's axis points
      forward (+x) at 0, its capsule centred 0.06 m ahead of the neck. Range [-60, 120] deg.
    - Motors: effort limits ``base`` 6 N m, ``elbow`` 6 N m, ``neck`` 2 N m (hobby smart
      servos of the Dynamixel MX-64 / MX-28 class); velocity limits 12 rad/s (not enforced
      by the default problem); armature 1e-3 kg m^2 (geared rotor); no damping.
    - Rest posture `REST_ACTIVE` (rad): ``base`` 0.5 (lower arm leans forward 29 deg),
      ``elbow`` -1.0 (upper arm leans back 29 deg), ``neck`` 1.0 (the shade points forward
      and 29 deg down): the CoM 2.8 cm ahead of the foot centre, the neck 0.37 m up.
    """
    P = LUXO
    b = ModelBuilder("luxo", source="<cstorm.robots.luxo_model>")
    hinge = lambda name: dict(axis=(0.0, 1.0, 0.0), armature=P["armature"], **P[name])
    f, la, ua, hd = P["foot"], P["lower_arm"], P["upper_arm"], P["head"]

    _, (Ip, _, Ia) = capsule_inertia(f["radius"], f["length"], mass=f["mass"])
    b.add_link("foot", mass=f["mass"], inertia=(Ia, Ip, Ip))  # axis along x
    b.add_geom("foot", Capsule(f["radius"], f["length"]), rpy=(0.0, math.pi / 2, 0.0), name="foot")
    b.add_frame("heel", "foot", xyz=(-f["length"] / 2, 0.0, -f["radius"]))
    b.add_frame("toe", "foot", xyz=(f["length"] / 2, 0.0, -f["radius"]))

    c = (0.0, 0.0, la["length"] / 2)
    b.add_link("lower_arm", mass=la["mass"], com=c, inertia=capsule_inertia(la["radius"], la["length"], mass=la["mass"])[1])
    b.add_joint("base", "revolute", "foot", "lower_arm", xyz=(0.0, 0.0, 0.0), **hinge("base"))
    b.add_geom("lower_arm", Capsule(la["radius"], la["length"]), xyz=c, name="lower_arm")

    c = (0.0, 0.0, ua["length"] / 2)
    b.add_link("upper_arm", mass=ua["mass"], com=c, inertia=capsule_inertia(ua["radius"], ua["length"], mass=ua["mass"])[1])
    b.add_joint("elbow", "revolute", "lower_arm", "upper_arm", xyz=(0.0, 0.0, la["length"]), **hinge("elbow"))
    b.add_geom("upper_arm", Capsule(ua["radius"], ua["length"]), xyz=c, name="upper_arm")

    c = (hd["offset"], 0.0, 0.0)
    _, (Ip, _, Ia) = capsule_inertia(hd["radius"], hd["length"], mass=hd["mass"])
    b.add_link("head", mass=hd["mass"], com=c, inertia=(Ia, Ip, Ip))  # axis along x
    b.add_joint("neck", "revolute", "upper_arm", "head", xyz=(0.0, 0.0, ua["length"]), **hinge("neck"))
    b.add_geom("head", Capsule(hd["radius"], hd["length"]), xyz=c, rpy=(0.0, math.pi / 2, 0.0), name="head")
    return b.build(floating_base="planar")


JUMPER = dict(
    gravity=9.81,
    body=dict(length=0.30, radius=0.04, mass=2.0, com=0.10, inertia=0.006),
    shank=dict(length=0.30, radius=0.025, mass=0.5),
    foot=dict(length=0.20, radius=0.02, mass=0.2, x=0.02, z=-0.03),
    knee=dict(lower=-0.05, upper=2.5, effort=40.0, velocity=15.0),
    ankle=dict(lower=-1.2, upper=1.0, effort=25.0, velocity=15.0),
    armature=1e-3,
    contact=dict(stiffness=5e3, damping=100.0, d_on=0.005, d_off=-0.005, friction=0.8, v_max=0.3, eps=0.01),
)
def jumper_model():
    """The jumper, a small planar one-legged robot (every number in `JUMPER`): joints
    ``root_x, root_z, root_pitch, knee, ankle``; bodies ``body, shank, foot``; geoms
    ``body, shank, foot``.

    Three links in a chain in the world x-z plane, gravity 9.81 m/s^2 along -z, all joints
    turning about +y (a positive angle tilts a link's +z axis towards +x):

    | link  | shape (collision)                   | mass   | CoM                       | inertia about CoM (kg m^2)  |
    |-------|-------------------------------------|--------|---------------------------|-----------------------------|
    | body  | capsule r 0.04 m, axis 0.30 m, z     | 2.0 kg | 0.10 m above the centre   | 0.006 (x, y), 1e-4 (z)      |
    | shank | capsule r 0.025 m, axis 0.30 m, z    | 0.5 kg | middle of the shank       | m l^2/12 = 0.00375, 1e-4    |
    | foot  | capsule r 0.02 m, axis 0.20 m, x     | 0.2 kg | capsule centre            | 1e-4, m l^2/12 = 6.7e-4 (y, z) |

    - ``body``: thigh and trunk in one link (the mass sits near the hip, at the top). Its
      frame is the capsule centre; the passive planar base ``root_x, root_z, root_pitch``
      (``ModelBuilder.build(floating_base="planar")``) moves it.
    - ``knee`` (active): body -> shank at the body's lower end (0, 0, -0.15); the shank
      hangs along -z from it. Positive knee angle swings the shank's lower end backwards
      (-x), the way a knee bends. Range [-0.05, 2.5] rad, effort 40 N m, velocity 15 rad/s.
    - ``ankle`` (active): shank -> foot at the shank's lower end (0, 0, -0.30). The foot
      capsule lies along x, its centre 0.02 m ahead of and 0.03 m below the ankle: end
      spheres (heel, toe) at x = -0.08 and +0.12 m, sole 0.05 m below the ankle. Positive
      ankle angle turns the toe down. Range [-1.2, 1.0] rad, effort 25 N m, velocity 15
      rad/s.
    - Armature 1e-3 kg m^2 on both motors (geared rotors); no joint damping or springs.
    - Total mass 2.7 kg (weight 26.5 N). Standing straight (all angles 0) the body centre
      is 0.50 m up and the CoM 0.48 m.
    """
    P = JUMPER
    b, s, f = P["body"], P["shank"], P["foot"]
    B = ModelBuilder("jumper", gravity=(0.0, 0.0, -P["gravity"]), source="<cstorm.robots.jumper_model>")
    B.add_link("body", mass=b["mass"], com=(0, 0, b["com"]), inertia=(b["inertia"], b["inertia"], 1e-4))
    B.add_geom("body", Capsule(b["radius"], b["length"]), name="body")
    B.add_link("shank", mass=s["mass"], com=(0, 0, -s["length"] / 2),
               inertia=(s["mass"] * s["length"] ** 2 / 12, s["mass"] * s["length"] ** 2 / 12, 1e-4))
    B.add_joint("knee", "revolute", "body", "shank", xyz=(0, 0, -b["length"] / 2), axis=(0, 1, 0),
                armature=P["armature"], **P["knee"])
    B.add_geom("shank", Capsule(s["radius"], s["length"]), xyz=(0, 0, -s["length"] / 2), name="shank")
    If = f["mass"] * f["length"] ** 2 / 12
    B.add_link("foot", mass=f["mass"], com=(f["x"], 0, f["z"]), inertia=(1e-4, If, If))
    B.add_joint("ankle", "revolute", "shank", "foot", xyz=(0, 0, -s["length"]), axis=(0, 1, 0),
                armature=P["armature"], **P["ankle"])
    B.add_geom("foot", Capsule(f["radius"], f["length"]), xyz=(f["x"], 0, f["z"]), rpy=(0, np.pi / 2, 0),
               name="foot")
    return B.build(floating_base="planar")


REGISTRY = {"double_pendulum": double_pendulum, "tumbler": tumbler}


def names():
    """Names of the robots `get` builds."""
    return sorted(REGISTRY)


def get(name: str):
    """A registered robot model by name, built with its defaults. Raises `ModelError`
    for an unknown name."""
    try:
        return REGISTRY[name]()
    except KeyError:
        raise ModelError(f"no shipped robot named {name!r}; shipped robots: {names()}") from None
