"""A hop-forward problem for the planar one-legged hopper of MuJoCo/Gymnasium
(``Hopper-v5``), `cs.robots.hopper_model` (every number of the model is there).

Contact (`hopper_contact`, not Gymnasium's soft constraints): cstorm's smooth penalty
law on the two end spheres of every capsule against the ground (8 contact points).
DESIGN.md's tumbler stiffness (k = 5e3 N/m for 3 kg) scaled by the mass ratio 15.8 / 3 ~ 5
(the same sink per unit weight): ``k = 2.5e4 N/m``; damping ``c = 2000 N s/m`` (a damping
ratio of about 1.6 for the whole robot on one contact point: a landing is absorbed, not
bounced), ``d_on = 0.01 m``, ``d_off = 0``, ``eps = 0.01 N``, friction ``mu = 0.9`` on every
capsule (Gymnasium's body friction; its foot has 2.0, which only stiffens the friction
damper ``1.5 mu N / v_max``), ``v_max = 0.3 m/s`` (the draft's 0.1 makes that damper,
about 1.5 * 0.9 * 155 N / 0.1 m/s ~ 2100 N s/m on the foot, a stiff mode for RK4 at 4 ms
steps; with 0.3 a loaded foot creeps at a few cm/s instead of ~1 cm/s). Standing still
the foot's end spheres rest about 4.4 mm above the ground (the force ramp starts at
``d_on``).

Problem (`hopper`)
------------------
Hop at least 0.15 m forward with a flight phase and land at rest: 1.5 s, 16 control
points per hinge, 5 shooting intervals; 19 stages (2 landing-penalty stages, the
12-stage landing `RAMP`, 5 stages tightening the every-step torque limits 1.6x -> 1x).
Why the formulation is what it is:

- the end posture is free within `END_POSTURE_TOL` (0.03 rad per hinge) and the base's
  end is asked for as velocities and accelerations within tolerances (`AtRest`'s
  ``accel_tol``) with the height and pitch only within 3 mm / 3 mrad. With the posture
  pinned, the terminal base state is the contact's passive settling and barely moves
  with the controls (the Jacobian of the terminal landing quantities has singular
  values down to 2.5e-6); a free posture moves the balance on the foot directly;
- 1.5 s with 16 control points leave room and authority to settle after the landing
  (at 1.2 s / 12 points the plan stalls with violations 0.3-8);
- `cstorm.optimize.SlipPower` <= 40 W from stage 1 (a foot sliding 0.3 m/s under body weight is
  ~50 W) and ``max_pitch`` 0.6 rad: without them the optimizer gains the distance by
  leaning back and sliding the foot after the landing;
- "at rest" is judged by the hold test rather than a 1e-2 m/s^2 acceleration bound: on
  the contact springs (k/m ~ 3000 s^-2) 1e-2 m/s^2 is the equilibrium 3 micrometres
  away, below what the controls can steer the passive settling to.

Results and what the motion looks like: docs/examples.md.
"""

from __future__ import annotations

import copy

import numpy as np

from ..contact import ContactParams
from ..optimize.constraints import SlipPower
from .hopping import hop_criteria, hop_problem
from .robots import HOPPER, hopper_model


def standing_height():
    """Height of the torso centre when the straight hopper's foot touches the ground
    (``q = 0`` posture, foot capsule tangent to z = 0), m."""
    P = HOPPER
    return P["torso"]["length"] / 2 + P["thigh"]["length"] + P["leg"]["length"] + P["foot"]["radius"]


ACTIVE = ("thigh_joint", "leg_joint", "foot_joint")


def hopper_contact(stiffness=2.5e4, damping=2000.0, d_on=0.01, d_off=0.0, friction=0.9, v_max=0.3):
    """The hopper's `ContactParams` (see the module docstring for the choice)."""
    return ContactParams(stiffness=stiffness, damping=damping, d_on=d_on, d_off=d_off, friction=friction,
                         v_max=v_max)


# Standing rest state with the default contact (q = 0 posture, v = 0): the equilibrium of
# the passive base computed by `hopping.standing_equilibrium` (|a_base| < 1e-12 there;
# tests/test_hopping.py re-checks the force balance). The foot's end spheres rest ~4.4 mm above the
# ground; the torso tilts back by 0.15 deg (the heel carries 62 % of the weight).
REST_Z = 1.2143910383975463
REST_PITCH = -0.0026500383279347


# The default initial guess: postures (thigh, leg, foot angles in rad) at fractions of
# t_final, joined by smoothstep ramps and fitted by the splines: stand, crouch (knees
# forward, foot flat), push-off (legs straight, toes pointed down), tuck, landing crouch,
# stand. A posture-level sketch of a hop; it says nothing about the base, the timing of
# contacts or the distance. Rolled out (the defaults: 1.5 s, 16 control points, 4 ms RK4,
# single shooting) it hops 0.17 s, 4.2 cm clear, leans back up to 0.65 rad and lands only
# 9 mm ahead; its peak torque is 361 N m (the limit is 200).
KEYFRAMES = (
    (0.0, (0.0, 0.0, 0.0)),
    (0.4 / 1.2, (-0.1, -0.8, 0.45)),
    (0.48 / 1.2, (-0.1, -0.2, -0.5)),
    (0.6 / 1.2, (-0.3, -0.6, 0.3)),
    (0.78 / 1.2, (-0.1, -0.8, 0.45)),
    (1.0, (0.0, 0.0, 0.0)),
)


#: the hopper's landing ramp (see `hopping.hop_problem`): ``(fraction of the distance,
#: base velocity tolerance m/s and rad/s, base acceleration tolerance m/s^2 and rad/s^2,
#: terminal height (m) and pitch (rad) tolerance)``. The distance goes to 100 % at 1 cm,
#: then the tolerances tighten by about 1.4x per stage (halving them in one stage made
#: SLSQP diverge) to the last stage's 8e-4 m/s, 0.8 m/s^2 and 3 mm / 3 mrad. The
#: acceleration tolerance is 1000 s^-1 x the velocity one: on the contact springs
#: (k/m ~ 3000 s^-2) 0.8 m/s^2 is the equilibrium 0.3 mm away, and the `HOLD` test, not
#: the acceleration, is what says the robot stays put
RAMP = tuple((f, tl, 1000.0 * tl, max(tl, 0.003)) for f, tl in (
    (1 / 3, 0.05), (2 / 3, 0.02), (5 / 6, 0.01), (0.91625, 0.01), (1.0, 0.01), (1.0, 0.007), (1.0, 0.005),
    (1.0, 0.0035), (1.0, 0.0025), (1.0, 0.0018), (1.0, 0.0012), (1.0, 8e-4)))

#: the end posture: each hinge within this (rad) of straight (its rest value), so that
#: the last control points can trim the balance on the foot (with the posture pinned the
#: terminal base state is the contact's passive settling and barely moves with the
#: controls; see the module docstring)
END_POSTURE_TOL = 0.03

#: the factor on the motor limits of the every-step torque constraint, stage by stage
#: after the landing ramp (the sampled plan needs 1.67x at the landing, on the ankle)
DENSE_RAMP = (1.6, 1.4, 1.25, 1.1, 1.0)

#: the hold test of the criteria (`planar.hold_test`): 1 s more with the joints locked,
#: the base stays within 0.01 rad and 2 mm of where it ended and is still (< 1e-2 m/s)
HOLD = dict(duration=1.0, pitch_tol=0.01, pos_tol=0.002, v_tol=1e-2)

#: the acceleration criterion (m/s^2, rad/s^2): what the last stage asks for, 0.8, with
#: room; the HOLD test checks the rest
ACC_TOL = 1.0


def hopper(distance: float = 0.15, t_final: float = 1.5, n_ctrl: int = 16, dt: float = 0.004,
           clearance: float = 0.03, integrator: str = "rk4", contact=None, schedule=None,
           armature: float | None = None, max_pitch: float = 0.6, w_land: float = 1e7, first_step: float = 0.1,
           trust: float = 1.0, shooting: int = 5, ramp=None, slip_power: float | None = 40.0,
           dense_torque: bool = True, dense_ramp=DENSE_RAMP, final_tol: float = 1e-6, **landing):
    """Hop forward by at least ``distance`` m, with a flight phase, and land at rest.

    Robot: `hopper_model` (Gymnasium's hopper; ``armature`` overrides its 1 kg m^2) with
    `hopper_contact` on every capsule against flat ground; active ``thigh_joint,
    leg_joint, foot_joint`` (quintic B-splines, ``n_ctrl`` control points each, RK4 at
    ``dt``), passive planar base.

    Start: standing straight at rest (``q = 0`` posture, base at the contact equilibrium
    `REST_Z`, `REST_PITCH`, ``v = 0``). End (``t_final``): the joints at rest within
    `END_POSTURE_TOL` of straight, the base at rest (velocities and accelerations within
    the last stage of ``ramp``, height and pitch within 3 mm / 3 mrad of the standing
    equilibrium), ``root_x`` at least ``distance`` ahead.

    The problem is `hopping.hop_problem` (costs, constraints, variable bounds, solve plan
    and success criteria are documented there) with ``rest_accel=True``: cost ``integral
    1/2 |tau|^2 dt`` over the three motors (N^2 m^2 s) plus the landing penalty
    (``w_land``, N^2 m^2 s per m^2) of the first stages; a flight phase with every contact
    point at least ``clearance`` m up at some instant (not scheduled); ``|pitch| <=
    max_pitch`` rad; joint limits and ``|tau| <= 200 N m`` (sampled, and with
    ``dense_torque`` on every step after the ramp, along ``dense_ramp``); with
    ``slip_power`` (W) from stage 1 `cstorm.optimize.SlipPower`: the contacts' sliding power
    bounded at every sample, so that the distance is not gained by sliding the foot. The
    last stage stops at SLSQP tolerance ``final_tol``. Success criteria: `hop_criteria`
    with `ACC_TOL` and the `HOLD` test.

    Initial guess (posture level): `KEYFRAMES` (stand, crouch, push, tuck, land, stand);
    with ``shooting=K > 1`` (default 5: multiple shooting, `MotionProblem`) `cs.solve`
    starts the node states on the guess's own rollout. ``ramp``: the landing ramp
    (default `RAMP`). ``landing``: further `hop_problem` arguments.
    """
    model = hopper_model(armature=armature)
    contact = hopper_contact() if contact is None else contact
    q_rest = np.array([0.0, REST_Z, REST_PITCH, 0.0, 0.0, 0.0])
    opts = dict(end_posture_tol=END_POSTURE_TOL, rest_accel=True,
                criteria_options=dict(acc_tol=ACC_TOL, hold=HOLD), final_tol=final_tol,
                extra=[] if slip_power is None else [SlipPower(float(slip_power), stage=1)])
    opts.update(landing)
    return hop_problem("hopper", model, ACTIVE, q_rest, contact, distance=distance, t_final=t_final, n_ctrl=n_ctrl,
                       dt=dt, clearance=clearance, max_pitch=max_pitch, w_land=w_land, min_flight=0.05,
                       keyframes=KEYFRAMES, integrator=integrator, schedule=schedule, first_step=first_step,
                       trust=trust, ramp=RAMP if ramp is None else ramp, shooting=shooting, dense_torque=dense_torque, dense_ramp=dense_ramp,
                       **opts)


#: the fast variant's plan (CI; see `fast_variant`): the default plan's first stages up to
#: the landing ramp's first entry (``FAST["stages"]`` of them), the second penalty stage cut
#: at ``penalty_max_iter`` iterations, then that entry's tolerances again at SLSQP
#: tolerance 1e-6 inside a box of ``polish_trust`` (control points, rad) around where it
#: starts, at most ``polish_max_iter`` iterations
FAST = dict(stages=3, penalty_max_iter=25, polish_trust=0.02, polish_max_iter=100)


def fast_variant(problem=None):
    """The hopper's fast variant (CI runs it; the full plan takes 250-700 iterations): the
    same problem (robot, contact, horizon, controls, guess, constraints) solved along the
    first part of its plan only, to a short hop landing nearly at rest.

    Plan (`FAST`): the two landing-penalty stages (the second cut at 25 iterations) and the
    landing ramp's first entry: a third of ``distance`` (0.05 m by default), the base at
    T within 0.05 m/s, 50 m/s^2 and 0.05 m / rad of the standing rest, at SLSQP tolerance
    1e-4; then the same stage again at tolerance 1e-6, each control point within 0.02 rad
    of where that stage starts (a polish: unboxed, SLSQP at 1e-6 wanders off to other
    motions with violations of 1e-3..1e-2 for 100+ iterations, measured).

    Criteria (`hop_criteria`, not the full problem's): feasibility <= 1e-6, forward >= the
    stage's distance, a flight of >= 0.05 s, the end within the stage's tolerances
    (height and pitch 0.05, speed 0.05, acceleration 50), penetration <= 1 cm. Not
    checked: the hold test and the motor limits on every step (the plan stops before the
    every-step torque stages; sampled, the limits hold).

    Args:
      problem: a `hopper()` problem to derive it from (default: a new one). The variant is
        a shallow copy that shares the compiled functions kept on that object, so a test
        that has compiled the hopper once pays no second compile.

    Returns the `MotionProblem` with the plan in ``solve_options`` and its own
    ``success_criteria``."""
    base = hopper() if problem is None else problem
    if base.name != "hopper":
        raise ValueError(f"hopper.fast_variant: expects a hopper() problem, got {base.name!r}")
    p = copy.copy(base)  # the compiled functions live on the object: shared
    k = FAST["stages"]
    sched = [dict(s) for s in base.solve_options["schedule"][:k]]
    sched[1]["max_iter"] = FAST["penalty_max_iter"]
    sched.append(dict(sched[-1], tol=1e-6, max_iter=FAST["polish_max_iter"], trust_region=FAST["polish_trust"]))
    p.solve_options = dict(base.solve_options, schedule=sched)
    last = sched[-1]["params"]
    land, acc, pose = (float(last[n]) for n in ("land_tol", "acc_tol", "pose_tol"))

    def criteria(solution):
        out = hop_criteria(p, solution, distance=float(last["distance"]), min_flight=0.05, z_rest=REST_Z,
                           pitch_rest=REST_PITCH, pose_tol_z=pose, pose_tol_pitch=pose, vel_tol=land, acc_tol=acc,
                           d_on=float(np.max(np.asarray(p.contact.d_on))))
        out.pop("torque_limits")  # on every step: the full plan's last stages
        return out

    p.success_criteria = criteria
    return p


EXAMPLES = {"hopper": hopper}
