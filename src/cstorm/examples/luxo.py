"""A planar Luxo lamp (the desk lamp of Pixar's "Luxo Jr.", the draft's introduction) and
a hop-forward problem.

Model: `cs.robots.luxo_model` (every number is there).

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
`hopping.hop_problem`: start at rest in `REST_ACTIVE` at the contact equilibrium, hop
forward at least one foot length (0.16 m, end to end), with a flight phase (every contact
point 1 cm up at some instant, not scheduled), land at rest in the same posture; cost
``integral 1/2 |tau|^2 dt``; 1.0 s, RK4 at 2 ms, 14 control points per joint (24
variables), SLSQP along the default solve plan (10 stages, see `hop_problem`),
``first_step = 0.1``; then the motor limits on every integration step (``dense_torque``,
`hopping.DENSE_RAMP`: 1.25x, 1.1x, 1x the limits at the 0.5 mm landing tolerance) and the
final 1e-6 stage, 14 stages in all. Initial guess: `KEYFRAMES` (posture level). Without
the every-step limits (``dense_torque=False``) the limits hold only at samples, and at
the landing the elbow needs more than its 6 N m between two of them.

The plan's path depends on the last bits of the derivatives: a 1e-15 change of the
Jacobians can make it fail. Results: docs/examples.md.
"""

from __future__ import annotations

import numpy as np

from ..contact import ContactParams
from .hopping import hop_problem
from .robots import LUXO, luxo_model


ACTIVE = ("base", "elbow", "neck")
REST_ACTIVE = (0.5, -1.0, 1.0)


def luxo_contact(stiffness=5e3, damping=50.0, d_on=0.005, d_off=0.0, friction=0.8, v_max=0.3):
    """The lamp's `ContactParams` (see the module docstring for the choice)."""
    return ContactParams(stiffness=stiffness, damping=damping, d_on=d_on, d_off=d_off, friction=friction,
                         v_max=v_max)


# Standing rest state with the default contact (`REST_ACTIVE` posture, v = 0): the
# equilibrium of the passive base computed by `hopping.standing_equilibrium` (|a_base| <
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
         w_land: float = 1e5, first_step: float = 0.1, dense_torque: bool = True, model=None, q_rest=None,
         keyframes=KEYFRAMES, name: str = "luxo"):
    """Hop forward by at least ``distance`` m (default one foot length, 0.16 m), with a
    flight phase, and land at rest in the rest posture.

    Robot: `luxo_model` with `luxo_contact` on every capsule against flat ground; active
    ``base, elbow, neck`` (quintic B-splines, ``n_ctrl`` control points each), passive
    planar base. Start: `REST_ACTIVE` at rest, base at the contact equilibrium
    (`REST_Z`, `REST_PITCH`). The problem is `hopping.hop_problem` (costs, constraints,
    solve plan and success criteria are documented there): cost ``integral 1/2 |tau|^2
    dt`` (N^2 m^2 s) plus the landing penalty of the first stages; a flight phase with
    every contact point at least ``clearance`` m up at some instant; the base pitch
    within ``max_pitch`` rad of its rest value; the end at rest in the rest pose; with
    ``dense_torque`` (default) the motor limits on every integration step, tightened along
    `hopping.DENSE_RAMP` after the landing ramp (without it only the constraint grid's
    samples, and the landing needs 1.11x the elbow's limit between two of them).
    Initial guess: `KEYFRAMES` (posture level).

    Variants (`benchmarks.ddp_robustness`): ``model`` (default `luxo_model()`), ``q_rest``
    (nq,) the start and landing state (default `REST_ACTIVE` on the base's equilibrium
    with the default contact: `REST_Z`, `REST_PITCH`), ``keyframes`` the guess's
    postures, ``name``."""
    model = luxo_model() if model is None else model
    contact = luxo_contact() if contact is None else contact
    q_rest = np.array([0.0, REST_Z, REST_PITCH, *REST_ACTIVE]) if q_rest is None else np.asarray(q_rest, float)
    return hop_problem(name, model, ACTIVE, q_rest, contact, distance=distance, t_final=t_final, n_ctrl=n_ctrl,
                       dt=dt, clearance=clearance, max_pitch=max_pitch, w_land=w_land, min_flight=0.05,
                       keyframes=keyframes, integrator=integrator, schedule=schedule, first_step=first_step,
                       max_penetration=0.015, dense_torque=dense_torque)


EXAMPLES = {"luxo": luxo}
