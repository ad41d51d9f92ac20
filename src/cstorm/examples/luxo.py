"""A planar Luxo lamp (the desk lamp of Pixar's "Luxo Jr.", the draft's introduction) and
a hop-forward problem.

Model (`luxo_model`; numbers chosen for a small desk lamp, 1.35 kg in all)
---------------------------------------------------------------------------
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

Contact (`luxo_contact`): the smooth penalty law on both end spheres of every capsule
against the ground. DESIGN.md's tumbler values (k = 5e3 N/m, c = 100 N s/m, d_on = 0.01 m
for 3 kg) adapted to a 1.35 kg lamp: ``k = 5e3 N/m`` with ``d_on = 0.005 m`` (the same
force at full ramp per unit weight, half the float height: ~2.5 mm at rest), ``c = 50
N s/m``, ``d_off = 0``, rubber pads ``mu = 0.8`` (DESIGN.md: 0.3 slips), ``v_max = 0.3
m/s`` (the draft's 0.1 makes the friction law's viscous slope at zero slip, 1.5 mu N /
v_max, so stiff at the touchdown, ~90 N on a light foot, that RK4 needs dt <= 1.1 ms:
`cstorm.check_time_step` along the solution; at 4 ms the plan's landing "at rest" was
an integration artefact, the re-simulation at dt/4 ending at 0.024 m/s and 14 deg/s.
With 0.3 the limit is 2.8 ms and the plan runs at 2 ms).

Problem (`luxo`)
----------------
`_hopping.hop_problem`: start at rest in `REST_ACTIVE` at the contact equilibrium, hop
forward at least one foot length (0.16 m, end to end), with a flight phase (every contact
point 1 cm up at some instant, not scheduled), land at rest in the same posture; cost
``integral 1/2 |tau|^2 dt``; 1.0 s, RK4 at 2 ms, 14 control points per joint (24
variables), SLSQP along the default solve plan (10 stages, see `hop_problem`),
``first_step = 0.1``; then the motor limits on every integration step (``dense_torque``,
`_hopping.DENSE_RAMP`: 1.25x, 1.1x, 1x the limits at the 0.5 mm landing tolerance) and the
final 1e-6 stage, 14 stages in all. Initial guess: `KEYFRAMES` (posture level). Without
the every-step limits (``dense_torque=False``) the limits hold only at samples, and at
the landing the elbow needs more than its 6 N m between two of them.

The plan's path depends on the last bits of the derivatives: a 1e-15 change of the
Jacobians can make it fail. Results: docs/examples.md.
"""

from __future__ import annotations

import math

import numpy as np

from ..geometry.shapes import Capsule
from ..model.builder import ModelBuilder
from ._planar import capsule_inertia

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

ACTIVE = ("base", "elbow", "neck")
REST_ACTIVE = (0.5, -1.0, 1.0)


def luxo_model():
    """The planar Luxo lamp (see the module docstring for every number). Joints
    ``root_x, root_z, root_pitch, base, elbow, neck``; geoms ``foot, lower_arm,
    upper_arm, head``."""
    P = LUXO
    b = ModelBuilder("luxo", source="<cstorm.examples.luxo.luxo_model>")
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


def luxo_contact(stiffness=5e3, damping=50.0, d_on=0.005, d_off=0.0, friction=0.8, v_max=0.3):
    """The lamp's `ContactParams` (see the module docstring for the choice)."""
    from ..contact import ContactParams

    return ContactParams(stiffness=stiffness, damping=damping, d_on=d_on, d_off=d_off, friction=friction,
                         v_max=v_max)


# Standing rest state with the default contact (`REST_ACTIVE` posture, v = 0): the
# equilibrium of the passive base computed by `_hopping.standing_equilibrium` (|a_base| <
# 1e-13 there; tests/test_hopping.py re-checks the force balance). The foot's end spheres rest 2.0 and 3.0
# mm above the ground (d_on = 5 mm); the foot tilts forward by 0.49 deg.
REST_Z = 0.02250410464276732
REST_PITCH = 0.008633362548307924
FOOT_LENGTH = LUXO["foot"]["length"] + 2 * LUXO["foot"]["radius"]  # 0.16 m, end to end

# The default initial guess: postures (base, elbow, neck in rad) at fractions of t_final,
# joined by smoothstep ramps and fitted by the splines: rest, crouch (the lower arm leans
# forward 52 deg, the elbow folds to -1.65, the shade kept level by the neck), extension
# (the lower arm swings back to -0.3, the elbow opens to -0.6), half fold, rest. A
# posture-level sketch of a hop; it says nothing about the base, the timing of contacts
# or the distance. Rolled out (14 control points, RK4) it jumps about 0.2 s clear of the
# ground and lands a few cm ahead (measured at 4 ms: 4 cm clear, 6 cm ahead, tilted
# 0.1 rad; peak torque 6.0 N m).
KEYFRAMES = (
    (0.0, REST_ACTIVE),
    (0.3, (0.9, -1.65, 1.55)),
    (0.45, (-0.3, -0.6, 0.7)),
    (0.6, (0.6, -1.5, 1.5)),
    (1.0, REST_ACTIVE),
)


def luxo(distance: float = FOOT_LENGTH, t_final: float = 1.0, n_ctrl: int = 14, dt: float = 0.002,
         clearance: float = 0.01, integrator: str = "rk4", contact=None, schedule=None, max_pitch: float = 1.0,
         w_land: float = 1e5, first_step: float = 0.1, dense_torque: bool = True):
    """Hop forward by at least ``distance`` m (default one foot length, 0.16 m), with a
    flight phase, and land at rest in the rest posture.

    Robot: `luxo_model` with `luxo_contact` on every capsule against flat ground; active
    ``base, elbow, neck`` (quintic B-splines, ``n_ctrl`` control points each), passive
    planar base. Start: `REST_ACTIVE` at rest, base at the contact equilibrium
    (`REST_Z`, `REST_PITCH`). The problem is `_hopping.hop_problem` (costs, constraints,
    solve plan and success criteria are documented there): cost ``integral 1/2 |tau|^2
    dt`` (N^2 m^2 s) plus the landing penalty of the first stages; a flight phase with
    every contact point at least ``clearance`` m up at some instant; the base pitch
    within ``max_pitch`` rad of its rest value; the end at rest in the rest pose; with
    ``dense_torque`` (default) the motor limits on every integration step, tightened along
    `_hopping.DENSE_RAMP` after the landing ramp (without it only the constraint grid's
    samples, and the landing needs 1.11x the elbow's limit between two of them).
    Initial guess: `KEYFRAMES` (posture level)."""
    from ._hopping import hop_problem

    model = luxo_model()
    contact = luxo_contact() if contact is None else contact
    q_rest = np.array([0.0, REST_Z, REST_PITCH, *REST_ACTIVE])
    return hop_problem("luxo", model, ACTIVE, q_rest, contact, distance=distance, t_final=t_final, n_ctrl=n_ctrl,
                       dt=dt, clearance=clearance, max_pitch=max_pitch, w_land=w_land, min_flight=0.05,
                       keyframes=KEYFRAMES, integrator=integrator, schedule=schedule, first_step=first_step,
                       max_penetration=0.015, dense_torque=dense_torque)


EXAMPLES = {"luxo": luxo}
