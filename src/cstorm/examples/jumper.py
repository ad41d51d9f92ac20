"""The jumper: a small planar one-legged robot that must jump (leave the ground for a
while) and land back at rest, a contact problem whose gradients run through making and
breaking contact (issue 4's "small contact problem").

Model: `cs.robots.jumper_model` (every number is in `cs.robots.JUMPER`).

Contact (`jumper_contact`): `cstorm.contact_forces` on every capsule end sphere (6
points) against flat ground, with DESIGN.md's feasibility-study values k = 5e3 N/m,
c = 100 N s/m, friction mu = 0.8, eps = 0.01 N, and two deliberate changes:

- the force ramp is shifted to straddle the surface, ``d_on = +5 mm``, ``d_off = -5 mm``
  (the study's ``d_on = 10 mm, d_off = 0`` makes a resting body float ~5 mm above the
  ground): standing, the foot rests 0.1 mm above the ground; in the air (all distances
  above ``d_on``) the contact force is exactly zero.
- ``v_max = 0.3 m/s`` (the draft's 0.1): near zero slip, friction is a viscous damper
  ``1.5 mu N / v_max`` whose stiffest mode, for this light robot standing on its foot, is
  about -720 1/s with 0.1 m/s — beyond RK4's stability limit (2.79/|lambda| ~ 3.9 ms)
  at the 4 ms steps of the fast variant; with 0.3 m/s it is -240 1/s (at rest; impacts
  raise it with the normal force). The price: a foot under a horizontal load creeps at
  a few cm/s instead of ~1 cm/s.

Problem (`jumper`)
------------------
Start: crouched at rest, ``shank_angle = 0.5`` rad (shank tilted forward, foot flat,
body CoM over the foot centre: knee 1.079 rad, ankle -0.5 rad), base at the contact
equilibrium (`rest_configuration`, accelerations < 1e-12). End (``t_final``): the same
posture at rest (active joints by construction; the base by inequality constraints
``|z(T) - z0|, |pitch(T) - pitch0| <= qtol`` and ``|v_x|, |v_z|, |v_pitch| <= vtol`` at
``T``; ``root_x`` is free). Cost: ``integral 1/2 (tau_knee^2 + tau_ankle^2) dt``
(N^2 m^2 s). Constraints (sampled on ``n_path_samples`` grid points):

- flight: every contact point at least ``clearance = 2 cm`` above the ground (so no
  contact force at all) at every sample in the time window ``flight = (0.40, 0.48) s``;
- pitch: ``|pitch - pitch0| <= max_pitch = 0.5`` rad at every sample (keeps the solver
  out of the basin where the robot lands lying on its back, see below);
- joint position limits, ``|tau| <=`` the effort limits;
- the landing at rest as above.

Initial guess (posture level, `GUESS`): hold the crouch, extend the knee and point the
toe by 0.40 T (push-off), tuck, land in the crouch by 0.65 T. At ``dt = 4 ms`` its
rollout leaves the ground for 0.06 s (0.48-0.54 s), apex clearance 8.6 mm, heel strike
5 x body weight, lands within 3 mm / 0.06 rad of the crouch, pitch never beyond 0.35
rad: a point where the rollout makes and breaks contact (the gradient tests use it).
The free control points are boxed to ``x0 +- trust`` (0.8 rad) within the joint limits
(``problem.x_bounds``). Solve plan (``solve_options["schedule"]``): the landing enters
first as a terminal penalty ``w_land/2 (|z - z0|^2 + |pitch - pitch0|^2 + |v_base|^2)``
with ``w_land`` ramped 1, 10, 100 (constraint level 0: flight, pitch, limits), then
the landing constraints (level 1) at ``qtol = 5 mm/rad, vtol = 1 cm/s``, then ``1e-3``.

**Status: not yet solved.** The hopper's formulation (`hopping.hop_problem` on this
model: the crouch of ``crouch_angles(0.5)`` as ``q_rest``, keyframes from `GUESS`,
distance 0, 1.0 s, RK4 at 4 ms, 16 control points, 5 shooting intervals, clearance 2 cm,
``max_pitch`` 0.5, the hopper's `RAMP`, every-step torque limits) converges to a 0.35 s
flight landing at rest and meets every `hop_criteria` entry except the penetration
(15.8 mm at the landing against 1 cm: k = 5e3 N/m stops a 2.7 kg robot falling from
~15 cm only that deep); a bare penetration bound makes the later stages fail their line
searches. A lower jump (a clearance window, or a bound on the flight's height) is the
next thing to try. The plan above (penalty, then landing constraints), SLSQP or IPOPT,
does not reach the landing at rest: in flight the pitch is fixed by the angular
momentum at take-off, which 12-point splines (knot spacing 0.14 s, longer than the
push-off) shape only coarsely.

Soft contact: the penalty law lets the foot sink into the ground under load: in the
motions above the heel strike reaches 5-13 x body weight and 1.3-3.6 cm penetration
(k = 5e3 N/m). `jump_report` gives the figures of a motion.
"""

from __future__ import annotations

import numpy as np
import jax.numpy as jnp
from scipy.optimize import brentq, fsolve

from ..contact import ContactParams, Environment, ground, normal_force
from ..errors import InputError
from ..optimize import constraints as C, costs
from ..optimize.bounds import variable_bounds
from ..optimize.problem import MotionProblem
from .robots import JUMPER, jumper_model


ACTIVE = ("knee", "ankle")
# Posture-level initial guess: keyframes (times as fractions of t_final; joint offsets
# from the crouch, rad) linearly interpolated and fitted by the splines: hold the
# crouch, extend the knee and point the toe (push-off), tuck, land in the crouch.
GUESS = dict(t=(0.0, 0.25, 0.40, 0.525, 0.65, 0.75, 1.0),
             knee=(0.0, 0.0, -1.079, 0.121, 0.0, 0.0, 0.0),
             ankle=(0.0, 0.0, 1.1, 0.0, 0.0, 0.0, 0.0))


def jumper_contact(**changes):
    """The jumper's `ContactParams` (module docstring); keyword arguments override."""
    return ContactParams(**{**JUMPER["contact"], **changes})


def _rot(a):
    """Rotation about +y by ``a`` acting on (x, z)."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, s], [-s, c]])


def _planar(knee, ankle, foot_angle, ankle_xz):
    """Host-side planar kinematics from the foot: the configuration q (5,), the CoM
    (x, z) and the heel/toe sphere centres (x, z) for a foot at ``foot_angle`` (rad)
    with the ankle at ``ankle_xz`` (m)."""
    P = JUMPER
    b, s, f = P["body"], P["shank"], P["foot"]
    a = np.asarray(ankle_xz, float)
    t_shank = foot_angle - ankle
    t_body = t_shank - knee
    knee_p = a + _rot(t_shank) @ [0.0, s["length"]]
    body_o = knee_p + _rot(t_body) @ [0.0, b["length"] / 2]
    coms = np.stack([knee_p + _rot(t_body) @ [0.0, b["length"] / 2 + b["com"]],
                     a + _rot(t_shank) @ [0.0, s["length"] / 2], a + _rot(foot_angle) @ [f["x"], f["z"]]])
    ms = np.array([b["mass"], s["mass"], f["mass"]])
    ends = [a + _rot(foot_angle) @ [f["x"] + sg * f["length"] / 2, f["z"]] for sg in (-1.0, 1.0)]
    q = np.array([body_o[0], body_o[1], t_body, knee, ankle])
    return q, ms @ coms / ms.sum(), ends, ms.sum()


def crouch_angles(shank_angle: float):
    """``(knee, ankle)`` (rad) of a crouch with the foot flat, the shank tilted forward by
    ``shank_angle`` rad and the CoM over the foot's centre."""
    fx = JUMPER["foot"]["x"]
    off = lambda k: _planar(k, -shank_angle, 0.0, (0.0, 0.0))[1][0] - fx
    lo, hi = 0.0, JUMPER["knee"]["upper"]
    if off(lo) * off(hi) > 0:
        raise InputError(f"jumper: no crouch with the CoM over the foot for shank_angle={shank_angle!r} rad")
    k = brentq(off, lo, hi, xtol=1e-14)
    return k, -float(shank_angle)


def rest_configuration(knee: float, ankle: float, contact=None, x: float = 0.0):
    """The configuration q (5,) in which the jumper with active angles ``knee, ankle``
    stands still on flat ground: the foot's tilt and height at which the heel's and toe's
    normal forces carry the weight with no net moment about the CoM (static equilibrium
    of the passive base; friction is zero at rest). ``x``: the ankle's x (m)."""
    cp = jumper_contact() if contact is None else contact
    r, W = JUMPER["foot"]["radius"], None
    N = lambda d: float(normal_force(jnp.asarray(d), jnp.asarray(0.0), cp))

    def residual(u):
        q, com, ends, m = _planar(knee, ankle, u[0], (x, u[1]))
        w = m * JUMPER["gravity"]
        Fh, Ft = N(ends[0][1] - r), N(ends[1][1] - r)
        return [(Fh + Ft - w) / w, (Fh * (ends[0][0] - com[0]) + Ft * (ends[1][0] - com[0])) / w]

    u, info, ier, msg = fsolve(residual, [0.0, -JUMPER["foot"]["z"] + r], full_output=True, xtol=1e-14)
    if ier != 1 or np.max(np.abs(residual(u))) > 1e-10:
        raise InputError(f"jumper: no standing equilibrium for knee={knee!r}, ankle={ankle!r} rad ({msg})")
    return _planar(knee, ankle, u[0], (x, u[1]))[0]


def jumper(t_final: float = 1.0, n_ctrl: int = 12, dt: float = 0.002, flight=(0.40, 0.48),
           clearance: float = 0.02, shank_angle: float = 0.5,
           n_path_samples: int = 50, integrator: str = "rk4", contact=None, schedule=None,
           max_pitch: float = 0.5, trust: float = 0.8):
    """Jump from a crouch, fly, and land back in the crouch at rest (module docstring).

    Args:
      t_final: duration (s). n_ctrl: control points per active joint (>= 7 and enough to
        shape crouch, push, tuck and landing). dt: RK4
        step (s; <= 4 ms with the default contact, see the module docstring).
      flight: the time window (s) in which every contact point must be at least
        ``clearance`` m above the ground (problem parameter ``"clearance"``).
      shank_angle: the crouch (rad), see `crouch_angles`.
      contact: `ContactParams` (default `jumper_contact()`).
      schedule: the solve plan (default: the one in the module docstring; ``[]`` for
        none: one stage with every constraint).
      max_pitch: bound (rad) on ``|pitch - pitch0|`` at every sample (problem parameter
        ``"max_pitch"``).
      trust: half-width (rad) of the box around the initial guess that the free control
        points stay in (within the joint limits); None: the joint limits only.

    Returns a `MotionProblem` named ``"jumper"``; ``cs.solve(problem)`` follows
    ``problem.solve_options["schedule"]``. ``problem.success_criteria`` checks the
    flight and the landing on the solution.
    """
    model = jumper_model()
    cp = jumper_contact() if contact is None else contact
    knee, ankle = crouch_angles(shank_angle)
    q0 = rest_configuration(knee, ankle, cp)
    z0, p0 = float(q0[1]), float(q0[2])
    tt = np.linspace(0.0, 1.0, 101)
    guess = {name: (tt * t_final, np.interp(tt, GUESS["t"], GUESS[name]) + q0[3 + k]) for k, name in enumerate(ACTIVE)}

    def pitch_bound(t, q, v, a, tau, params):
        e = q[2] - p0
        return jnp.stack([params["max_pitch"] - e, params["max_pitch"] + e])
    prob = MotionProblem(
        model, active=ACTIVE, t_final=t_final, n_ctrl=n_ctrl, dt=dt, q0=q0, env=Environment([ground()]),
        contact=cp, q_final_active=q0[3:], rest_end=True, rest_start=True,
        costs=[costs.TorqueSquared(),
               costs.StateTarget("root_z", q=z0, v=0.0, weight="w_land"),
               costs.StateTarget("root_pitch", q=p0, v=0.0, weight="w_land"),
               costs.StateTarget("root_x", v=0.0, weight="w_land")],
        constraints=[
            C.ContactDistance("clearance", window=flight, name="flight"),
            C.PathConstraint(pitch_bound, name="pitch"),
            C.JointLimits(list(ACTIVE), velocity=False),
            C.TorqueLimits(),
            C.TerminalState("root_z", q=z0, kind="ineq", tol="qtol", stage=1, name="land_z"),
            C.TerminalState("root_pitch", q=p0, kind="ineq", tol="qtol", stage=1, name="land_pitch"),
            C.TerminalState("root_z", v=0.0, kind="ineq", tol="vtol", stage=1, name="rest_vz"),
            C.TerminalState("root_pitch", v=0.0, kind="ineq", tol="vtol", stage=1, name="rest_vpitch"),
            C.TerminalState("root_x", v=0.0, kind="ineq", tol="vtol", stage=1, name="rest_vx"),
        ],
        params={"clearance": clearance, "w_land": 0.0, "qtol": 1e-3, "vtol": 1e-3, "max_pitch": max_pitch},
        integrator=integrator, n_path_samples=n_path_samples, name="jumper", initial_guess=guess,
    )
    prob.rest_q = q0
    if trust is not None:
        lb, ub = variable_bounds(prob)  # the joint limits
        prob.x0 = np.clip(np.asarray(prob.x0, float), lb, ub)
        prob.x_bounds = (np.maximum(lb, prob.x0 - trust), np.minimum(ub, prob.x0 + trust))
    if schedule is None:
        schedule = [dict(params=dict(w_land=w), level=0) for w in (1.0, 10.0, 100.0)] + [
            dict(params=dict(w_land=100.0, qtol=5e-3, vtol=1e-2), level=1),
            dict(params=dict(w_land=100.0, qtol=1e-3, vtol=1e-3), level=1)]
    if schedule:
        prob.solve_options["schedule"] = schedule
    d_on = float(np.max(np.asarray(cp.d_on)))

    def criteria(solution):
        return jump_criteria(solution, q0, d_on=d_on, min_flight=flight[1] - flight[0])

    prob.success_criteria = criteria
    return prob


def jump_report(trajectory, q_rest, d_on=None):
    """Figures of a jumper motion from a solution's ``trajectory`` dict (``t, q, v, a``
    and ``contact`` with per-point ``d`` (N+1, k) and ``normal_magnitude``): the longest
    flight (all contact distances ``> d_on``: no contact force at all) and when, the
    apex clearance, the deepest penetration, the largest normal force, and the landing
    residuals at the end (base position error against ``q_rest`` for z and pitch, base
    velocities, passive accelerations)."""
    d_on = JUMPER["contact"]["d_on"] if d_on is None else d_on
    t = np.asarray(trajectory["t"])
    c = trajectory["contact"]
    d = np.asarray(c["d"] if isinstance(c, dict) else c.d)
    Nm = np.asarray(c["normal_magnitude"] if isinstance(c, dict) else c.normal_magnitude)
    air = np.all(d > d_on, axis=1)
    best, start, run0 = (0.0, None, None), None, None
    for k, a in enumerate(air):
        if a and start is None:
            start = k
        if (not a or k == len(air) - 1) and start is not None:
            end = k if not a else k + 1
            dur = t[end - 1] - t[start] if end - 1 > start else 0.0
            if dur > best[0]:
                best = (dur, t[start], t[end - 1])
            start = None
    q, v, a = (np.asarray(trajectory[k]) for k in ("q", "v", "a"))
    return dict(flight_s=float(best[0]), takeoff_s=best[1], touchdown_s=best[2],
                apex_clearance_m=float(np.max(np.min(d, axis=1))), min_distance_m=float(np.min(d)),
                max_normal_force_n=float(np.max(Nm)),
                weight_n=float(sum(JUMPER[k]["mass"] for k in ("body", "shank", "foot")) * JUMPER["gravity"]),
                land_z_err_m=float(abs(q[-1, 1] - q_rest[1])), land_pitch_err_rad=float(abs(q[-1, 2] - q_rest[2])),
                land_v=[float(x) for x in v[-1, :3]], land_a=[float(x) for x in a[-1, :3]],
                displacement_x_m=float(q[-1, 0] - q[0, 0]))


def jump_criteria(solution, q_rest, d_on, min_flight):
    """Success criteria of a jumper solution: a flight of at least ``min_flight`` s,
    landing within 1e-3 (m, rad) of the rest posture, base velocities within 1e-3."""
    r = jump_report(solution.trajectory, q_rest, d_on)
    out = {"flight_s": dict(value=r["flight_s"], tol=min_flight, op=">=", ok=r["flight_s"] >= min_flight - 1e-9)}
    for name, val in (("land_z_err_m", r["land_z_err_m"]), ("land_pitch_err_rad", r["land_pitch_err_rad"]),
                      ("land_speed", float(np.max(np.abs(r["land_v"]))))):
        out[name] = dict(value=val, tol=1e-3 + 1e-9, op="<=", ok=val <= 1e-3 + 1e-9)
    return out


EXAMPLES = {"jumper": jumper}
