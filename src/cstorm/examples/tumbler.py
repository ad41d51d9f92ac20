"""The paper's tumbling robot: start -> handstand -> roll -> standing -> start, as a
`MotionSequence` of four segments, each solved from the state where the previous one
ended, each minimizing the integral of squared active torque.

Robot: `cs.robots.tumbler(feet=True)` (planar; legs 0.30 m / 1.0 kg, torso 0.30 m /
1.5 kg, arms 0.25 m / 0.5 kg, capsule radii 0.03 / 0.04 / 0.025 m; hip and shoulder
active, limits +-2.8 / +-3.0 rad, 12 / 8 N m; passive planar base ``root_x, root_z,
root_pitch`` on the torso; a foot and a palm capsule across the ends of the legs and
arms; every number documented there). Ground contact through the smooth penalty model
on both end spheres of every capsule (10 contact points); no contact schedule is given
to the optimizer.

Conventions: ``root_pitch`` rotates the torso about the world y axis; positive pitch
tips the torso's top (shoulders) towards +x, so the whole sequence is one forward
revolution: pitch 0 (standing) -> pi (handstand) -> 3 pi / 2 (lying, rolling) -> 2 pi
(standing again). ``hip = 0``: legs straight below the torso; ``shoulder = 0``: arms
straight above it (overhead); ``shoulder = 3.0``: arms hanging down in front of the body
("arms down", the joint limit; in the plane the arms overlap the torso: the model has no
self-collision).

Contact: ``k = 5e3 N/m, c = 100 N s/m, d_on = 0.01 m, d_off = 0``, smooth
non-negativity ``eps = 0.01 N``, friction ``mu = 0.8`` (rubber hands and feet on a mat;
at the draft's 0.3 the feet slide during the pike), ``v_max = 0.1 m/s``. Resting on its
foot (or palm) the robot sits where the ramped springs of the three level contact points
carry its weight, 5.5 mm above the ground; the nominal postures are placed at that
height.

Segments (each ``T`` seconds, RK4 at ``dt`` = `DT` = 2 ms, quintic B-splines with
``n_ctrl`` = 12 control points per active joint, start position and velocity from the
previous segment by construction; cost ``integral 1/2 |tau|^2 dt``, N^2 m^2 s):

1. ``handstand`` (`HANDSTAND_T` = 2.5 s, `HANDSTAND_N_CTRL` = 15, `HANDSTAND_DT` =
   1.25 ms): from the start position (standing at rest, arms down) to a balanced
   handstand at rest: pitch = pi, hip = shoulder = 0. Plan: the terminal pitch at pi
   (equality, level 0), then `HANDSTAND_REST_RAMP` (level 1): base velocities within
   ``vtol``, accelerations within ``atol``, the pitch within ``ptol`` and torque limits
   scaled by ``tau_factor``, tightened together from (1 m/s or rad/s, 4x the limits) to
   (8e-3, 1x), each stage boxed to `HANDSTAND_REST_TRUST` around where it starts. Guess
   `HANDSTAND_KEYFRAMES`: a kick whose rollout ends on the hands.
2. ``roll`` (1.5 s): from the handstand, tip over forward and roll along the back: at
   the end the torso lies on the ground (its centre lower than 0.1 m) with pitch >= 3 pi
   / 2 - 0.2, still rotating forwards (pitch rate >= 1 rad/s); joints free
   (``roll_end="free"``) or, in the `tumbler` sequence, ending at `ROLL_END`'s joint
   positions and velocities (``roll_end="nominal"``: the start the standing segment's
   guess and plan are made for). Level 0: the pose; level 1: the pitch rate and the
   torque limits. Guess `ROLL_KEYFRAMES`.
3. ``standing`` (2.0 s): from the roll, come up onto the feet: pitch = 2 pi, hip =
   shoulder = 0, base at rest. Plan: the terminal pitch at 2 pi (level 0, boxed to
   `STANDING_PITCH_TRUST`, first step `STANDING_FIRST_STEP`), then `REST_RAMP` (level
   1), each stage boxed to 0.2 rad. Guess `STANDING_KEYFRAMES`.
4. ``start`` (2.0 s): from standing (arms overhead) back to the start position: pitch =
   2 pi within 0.05 rad, hip = 0, shoulder = 3.0, base at rest. Plan: `REST_RAMP` only,
   each stage boxed to 0.05 rad (``solve_options["trust_region"]``, see `cstorm.solve`)
   with ``first_step = 0.05``. Guess `START_KEYFRAMES`: lower the arms while the hip
   counterbalances.

"At rest" at a segment's end is checked by the success criteria: base velocities within
`REST_TOL` and a hold test (`HOLD`: 1 s with the joints locked, the robot stays put).

Joint position limits hold by construction (control points bounded by the limits; see
`cstorm.optimize.solve.variable_bounds`). Torque limits are sampled inequalities
(`ScaledTorqueLimits`, about 40 samples): at the contact impacts the splines'
accelerations need more than the motors have for a few ms between samples (the
handstand's landing on the hands, the roll's on the back, standing's legs swinging down
onto the floor need 2.3-2.9x the limits), so these three motions are not yet feasible
for the stated motors; ``cstorm solve`` reports it under ``torque_limits`` in
summary.json. With ``dense_torque=True`` the limits also hold on every integration step
(a level after the plan, `DENSE_RAMPS`); the roll, standing and start segments solve
that way on their own, the handstand does not, so it is not the default.

Initial guesses are posture-level keyframes joined by smoothstep ramps
(`cstorm.optimize.keyframe_guess`), documented at each constant. Where a guess counterbalances
(the hip at 0.1-0.16 rad while the arms swing), the value comes from a scan of rollouts:
standing on the compliant foot is only marginally stable (the foot's rotational contact
stiffness, ~25 N m/rad, against gravity's ~13 N m/rad), and swinging the arms without it
tips the robot onto its face.

SLSQP's path through the handstand's plan follows the last bits of the floating-point
Jacobians; the handstand therefore keeps plain autodiff contact derivatives and every
step's Jacobians (the settings its plan was made with), and failed stages are refined
(``solve_options["refine"]``). Results: docs/examples.md.
"""

from __future__ import annotations

import numpy as np
import jax.numpy as jnp

from ..analysis.criteria import evaluate_criteria
from ..contact import ContactParams, Environment, ground
from ..optimize import constraints as K, costs as C
from ..optimize.constraints import ScaledTorqueLimits
from ..optimize.guesses import keyframe_guess
from ..optimize.problem import MotionProblem
from ..optimize.sequence import MotionSequence
from . import robots
from .planar import criterion, hold_test


__all__ = ["tumbler", "tumbler_segment", "CONTACT", "SEGMENTS", "start_q", "handstand_q", "standing_q",
           "env_contact"]

#: smooth contact parameters (see the module docstring)
CONTACT = dict(stiffness=5e3, damping=100.0, d_on=0.01, d_off=0.0, friction=0.8, v_max=0.1, eps=0.01)
ARMS_DOWN = 3.0  # rad, the shoulder's limit
SEGMENTS = ("handstand", "roll", "standing", "start")


def _rest_sink(model, n_points=3):
    """Distance ``d`` of the supporting spheres from the ground when the whole robot rests
    on ``n_points`` level contact points (foot or palm: its two end spheres and the
    limb's end sphere): the root of ``n beta(d) k (d_on - d) = m g`` (bisection; the
    force law of `cstorm.contact` at rest)."""
    m = float(np.sum(np.asarray(model.mass)))
    g = float(np.linalg.norm(np.asarray(model.gravity)))
    k, d_on, d_off = CONTACT["stiffness"], CONTACT["d_on"], CONTACT["d_off"]

    def force(d):
        s = min(max((d - d_on) / (d_off - d_on), 0.0), 1.0)
        return n_points * s * s * (3.0 - 2.0 * s) * k * (d_on - d)

    lo, hi = d_off - 1.0, d_on  # force(lo) > m g >= force(hi) = 0
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if force(mid) > m * g else (lo, mid)
    return 0.5 * (lo + hi)


def start_q(model):
    """Start position: standing on the feet at rest, arms down (``shoulder = 3.0``)."""
    P = robots.TUMBLER
    z = P["legs"]["length"] + P["torso"]["length"] / 2 + P["legs"]["radius"] + _rest_sink(model)
    return np.array([0.0, z, 0.0, 0.0, ARMS_DOWN])


def standing_q(model, pitch=2 * np.pi):
    """Standing on the feet, arms overhead, torso upright at ``pitch``."""
    q = start_q(model)
    q[2], q[4] = pitch, 0.0
    return q


def handstand_q(model):
    """Balanced handstand: pitch pi, body straight, arms overhead on the ground."""
    P = robots.TUMBLER
    z = P["arms"]["length"] + P["torso"]["length"] / 2 + P["arms"]["radius"] + _rest_sink(model)
    return np.array([0.0, z, np.pi, 0.0, 0.0])


def env_contact():
    """The tumbler's world: flat ground and its `ContactParams` (`CONTACT`)."""
    return Environment([ground()]), ContactParams(**CONTACT)


#: the foot's contact points (heel and toe) stay within this distance of the ground
#: while the arms swing in the last segment (m; ``d_on`` = 0.01 m, at rest 0.0055 m)
FOOT_FLAT = 0.008


def FootFlat(max_distance=FOOT_FLAT):
    """The foot kept flat on the ground (`constraints.ContactDistance` with
    ``max_distance``, level 0): heel and toe stay loaded, so the robot does not rock onto
    one edge; where an edge nearly lifts, the terminal state depends on the controls
    through the C1 end of the force ramp and SLSQP's linearizations fail (measured on the
    ``start`` segment: the terminal pitch rate moved 20x more than predicted for a 0.02
    rad step)."""
    return K.ContactDistance(max_distance=max_distance, geoms=("foot",), stage=0, name="foot flat")


def _rest_terms(stage=1, pitch_tol="ptol", pitch_eq=False):
    """Terminal base pitch within ``pitch_tol`` (rad; a number or a parameter's name) of
    the ``pitch`` parameter, the base at rest *at an equilibrium* (velocities within
    ``vtol`` m/s, rad/s and accelerations within ``atol`` m/s^2, rad/s^2: a robot that
    passes through a still posture while rocking on its compliant foot has zero velocity
    but not zero acceleration, and fails the hold test) and the torque limits relaxed by
    ``tau_factor``: inequalities of level ``stage`` whose tolerances a solve plan tightens.
    ``pitch_eq``: the terminal pitch is instead an equality of level 0 (for a
    continuation on ``pitch``)."""
    pitch = (K.TerminalState("root_pitch", q="pitch", stage=0, name="pitch") if pitch_eq else
             K.TerminalState("root_pitch", q="pitch", kind="ineq", tol=pitch_tol, stage=stage, name="pitch"))
    rest = []
    for j, what in (("root_pitch", "pitch"), ("root_x", "x"), ("root_z", "z")):
        rest += [K.TerminalState(j, v=0.0, kind="ineq", tol="vtol", stage=stage, name=f"{what} rate"),
                 K.TerminalState(j, a=0.0, kind="ineq", tol="atol", stage=stage, name=f"{what} acceleration")]
    return [pitch, *rest, ScaledTorqueLimits("tau_factor", stage=stage, name="torque limits")]


#: the handstand's duration (s) and control points per joint: the kick below takes 2 s,
#: the last 0.5 s (two knot spans) leave the motors time to settle the body on the palm
#: (in 2.0 s with 12 control points the rest ramp stalls at its 1.1x-torque stage: the
#: shoulder would need 13.5 N m to stop the tipping in time)
HANDSTAND_T, HANDSTAND_N_CTRL = 2.5, 15
#: the default initial guess of the handstand, (time s, (hip, shoulder) rad) with
#: smoothstep ramps between (see `cstorm.optimize.keyframe_guess`): a kick. Fold at the hip
#: (legs forward, -0.8 rad) while the arms swing forward and down to the floor
#: (shoulder 2.5) by 0.7 s, swing the legs back and up over the hands while the arms go
#: overhead (hip -0.3, shoulder -0.2 at 1.6 s), straighten by 2.0 s and hold. Chosen
#: from scans of 810 and then 729 keyframe sets (rolled out with the control points
#: inside the joint limits, at 2 ms, scored by the distance from a handstand at rest at
#: T): its rollout ends on the hands at T, pitch pi + 0.05 (pi + 0.11 at `HANDSTAND_DT`),
#: torso at the handstand height (0.5 mm), base speeds <= 0.1 (0.21). The handstand is an inverted pendulum on the palm, so
#: the neighbourhood is narrow: 5 of the 729 sets end near it, the others fall to
#: either side. A guess that stays on the feet (raise the arms, counterbalance with the
#: hip) needed a pitch continuation that stalled where the weight moves onto the hands;
#: one that ends lying on the floor gives the terminal pitch no gradient (see the
#: module docstring, Status).
HANDSTAND_KEYFRAMES = ((0.0, (0.0, ARMS_DOWN)), (0.7, (-0.8, 2.5)), (1.6, (-0.3, -0.2)), (2.0, (0.0, 0.0)))
#: every stage of the handstand's rest ramp (`HANDSTAND_REST_RAMP`) is boxed to this (rad)
#: around where it starts
HANDSTAND_REST_TRUST = 0.1
#: the handstand's first stage (the terminal pitch at pi) is boxed to this (rad), and
#: SLSQP's first step of every stage is about `HANDSTAND_FIRST_STEP` rad (see `cs.solve`'s
#: ``objective_scale``): the guess ends close to the handstand, and a first step of ~1
#: rad (the default) tips it off the hands (measured: violation 0.05 -> 1.55, and the
#: pitch stage then wanders for 30-110 iterations into a different end each run)
HANDSTAND_PITCH_TRUST, HANDSTAND_FIRST_STEP = 0.3, 0.05
#: the handstand's "bridge" guess (``guess="bridge"``, for multiple shooting): lean
#: forward about the planted feet, legs vertical, into a pike bridge with the hands on the
#: floor ahead (torso pitch `BRIDGE_PITCH`, arms vertical) at 40 % of T, then swing the
#: legs up about the planted hands into the handstand
BRIDGE_PITCH = 1.75  # rad: pi/2 + the torso's tilt where the arms (0.25 m) are shorter than the legs (0.30 m)
BRIDGE_KEYFRAMES = ((0.0, (0.0, ARMS_DOWN)), (0.4, (-BRIDGE_PITCH, np.pi - BRIDGE_PITCH)), (1.0, (0.0, 0.0)))


def bridge_nodes(model, t_final):
    """The base path of the bridge guess as a ``node_guess`` (``t -> (q, v)``): the pitch
    follows smoothstep ramps 0 -> `BRIDGE_PITCH` (0 to 0.4 T) -> pi (to T), and the torso
    centre the kinematics of a body pivoting about its planted feet (legs vertical, hip
    ``-pitch``), then about its planted hands (arms vertical, shoulder ``pi - pitch``);
    joints as `BRIDGE_KEYFRAMES`. A posture-level guess: contact-consistent in geometry,
    not in dynamics (the optimizer closes the shooting defects)."""
    P = robots.TUMBLER
    half = P["torso"]["length"] / 2
    hip_z = start_q(model)[1] - half  # the hip above the planted feet
    sh_z = handstand_q(model)[1] - half  # the shoulder above the planted hands
    pb = BRIDGE_PITCH
    sh_x = 2 * half * np.sin(pb)  # the shoulder's x at the bridge (hip at x = 0)
    t1 = 0.4 * t_final

    def node(t):
        first = t < t1
        h = t1 if first else t_final - t1
        u = float(np.clip((t if first else t - t1) / h, 0.0, 1.0))
        w, dw = u * u * (3 - 2 * u), 6 * u * (1 - u) / h
        if first:
            phi, dphi = pb * w, pb * dw
            c = np.array([half * np.sin(phi), hip_z + half * np.cos(phi)])
            dc = half * np.array([np.cos(phi), -np.sin(phi)]) * dphi
            j, dj = np.array([-phi, ARMS_DOWN + (np.pi - pb - ARMS_DOWN) * w]), np.array(
                [-dphi, (np.pi - pb - ARMS_DOWN) * dw])
        else:
            phi, dphi = pb + (np.pi - pb) * w, (np.pi - pb) * dw
            c = np.array([sh_x - half * np.sin(phi), sh_z - half * np.cos(phi)])
            dc = -half * np.array([np.cos(phi), -np.sin(phi)]) * dphi
            j, dj = np.array([-pb * (1 - w), np.pi - phi]), np.array([pb * dw, -dphi])
        return np.array([c[0], c[1], phi, *j]), np.array([dc[0], dc[1], dphi, *dj])
    return node


#: the roll's guess: tip the body forward with the shoulder (arms pinned on the floor, the
#: torso leans past the hands), pike while falling, land on the back
ROLL_KEYFRAMES = ((0.0, (0.0, 0.0)), (0.3, (0.0, -0.6)), (0.7, (-1.0, -0.3)), (1.0, (-1.5, 0.0)))
#: the last segment's guess: lower the arms (forward and down) while the hip opens
#: slightly (legs back, 0.1 rad at mid-motion) to counterbalance; rolled out it stays on
#: its feet (pitch within 0.06 rad of upright, 0.08 rad/s at T; without the hip motion the
#: arm swing tips it forward onto its face)
START_KEYFRAMES = ((0.0, (0.0, 0.0)), (0.5, (0.1, 1.5)), (1.0, (0.0, ARMS_DOWN)))
#: the standing segment's default guess, (fraction of T, (hip, shoulder) rad): from the
#: roll's end (lying on the back, legs up), swing the legs forward and down hard (hip
#: 2.4 rad at 0.35 T) while the arms swing back (shoulder -2.0), fold slightly the other
#: way (hip -0.3, shoulder -0.6 at 0.6 T), straight by 0.8 T and hold. Chosen from scans of 864 and 360 keyframe sets rolled out, with the control points
#: inside the joint limits as the solver sees them, from four starts: `ROLL_END`, the
#: end of a chained roll (pitching at 1.27 rad/s, not 1.00, 0.28 m further on), and
#: `ROLL_END` with its pitch rate x0.8 and x1.3; scored by the worst of the four. From
#: every one it ends on its feet within 0.06 rad of upright, pitching at 0.08 rad/s, and
#: its neighbours (shoulder -0.2 or -1.0 at 0.6 T) within 0.08 rad. Most keyframe sets
#: end lying on the back or on the face (pitch 2 pi -+ 1.59), which gives the terminal
#: pitch no useful gradient; a guess scanned without clipping its control points to the
#: joint limits can end on the face once the solver clips them.
STANDING_KEYFRAMES = ((0.0, (-1.0, 0.0)), (0.35, (2.4, -2.0)), (0.6, (-0.3, -0.6)), (0.8, (0.0, 0.0)),
                      (1.0, (0.0, 0.0)))
#: standing's first stage (the terminal pitch at 2 pi) is boxed to this (rad) around the
#: guess, and SLSQP's first step of every stage is about `STANDING_FIRST_STEP` rad: the
#: guess ends near upright, and a ~1 rad first step throws it onto its back or its face
STANDING_PITCH_TRUST, STANDING_FIRST_STEP = 0.3, 0.05
#: the roll's end from its solve (``cstorm solve tumbler --segment roll``, from the nominal
#: handstand; lying on the back at pitch 4.73 rad, rolling at 1.0 rad/s): the standing
#: segment's start when it is solved alone (in the sequence the roll's actual end replaces it)
ROLL_END = (np.array([0.49500731727004044, 0.04635361151352915, 4.732207855240625, -1.0126033339884237,
                      0.06279084679987072]),
            np.array([0.00622571507542905, 0.10880413290826021, 1.0000000446514388, 2.0855375071474107,
                      -2.182392818840079]))
#: "at rest" at the end of a segment: base velocities within this (m/s, rad/s), and the
#: robot holds its posture for `HOLD` after T with the joints locked (a robot on the
#: compliant, lightly damped contact rocks with a period of 1.3 s; 1e-2 rad/s of rocking
#: is ~2 mrad of amplitude)
REST_TOL = 1e-2
#: the hold test after an at-rest segment: joints locked at their final values for
#: ``duration`` s from the final state; the base pitch stays within ``pitch_tol`` rad of its
#: final value and every base speed is below ``v_tol`` at the end
HOLD = dict(duration=1.0, pitch_tol=0.01, v_tol=REST_TOL)
#: solve plan of the at-rest segments: after the pitch ramp (level 0), the terminal
#: constraints (level 1) along (pitch tolerance rad, velocity tolerance m/s and rad/s,
#: acceleration tolerance m/s^2 and rad/s^2, torque-limit factor). The last stage is
#: 20 % inside the success criteria (a solver's 1e-9 violation of a bound is not a
#: criterion's failure); its acceleration bound keeps the rocking amplitude at the end
#: (acceleration / omega^2, omega = 4.8 rad/s) below ~2 mrad
REST_RAMP = ((0.3, 1.0, 5.0, 4.0), (0.1, 0.3, 1.5, 2.5), (0.03, 0.1, 0.5, 1.6), (0.01, 0.03, 0.15, 1.2),
             (0.8e-3, 0.8 * REST_TOL, 0.04, 1.0))
#: RK4 step (s) of every segment. The friction law's viscous slope at zero slip,
#: 1.5 mu N / v_max (DESIGN.md), is the stiffest mode: standing on the foot (about 10 N
#: per contact point) RK4 at 4 ms is past its stability limit for it and settles into a
#: hidden fast oscillation of the foot's slip that biases the base velocities (measured:
#: the pitch rate off by 0.035 rad/s at rest while the positions agree), at 3 ms and below
#: the results agree with 0.25 ms to 5 digits. 2 ms leaves room for heavier loads.
DT = 2e-3
#: the handstand's rest ramp: `REST_RAMP` with two more stages (1.4x and 1.1x torque),
#: finer where the torque limits close in on what catching the body needs
HANDSTAND_REST_RAMP = REST_RAMP[:3] + ((0.02, 0.06, 0.3, 1.4),) + REST_RAMP[3:4] + ((0.005, 0.015, 0.08, 1.1),) + \
    REST_RAMP[4:]
#: the handstand's RK4 step (s): its hands land hard (about 180 N on the palm's edge for
#: a few ms), which puts the friction's viscous mode at ~2,000 1/s, past RK4's limit at
#: 2 ms (1.35 ms along the 2 ms solution). Planned at 2 ms, the "at rest" of the end was
#: partly the integrator's: re-simulated at 1.25, 1 and 0.5 ms the same controls end
#: with a pitch rate of -0.013 rad/s and the pitch 2.6 mrad off (criteria: 0.01, 1e-3).
#: At 1.25 ms the three agree to 3e-4 rad/s, and the step check along the solution is
#: ok (limit 1.48 ms)
HANDSTAND_DT = 1.25e-3


#: with ``dense_torque``: the factor on the effort limits of the every-step torque
#: constraint (level 2), stage by stage after the segment's plan, per segment (the
#: sampled solutions need 2.7x, handstand, 2.8x, roll, and 2.3x, standing, at their
#: impacts; a ramp that starts far looser than needed lets the first stage wander off)
DENSE_RAMPS = dict(handstand=(3.0, 2.6, 2.2, 1.9, 1.6, 1.4, 1.25, 1.1, 1.0), roll=(3.0, 2.2, 1.6, 1.25, 1.0),
                   standing=(2.4, 2.0, 1.6, 1.3, 1.1, 1.0), start=(1.1, 1.0))


def _plan(pitch_ramp=(), rest_ramp=REST_RAMP, rest_trust=None, pitch_trust=None):
    """Stages: the terminal pitch (equality, level 0) along ``pitch_ramp``, each stage
    within a box of ``pitch_trust`` rad around where it starts, then the ``rest_ramp``
    (level 1) at the last pitch, each of its stages within ``rest_trust`` (None: the
    problem's own trust region)."""
    final = pitch_ramp[-1] if len(pitch_ramp) else 2 * np.pi
    tr = {} if rest_trust is None else dict(trust_region=rest_trust)
    tp = {} if pitch_trust is None else dict(trust_region=pitch_trust)
    return ([dict(params=dict(pitch=p), level=0, **tp) for p in pitch_ramp] +
            [dict(params=dict(pitch=final, ptol=pt, vtol=v, atol=acc, tau_factor=f), level=1, **tr)
             for pt, v, acc, f in rest_ramp])


def tumbler_segment(name: str, *, n_ctrl: int | None = None, dt: float | None = None, t_final: float | None = None, q0=None,
                    v0=None, model=None, shooting: int = 1, guess: str = "default", n_path_samples: int = 40,
                    dense_torque: bool = False, roll_end: str = "free", dense_ramp=None):
    """One segment of the tumbler sequence as a `MotionProblem` (see the module docstring).

    Args:
      name: one of ``SEGMENTS``.
      n_ctrl: control points per active joint (default 12; the handstand
        `HANDSTAND_N_CTRL`). dt: RK4 step (s; default `DT`, the handstand
        `HANDSTAND_DT`).
      t_final: duration (s; default per segment).
      q0, v0: start state (default: the segment's nominal start posture at rest; in a
        sequence the previous segment's end state replaces it).
      shooting: multiple-shooting intervals (see `cstorm.optimize.problem`).
      n_path_samples: about how many grid points the torque limits are sampled at.
      dense_torque: also the motor limits on *every* integration step (level 2,
        `ScaledTorqueLimits` with ``dense=True`` and the factor ``tau_dense``), tightened
        after the segment's plan along ``dense_ramp`` (default `DENSE_RAMPS` of the
        segment). Without it the limits hold only at the ~40 samples, and the contact
        impacts between them need more than the motors have.
      roll_end: the roll's joints at its end: ``"free"`` (default) or ``"nominal"``
        (hip and shoulder positions and velocities of `ROLL_END`, by construction: the
        start the standing segment's guess and plan are tuned for; `tumbler` uses it).
      guess: ``"default"`` (the keyframes documented at each segment), or for the
        handstand ``"bridge"`` (`BRIDGE_KEYFRAMES` with `bridge_nodes` as the nodes' guess;
        needs ``shooting > 1``) with the terminal pitch at pi from the first stage.
    """

    model = robots.tumbler(feet=True) if model is None else model
    env, contact = env_contact()
    # the handstand's contact derivatives by plain autodiff: its plan was verified with
    # them. The analytic rule (the default, and the other segments') gives the same
    # Jacobians to 1e-14, yet SLSQP's path through the handstand's plan splits at its
    # fourth stage and then stalls (the 1.2x-torque stage at violation 1.55; refined, the
    # final stage creeps past 500 iterations at violation 3e-5)
    common = dict(env=env, contact=contact, costs=[C.TorqueSquared()], name=name, n_path_samples=n_path_samples,
                  shooting=shooting, contact_jacobians="autodiff" if name == "handstand" else "analytic")
    if roll_end not in ("free", "nominal"):
        raise ValueError(f"tumbler_segment: roll_end must be 'free' or 'nominal', got {roll_end!r}")
    if guess not in ("default", "bridge") or (guess == "bridge" and (name != "handstand" or shooting < 2)):
        raise ValueError(f"tumbler_segment: guess={guess!r} is not available for {name!r} with shooting={shooting} "
                         "(guesses: 'default'; 'bridge' for the handstand with shooting > 1)")
    dense = [ScaledTorqueLimits("tau_dense", stage=2, name="torque limits, every step", dense=True)] \
        if dense_torque else []
    dense_params = {"tau_dense": 1.0} if dense_torque else {}
    rest_params = {"ptol": REST_RAMP[-1][0], "vtol": REST_RAMP[-1][1], "atol": REST_RAMP[-1][2], "tau_factor": 1.0,
                   **dense_params}
    if n_ctrl is None:
        n_ctrl = HANDSTAND_N_CTRL if name == "handstand" else 12
    if dt is None:
        dt = HANDSTAND_DT if name == "handstand" else DT
    if name == "handstand":
        T = HANDSTAND_T if t_final is None else t_final
        q0 = start_q(model) if q0 is None else q0
        # keyframes in seconds -> fractions of T, holding the straight end posture to T
        kf = tuple((t / T, post) for t, post in HANDSTAND_KEYFRAMES if t < T) + ((1.0, (0.0, 0.0)),)
        p = MotionProblem(model, ["hip", "shoulder"], T, n_ctrl, dt, q0, v0, q_final_active={"hip": 0.0, "shoulder": 0.0},
                          rest_end=True, constraints=_rest_terms(pitch_eq=True) + dense, params={"pitch": np.pi, **rest_params},
                          initial_guess=keyframe_guess(kf, T, ("hip", "shoulder")), **common)
        p.solve_options["schedule"] = _plan((np.pi,), HANDSTAND_REST_RAMP, rest_trust=HANDSTAND_REST_TRUST,
                                            pitch_trust=HANDSTAND_PITCH_TRUST)
        # the ramp's stages only warm-start the next one: a loose tolerance is enough
        p.solve_options.update(intermediate_tol=1e-4, intermediate_max_iter=60, first_step=HANDSTAND_FIRST_STEP)
        # every step's grid-point Jacobians, as when its plan was verified: with the
        # constraint grid's only (`MotionProblem.record_grid_only`, 240 instead of 330 ms
        # per evaluation) the Jacobians move by ~1e-14, and SLSQP's path stalls at the
        # 1.1x-torque stage (violation 10 after 100 iterations, with either contact rule)
        p.record_grid_only = False
        if guess == "bridge":
            T_ = p.t_final
            p.x0 = p.initial_x(keyframe_guess(BRIDGE_KEYFRAMES, T_, ("hip", "shoulder")))
            p.node_guess = bridge_nodes(model, T_)
            p.solve_options["schedule"] = _plan((np.pi,))
    elif name == "roll":
        T = 1.5 if t_final is None else t_final
        q0 = handstand_q(model) if q0 is None else q0
        cons = [K.TerminalConstraint(lambda q, v, prm: q[2] - prm["pitch"], kind="ineq", stage=0,
                                     name="pitch past lying"),
                K.TerminalConstraint(lambda q, v, prm: 0.1 - q[1], kind="ineq", stage=0, name="torso on ground"),
                K.TerminalConstraint(lambda q, v, prm: v[2] - 1.0, kind="ineq", stage=1, name="still rolling"),
                ScaledTorqueLimits("tau_factor", stage=1, name="torque limits")] + dense
        # roll_end="nominal": the joints end as in ROLL_END (hip, shoulder; positions and
        # velocities, by construction), the state the standing segment's plan is tuned for
        pin = {} if roll_end == "free" else dict(
            q_final_active=dict(zip(("hip", "shoulder"), ROLL_END[0][3:])),
            v_final_active=dict(zip(("hip", "shoulder"), ROLL_END[1][3:])))
        p = MotionProblem(model, ["hip", "shoulder"], T, n_ctrl, dt, q0, v0, constraints=cons, **pin,
                          params={"pitch": 1.5 * np.pi - 0.2, "tau_factor": 1.0, **dense_params},
                          initial_guess=keyframe_guess(ROLL_KEYFRAMES, T, ("hip", "shoulder")), **common)
        p.solve_options.update(intermediate_tol=1e-4, intermediate_max_iter=40, first_step=0.1, trust_region=0.5)
    elif name == "standing":
        T = 2.0 if t_final is None else t_final
        if q0 is None:
            q0, v0 = ROLL_END
        p = MotionProblem(model, ["hip", "shoulder"], T, n_ctrl, dt, q0, v0, q_final_active={"hip": 0.0, "shoulder": 0.0},
                          rest_end=True, constraints=_rest_terms(pitch_eq=True) + dense,
                          params={"pitch": 2 * np.pi, **rest_params},
                          initial_guess=keyframe_guess(STANDING_KEYFRAMES, T, ("hip", "shoulder")), **common)
        p.solve_options["schedule"] = _plan((2 * np.pi,), rest_trust=0.2, pitch_trust=STANDING_PITCH_TRUST)
        p.solve_options.update(intermediate_tol=1e-4, intermediate_max_iter=60, first_step=STANDING_FIRST_STEP)
    elif name == "start":
        T = 2.0 if t_final is None else t_final
        q0 = standing_q(model) if q0 is None else q0
        p = MotionProblem(model, ["hip", "shoulder"], T, n_ctrl, dt, q0, v0,
                          q_final_active={"hip": 0.0, "shoulder": ARMS_DOWN}, rest_end=True,
                          constraints=_rest_terms(pitch_tol=0.05) + dense,
                          params={"pitch": 2 * np.pi, **rest_params},
                          initial_guess=keyframe_guess(START_KEYFRAMES, T, ("hip", "shoulder")), **common)
        p.solve_options["schedule"] = _plan()
        p.solve_options.update(intermediate_tol=1e-6, intermediate_max_iter=60, first_step=0.05, trust_region=0.05)
    else:
        raise ValueError(f"unknown tumbler segment {name!r}; segments are {SEGMENTS}")
    # a stage that fails (violation > 1e-2 when the solver stops) is run again after one
    # halfway from the stage before (see `cstorm.solve`): the plans above are sensitive
    # to rounding (a 1e-14 change of the gradients has sent the handstand's rest ramp
    # into a stall at violation 1.55)
    p.solve_options["refine"] = 2
    # the time-parallel tangent rule (`cstorm.simulate.tangents`): one values+Jacobian
    # evaluation of the handstand 330 ms against 643 ms by differentiating the scan, of
    # the roll 72 against 231 ms, of standing and start ~145 against 289 ms (2 cores);
    # single shooting only (the multiple-shooting guess="bridge" was not
    # measured with it)
    if shooting == 1:
        p.derivatives = "parallel"
    if dense_torque:  # after the plan, the limits on every step, tightened along DENSE_RAMPS
        # (no schedule: `cs.solve`'s default, one stage per level, before the dense level)
        plan = p.solve_options.get("schedule") or [dict(params={}, level=k) for k in range(p.n_levels - 1)]
        last = dict(plan[-1].get("params", {}))
        tr = {k: v for k, v in plan[-1].items() if k == "trust_region"}
        p.solve_options["schedule"] = list(plan) + [dict(params={**last, "tau_dense": f}, level=2, **tr)
                                                    for f in (DENSE_RAMPS[name] if dense_ramp is None else dense_ramp)]
    p.success_criteria = _criteria(name) if name == "roll" else _RestCriteria(_criteria(name), p)
    return p


class _RestCriteria:
    """Success criteria of an at-rest segment: the spec list of `_criteria`, and the
    `HOLD` test (``"holds still"``: max pitch deviation over the hold, rad; ``"still
    after hold"``: the largest base speed at its end)."""

    def __init__(self, spec, problem):
        self.spec, self.problem = spec, problem

    def __call__(self, sol):
        out = evaluate_criteria(self.spec, self.problem.model, sol)
        dev, _, vend = hold_test(self.problem, sol, HOLD["duration"])
        out["holds still"] = criterion(dev, HOLD["pitch_tol"], dev <= HOLD["pitch_tol"])
        out["still after hold"] = criterion(vend, HOLD["v_tol"], vend <= HOLD["v_tol"])
        return out


def _criteria(name):
    """Success criteria of a segment (checked on the solution by `cstorm.report`)."""
    feas = {"type": "constraint_violation", "tol": 1e-6, "name": "feasibility"}
    rest = [{"type": "final_v", "joint": j, "target": 0.0, "tol": REST_TOL, "name": f"{j} at rest"}
            for j in ("root_x", "root_z", "root_pitch")]
    if name == "handstand":
        return [feas, {"type": "final_q", "joint": "root_pitch", "target": np.pi, "tol": 1e-3, "name": "inverted"},
                *rest]
    if name == "roll":
        return [feas, {"type": "displacement", "joint": "root_pitch", "min": 0.5 * np.pi - 0.2,
                       "name": "rolled forward (rad)"}]
    if name == "standing":
        return [feas, {"type": "final_q", "joint": "root_pitch", "target": 2 * np.pi, "tol": 1e-3, "name": "upright"},
                *rest]
    return [feas, {"type": "final_q", "joint": "root_pitch", "target": 2 * np.pi, "tol": 0.05, "name": "upright"},
            {"type": "final_q", "joint": "shoulder", "target": ARMS_DOWN, "tol": 1e-6, "name": "arms down"}, *rest]


def tumbler(n_ctrl: int | None = None, dt: float | None = None):
    """The four-segment tumbler `MotionSequence` (see the module docstring)."""
    model = robots.tumbler(feet=True)
    segs = []
    for name in SEGMENTS:
        kw = {}
        if name == "standing":  # the roll's measured end; in the sequence the roll's actual end
            kw = dict(q0=ROLL_END[0], v0=ROLL_END[1])
        if name == "roll":  # the joints end as in ROLL_END: the standing plan's start (see roll_end)
            kw = dict(roll_end="nominal")
        segs.append(tumbler_segment(name, n_ctrl=n_ctrl, dt=dt, model=model, **kw))
    return MotionSequence(segs, name="tumbler")


EXAMPLES = {"tumbler": tumbler}
