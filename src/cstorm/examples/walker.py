"""A periodic walking problem for the planar biped of Gymnasium's ``Walker2d-v5``,
`cs.robots.walker_model` (every number of the model is there): one gait cycle (two
steps) at a chosen average speed, no contact schedule.

Contact (`walker_contact`, not Gymnasium's soft constraints): cstorm's smooth penalty law
on the two end spheres of every capsule against the ground (14 contact points). DESIGN.md's
tumbler values (k = 5e3 N/m, c = 100 N s/m for 3 kg) scaled by the mass ratio 23.7 / 3 ~ 8
(keeps the per-kilogram stiffness and the damping ratio): ``k = 4e4 N/m``, ``c = 800 N s/m``,
``d_on = 0.01 m``, ``d_off = 0``, ``eps = 0.01 N``, friction ``mu = 0.9`` on every capsule
(Gymnasium's body friction; its left foot has 1.9, which only stiffens the friction damper
``1.5 mu N / v_max``), ``v_max = 0.1 m/s``. With ``d_on > 0`` a foot at rest floats a few
millimetres above the ground (the force ramp starts at ``d_on``).

Solve plan
----------
Multiple shooting (``shooting=4``, nodes guessed by carrying the posture forward at
``speed``), a speed ramp 0.2, 0.4, 0.6 m/s whose intermediate stages are cut at 30
iterations (they only warm-start the next), the target speed, then the swing clearance
and `SlipPower` (<= 8 W per constraint sample) at level 1. Without the slip bound the
swing foot skims the ground inside the force ramp (``slip_power=None`` turns it off).
The success criteria (`walker_criteria`) do not yet check slip. Results:
docs/examples.md.
"""

from __future__ import annotations

import math

import numpy as np

from ..contact import ContactParams, Environment, contact_labels, ground
from ..optimize import constraints, costs
from ..optimize.bounds import variable_bounds
from ..optimize.constraints import SlipPower, SwingClearance
from ..optimize.problem import MotionProblem
from .planar import criterion as _entry, longest_run, trajectory_contact_d
from .robots import WALKER, walker_model


SIDES = ("r", "l")
ACTIVE = ("hip_r", "knee_r", "ankle_r", "hip_l", "knee_l", "ankle_l")


def standing_height():
    """Height of the torso centre (m) when the straight walker's feet touch the ground
    (``q = 0``, foot capsules tangent to z = 0): 1.21 m."""
    P = WALKER
    return P["torso"]["length"] / 2 + P["thigh"]["length"] + P["shin"]["length"] + P["foot"]["radius"]


def walker_contact(stiffness=4e4, damping=800.0, d_on=0.01, d_off=0.0, friction=0.9, v_max=0.1):
    """The walker's `ContactParams` (see the module docstring for the choice)."""
    return ContactParams(stiffness=stiffness, damping=damping, d_on=d_on, d_off=d_off, friction=friction,
                         v_max=v_max)


# ---------------------------------------------------------------------------------------
# The walking problem
# ---------------------------------------------------------------------------------------
def foot_flat_ankle(pitch, hip, knee):
    """The ankle angle (rad) that keeps the foot level, given the base pitch and the hip
    and knee angles: the hinges turn about -y and the pitch about +y, so the foot's pitch
    in the world is ``pitch - hip - knee - ankle``."""
    return pitch - hip - knee


def posture(split=0.2, knee=-0.1, pitch=0.0):
    """A double-support standing posture (the default initial guess): torso pitched by
    ``pitch`` rad, right thigh ``split`` rad forward of the torso axis, left thigh
    ``split`` back, both knees at ``knee`` rad, feet level; the base height puts the lower
    foot's sole 6 mm above the ground (about where the contact springs carry the weight).
    Returns ``q`` (9,) in the model's joint order."""
    P = WALKER
    t, lth, lsh, rf = P["torso"]["length"] / 2, P["thigh"]["length"], P["shin"]["length"], P["foot"]["radius"]
    q = np.zeros(9)
    q[2] = pitch
    lows = []
    for k, hip in ((3, split), (6, -split)):
        ankle = foot_flat_ankle(pitch, hip, knee)
        q[k: k + 3] = hip, knee, ankle
        a1, a2 = pitch - hip, pitch - hip - knee  # world pitch of thigh and shin (about +y)
        # ankle height below the torso centre (torso axis down, thigh, shin)
        lows.append(t * math.cos(pitch) + lth * math.cos(a1) + lsh * math.cos(a2))
    q[1] = max(lows) + rf + 0.006
    return q


FEET = (["foot_r_geom"], ["foot_l_geom"])
SWAP = (("hip_r", "hip_l"), ("knee_r", "knee_l"), ("ankle_r", "ankle_l"))
SPLIT = 0.2  # rad, the guess posture's hip angles (right forward, left back)


def _mirror(q):
    """Left and right legs exchanged in a (..., 9) array of q or v."""
    q = np.array(q, copy=True)
    q[..., 3:6], q[..., 6:9] = np.array(q[..., 6:9]), np.array(q[..., 3:6])
    return q


def walker(speed: float = 0.8, period: float = 1.2, n_ctrl: int = 9, dt: float = 0.005, clearance: float = 0.03,
           half_cycle: bool = True, integrator: str = "rk4", contact=None, n_path_samples: int = 30,
           continuation=True, staged: bool = True, hip_upper: float = math.radians(60.0),
           contact_geoms=("foot_*",), guess="hold", stages=None, shooting=4, moving_start=False,
           node_bound=None, slip_power=8.0):
    """A periodic walking gait of the walker at average speed ``speed`` m/s, gait cycle
    (two steps) ``period`` s.

    Robot: `walker_model` (Gymnasium's Walker2d numbers, hips' upper limit ``hip_upper``,
    see below) with `walker_contact` between the feet (``contact_geoms``, glob patterns;
    None: every capsule) and flat ground; active ``hip, knee, ankle`` of both legs
    (quintic B-splines, ``n_ctrl`` control points each), passive planar base.

    Periodic by a free start state (``MotionProblem(free_initial=...)``): the start
    height, pitch, every start velocity and the active joints' start angles and
    velocities are decision variables (offsets from the guess posture); ``root_x(0) = 0``.

    - ``half_cycle=True`` (default; mirror symmetry, half the work): the horizon is one
      step, ``period / 2``, and the end state equals the start state with the legs
      exchanged (`constraints.Periodic` with ``swap``; ``root_x`` aside). The left foot
      swings in this step (a naming convention: the guess starts with the left leg
      behind); the right foot swings in the mirrored second step. `full_cycle` assembles
      the two steps.
    - ``half_cycle=False``: the horizon is the whole cycle, ``period``, and the end state
      equals the start state (`constraints.Periodic`); both feet must swing.

    Equality constraints: the periodicity above and `AverageSpeed` (``root_x(T) -
    root_x(0) = speed T``). Inequalities: joint position limits and ``|tau| <= 100 N m``
    (sampled on ``n_path_samples`` grid points), and `SwingClearance`: the swinging foot
    (each foot, for the full cycle) is at least ``clearance`` m above the ground at some
    instant; when is not said (no contact schedule). Variable bounds (``x_bounds``, used
    by `solve`): the splines' free control points within the joint limits, the start
    offsets keep the active joints within their limits, the start height within +-0.2 m
    and pitch within +-0.5 rad of the guess, start velocities: forward 0 to ``2 speed + 0.5``
    m/s, vertical +-0.5 m/s, pitch rate +-2 rad/s, joints +-6 rad/s. Physically generous,
    they act as a trust region for SLSQP's first quasi-Newton steps.

    Cost: ``integral 1/2 |tau|^2 dt`` over the six motors (N^2 m^2 s).

    Hips: Gymnasium's walker2d lets a hip only extend (range [-150, 0] deg: the thigh can
    never swing forward of the torso's axis), so its gaits must lean the torso back. We
    keep every other number and widen the hips' upper limit to ``hip_upper`` (default +60
    deg, human hips flex ~120 deg) so that the robot can walk upright; ``hip_upper=0``
    gives Gymnasium's range.

    Initial guess (posture level): the double-support posture `posture` (torso upright,
    right thigh 0.2 rad forward of the torso axis, left 0.2 rad back, knees bent 0.1 rad,
    feet level, soles 6 mm up). ``guess="hold"`` (default): every joint held there, at
    rest; ``guess="ramp"``: the hips move linearly to the mirrored posture at the end of
    the step (half cycle) or there and back (full cycle). Nothing says when or how a foot
    lifts. ``moving_start=True`` starts the guess at ``speed`` forward instead of at rest.

    Multiple shooting (``shooting=K``, default 4; 1: single shooting): the base state
    (``root_x, root_z, root_pitch`` and their velocities) at the starts of intervals
    ``1..K-1`` are decision variables, guessed by ``node_guess``: the guess posture
    carried forward at ``speed`` (``root_x = speed t``, forward velocity ``speed``, all
    else as the posture at rest). Their bounds (``node_bound``, offsets from ``q0`` and
    velocities): ``root_x`` free, ``root_z`` +-0.3 m, pitch +-0.6 rad, velocities +-3 m/s
    forward, +-1 m/s vertical, +-3 rad/s pitch.

    Solve plan (``solve_options``): ``continuation`` (None: none; True (default): the
    speed ramped ``speed * (0.25, 0.5, 0.75, 1)``; or a list of speeds; the ramp's stages
    stop after 30 iterations or at tol 1e-4, they only warm-start the next); with
    ``staged=True`` (default) the swing clearance is switched on after the others (level
    1, a last stage at ``speed``). ``stages`` overrides the level of single constraints
    (dict with keys ``periodic, speed, limits, torque, swing``).

    No skating (``slip_power``, W, default 8; None: off): `SlipPower`, at level 1 with
    the swing clearance: the contact slip power at every constraint sample stays below
    it (a stance foot's penalty-friction creep costs ~2-4 W, a swing foot dragged along
    the ground tens of W).

    Attributes added: ``problem.success_criteria(solution) -> dict`` (`walker_criteria`).
    """
    model = walker_model(hip_upper=hip_upper)
    contact = walker_contact() if contact is None else contact
    env = Environment([ground()], pairs=None if contact_geoms is None else [(g, "ground") for g in contact_geoms])
    q0 = posture(split=SPLIT)
    t_final = period / 2 if half_cycle else period
    free = {"root_x": "v", "root_z": "qv", "root_pitch": "qv", **{j: "qv" for j in ACTIVE}}
    ts = np.linspace(0.0, t_final, 4 * n_ctrl)
    if guess == "ramp":
        ramp = 1.0 - 2.0 * ts / t_final if half_cycle else np.abs(1.0 - 2.0 * ts / t_final) * 2.0 - 1.0
        guess = {"hip_r": (ts, SPLIT * ramp), "hip_l": (ts, -SPLIT * ramp)}
    else:
        guess = None
    st = dict(periodic=0, speed=0, limits=0, torque=0, swing=1 if staged else 0)
    st.update(stages or {})
    swing = [FEET[1]] if half_cycle else list(FEET)
    v0 = np.zeros(9)
    if moving_start:
        v0[0] = speed
    node_guess = None
    if shooting > 1:
        def node_guess(t):  # the guess posture carried forward at the average speed
            q = q0.copy()
            q[0] = speed * t
            v = np.zeros(9)
            v[0] = speed
            return q, v
    prob = MotionProblem(
        model, active=ACTIVE, t_final=t_final, n_ctrl=n_ctrl, dt=dt, q0=q0, env=env, contact=contact,
        costs=[costs.TorqueSquared(weight=1.0)],
        constraints=[
            constraints.Periodic(exclude=("root_x",), swap=SWAP if half_cycle else None, stage=st["periodic"]),
            constraints.AverageSpeed("speed", stage=st["speed"]),
            constraints.JointLimits(list(ACTIVE), velocity=False, stage=st["limits"]),
            constraints.TorqueLimits(stage=st["torque"]),
            SwingClearance(swing, "clearance", stage=st["swing"]),
        ] + ([] if slip_power is None else [SlipPower("slip_power", stage=st["swing"])]),
        params={"speed": speed, "clearance": clearance, **({} if slip_power is None else {"slip_power": slip_power})}, integrator=integrator, n_path_samples=n_path_samples,
        name="walker", free_initial=free, initial_guess=guess, shooting=shooting,
        v0=v0, node_guess=node_guess,
    )
    prob.half_cycle = bool(half_cycle)
    # variable bounds (see the docstring): splines within the limits, start offsets boxed

    lb, ub = variable_bounds(prob)
    n0 = prob.n_spline_vars
    lo, hi = np.asarray(model.q_lower), np.asarray(model.q_upper)
    dq_idx, dv_idx = prob._fi_dq, prob._fi_dv  # v (= q, planar model) indices, in x order
    for k, i in enumerate(dq_idx):
        if i in (1, 2):
            lb[n0 + k], ub[n0 + k] = (-0.2, 0.2) if i == 1 else (-0.5, 0.5)
        else:
            lb[n0 + k], ub[n0 + k] = lo[i] - q0[i], hi[i] - q0[i]
    vbox = {0: (-v0[0], 2.0 * speed + 0.5 - v0[0]), 1: (-0.5, 0.5), 2: (-2.0, 2.0)}  # base x, z (m/s), pitch (rad/s)
    for k, i in enumerate(dv_idx):
        lb[n0 + len(dq_idx) + k], ub[n0 + len(dq_idx) + k] = vbox.get(i, (-6.0, 6.0))
    if shooting > 1:
        g = prob.variable_groups()
        nb = node_bound if node_bound is not None else dict(q=(np.inf, 0.3, 0.6), v=(3.0, 1.0, 3.0))
        for key, w in (("node_q", nb["q"]), ("node_v", nb["v"])):
            idx = g[key].reshape(shooting - 1, 3)
            for j in range(3):
                lb[idx[:, j]], ub[idx[:, j]] = -w[j], w[j]
    prob.x_bounds = (lb, ub)
    if continuation is True:
        prob.solve_options["continuation"] = {"speed": [speed * s for s in (0.25, 0.5, 0.75, 1.0)]}
    elif continuation:
        prob.solve_options["continuation"] = {"speed": list(continuation)}
    if prob.solve_options.get("continuation"):
        # the ramp's stages only warm-start the next: don't polish their cost
        prob.solve_options.update(intermediate_max_iter=30, intermediate_tol=1e-4)
    d_on = float(np.max(np.asarray(contact.d_on)))

    def criteria(solution):
        return walker_criteria(prob, solution, speed=speed, d_on=d_on)

    prob.success_criteria = criteria
    return prob


def full_cycle(problem, solution):
    """The whole gait cycle from a solution: dict ``t (M,)``, ``q (M, 9)``, ``v (M, 9)``,
    ``d (M, k)`` (contact distances; a full-cycle solution's own arrays). For a
    half-cycle solution the second step is the first with the legs exchanged, shifted
    forward by the step length and in time by the step duration (its first sample, the
    first step's last, is not repeated); contact points are exchanged foot for foot."""
    tr = solution.trajectory
    t, q, v = (np.asarray(tr[k]) for k in ("t", "q", "v"))
    d = trajectory_contact_d(tr, "walker criteria")
    if not getattr(problem, "half_cycle", False):
        return dict(t=t, q=q, v=v, d=d)
    labels = contact_labels(problem.model, problem.env)
    perm = []
    for geom, obs, feat in labels:
        other = geom.replace("_r_", "_X_").replace("_l_", "_r_").replace("_X_", "_l_")
        perm.append(labels.index((other, obs, feat)))
    q2, v2 = _mirror(q[1:]), _mirror(v[1:])
    q2[:, 0] += q[-1, 0] - q[0, 0]
    return dict(t=np.concatenate([t, t[1:] + t[-1]]), q=np.concatenate([q, q2]), v=np.concatenate([v, v2]),
                d=np.concatenate([d, d[1:][:, perm]]))


def walker_criteria(problem, solution, *, speed, d_on, periodic_tol=1e-6, speed_tol=1e-6, feas_tol=1e-6,
                    min_swing=0.1, max_penetration=0.01):
    """Success criteria of a walking gait, from a `Solution` (of `walker`, half or full
    cycle): a dict ``name -> dict(value, tol, op, ok)``:

    - ``feasibility``: the solver's constraint violation <= ``feas_tol``;
    - ``periodicity``: max |end - start| over every position (``root_x`` aside) and
      velocity (m, rad, m/s, rad/s) of the whole cycle (for a half cycle: the end state
      against the start state with the legs exchanged) <= ``periodic_tol``;
    - ``average_speed_error``: |root_x travelled / time - speed| (m/s) <= ``speed_tol``;
    - ``swing_time_r``, ``swing_time_l``: the longest interval (s) of the cycle during
      which every contact point of that foot is farther than ``d_on`` from the ground (no
      load: the foot takes a step) >= ``min_swing``;
    - ``max_penetration``: the deepest any contact point went below the ground (m) <=
      ``max_penetration`` (no feet through the floor).
    """
    tr = solution.trajectory
    q, v, t = (np.asarray(tr[k]) for k in ("q", "v", "t"))
    ix = problem.model.joint_q("root_x").start
    half = getattr(problem, "half_cycle", False)
    qe = np.delete((_mirror(q[0]) if half else q[0]) - q[-1], ix)  # every velocity, root_x's too
    ve = (_mirror(v[0]) if half else v[0]) - v[-1]
    per = float(max(np.max(np.abs(qe)), np.max(np.abs(ve))))
    avg = (q[-1, ix] - q[0, ix]) / (t[-1] - t[0])
    cyc = full_cycle(problem, solution)
    labels = contact_labels(problem.model, problem.env)
    out = dict(
        feasibility=_entry(solution.constraint_violation, feas_tol, solution.constraint_violation <= feas_tol),
        periodicity=_entry(per, periodic_tol, per <= periodic_tol),
        average_speed_error=_entry(abs(avg - speed), speed_tol, abs(avg - speed) <= speed_tol),
    )
    tc = cyc["t"]
    for side, geoms in zip(SIDES, FEET):
        idx = [i for i, lab in enumerate(labels) if lab[0] in geoms]
        _, longest = longest_run(tc, np.all(cyc["d"][:, idx] > d_on, axis=1))
        out[f"swing_time_{side}"] = _entry(longest, min_swing, longest >= min_swing, op=">=")
    pen = max(0.0, -float(np.min(cyc["d"])))
    out["max_penetration"] = _entry(pen, max_penetration, pen <= max_penetration)
    return out


#: the fast variant's numbers (`fast_variant`): half the speed, 7 control points per joint
FAST = dict(speed=0.4, n_ctrl=7)


def fast_variant():
    """The walker's fast variant (CI runs it; the full plan takes ~400 iterations): one
    step of a periodic gait at 0.4 m/s (`FAST`: half the default speed, 7 control points
    per joint instead of 9), solved without the speed ramp: the speed constraint at
    level 0 cut at 30 iterations, then the swing clearance and the slip bound (level 1)
    to SLSQP tolerance 1e-6. Same criteria as `walker` (`walker_criteria` at 0.4 m/s).
    The gait it finds is feasible, not polished (the stance foot skips mid-step).
    Returns the `MotionProblem` with that plan in ``solve_options``."""
    p = walker(**FAST, continuation=None)
    speed = FAST["speed"]
    p.solve_options["schedule"] = [dict(params=dict(speed=speed), level=0, max_iter=30, tol=1e-4),
                                   dict(params=dict(speed=speed), level=1, max_iter=150, tol=1e-6)]
    return p

EXAMPLES = {"walker": walker}
