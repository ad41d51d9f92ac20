"""Building blocks shared by the hopping examples (`hopper`, `luxo`): the standing
equilibrium, the hop-forward-and-land problem and its success criteria computed from a
`Solution`. Its terms (`FlightClearance`, `AtRest`, ...) are `cstorm.optimize`'s.

Not an example itself: it registers no problem (no ``EXAMPLES``).
"""

from __future__ import annotations

import numpy as np
import jax
import jax.numpy as jnp

from ..analysis.torque import torque_check
from ..contact import Environment, contact_forces, ground
from ..dynamics.hybrid import hybrid_unchecked
from ..dynamics.passive import passive_forces
from ..optimize import constraints, costs
from ..optimize.constraints import AtRest, FlightClearance, ForwardDistance, PitchBound, ScaledTorqueLimits
from ..optimize.costs import LandingPenalty
from ..optimize.guesses import keyframe_guess
from ..optimize.problem import MotionProblem
from ..optimize.bounds import variable_bounds
from ..simulate import RolloutLayout
from .planar import criterion, hold_test, longest_run, trajectory_contact_d

__all__ = ["standing_equilibrium", "hop_criteria", "flight_time", "hop_problem"]


def standing_equilibrium(model, env, contact, q_guess, active, iters=30, tol=1e-12):
    """The static equilibrium of the passive DoFs with the active joints held at their
    ``q_guess`` values: Newton's method on ``a_p(q_p) = 0`` at ``v = 0`` (hybrid dynamics
    with contact forces, zero active accelerations). Returns ``(q, |a_p|_inf)``, q (nq,).
    Compiles a small function (a few seconds)."""
    lay = RolloutLayout.make(model, active)
    qp_idx, vp_idx = np.array(lay.qp_idx, int), np.array(lay.vp_idx, int)
    q_guess = jnp.asarray(q_guess, jnp.float64)
    v = jnp.zeros(model.nv)

    @jax.jit
    def acc(qp):
        q = q_guess.at[qp_idx].set(qp)
        f = contact_forces(model, env, contact, q, v).f_ext
        pf = passive_forces(model, q, v)
        return hybrid_unchecked(model, q, v, jnp.zeros(lay.n_active), pf[vp_idx], lay.active, f)[1]

    jac = jax.jit(jax.jacfwd(acc))
    qp = q_guess[qp_idx]
    for _ in range(iters):
        a = acc(qp)
        if float(jnp.max(jnp.abs(a))) < tol:
            break
        J = jac(qp)
        # the horizontal position is neutral (flat ground): least-squares step
        step = jnp.linalg.lstsq(J, -a, rcond=1e-10)[0]
        qp = qp + step
    a = acc(qp)
    return np.asarray(q_guess.at[qp_idx].set(qp)), float(jnp.max(jnp.abs(a)))


def flight_time(t, d, d_on):
    """Total time (s) during which every contact point is farther than ``d_on`` (no
    contact force at all) on the grid ``t`` (N+1,), ``d`` (N+1, k); and the longest such
    interval: ``(total, longest)``."""
    return longest_run(t, np.all(np.asarray(d) > np.asarray(d_on), axis=1))


def hop_criteria(problem, solution, *, distance, min_flight, z_rest, pitch_rest, pose_tol_z=0.005,
                 pose_tol_pitch=np.radians(2.0), vel_tol=1e-3, acc_tol=1e-2, feas_tol=1e-6, max_penetration=0.01,
                 d_on=None, hold=None):
    """Success criteria of a hop-and-land problem, from a `Solution`: a dict ``name ->
    dict(value, tol, ok)``:

    - ``feasibility``: the solver's constraint violation <= ``feas_tol``;
    - ``forward_distance``: base x travelled (m) >= ``distance`` (``tol`` is the target);
    - ``flight_time``: the longest interval with every contact point beyond ``d_on`` (no
      contact force) >= ``min_flight`` s;
    - ``final_height_error``, ``final_pitch_error``: |base z - z_rest| (m) and |pitch -
      pitch_rest| (rad) at T, the standing rest pose;
    - ``final_base_speed``: max |v_base| (m/s, rad/s) at T <= ``vel_tol``;
    - ``final_base_accel``: max |a_base| at T <= ``acc_tol`` (at rest, not mid-bounce);
    - ``max_penetration``: the deepest any contact point went below the ground (m) <=
      ``max_penetration`` (no limbs through the floor);
    - ``torque_limits``: the largest ``|tau_i| / limit_i`` of the active joints on *every*
      integration step (not only at the constraint's samples) <= 1 (+1e-6): the motors can
      deliver the motion;
    - with ``hold`` (a dict ``duration`` s, ``pitch_tol`` rad, ``pos_tol`` m, ``v_tol``
      m/s and rad/s): `planar.hold_test`, the robot kept ``duration`` s more with its
      joints locked stays put: ``holds_still_pitch``, ``holds_still_position`` (the
      largest deviations from the final pose) and ``still_after_hold`` (the base speed at
      the end of the hold).
    """

    tr = solution.trajectory
    tq = torque_check(problem, solution)
    m = problem.model
    ix, iz, ip = (m.joint_q(n).start for n in ("root_x", "root_z", "root_pitch"))
    vp = np.array(problem.layout.vp_idx, int)
    q, v, a, t = (np.asarray(tr[k]) for k in ("q", "v", "a", "t"))
    d = trajectory_contact_d(tr, "hop criteria")
    d_on = float(np.max(np.asarray(problem.contact.d_on))) if d_on is None else float(d_on)
    _, longest = flight_time(t, d, d_on)
    fwd = q[-1, ix] - q[0, ix]
    out = dict(
        feasibility=criterion(solution.constraint_violation, feas_tol, solution.constraint_violation <= feas_tol),
        forward_distance=criterion(fwd, distance, fwd >= distance - 1e-6, op=">="),
        flight_time=criterion(longest, min_flight, longest >= min_flight, op=">="),
        final_height_error=criterion(abs(q[-1, iz] - z_rest), pose_tol_z, abs(q[-1, iz] - z_rest) <= pose_tol_z),
        final_pitch_error=criterion(abs(q[-1, ip] - pitch_rest), pose_tol_pitch,
                                 abs(q[-1, ip] - pitch_rest) <= pose_tol_pitch),
        final_base_speed=criterion(np.max(np.abs(v[-1, vp])), vel_tol, np.max(np.abs(v[-1, vp])) <= vel_tol),
        final_base_accel=criterion(np.max(np.abs(a[-1, vp])), acc_tol, np.max(np.abs(a[-1, vp])) <= acc_tol),
        max_penetration=criterion(max(0.0, -float(np.min(d))), max_penetration, -float(np.min(d)) <= max_penetration),
        torque_limits=criterion(tq["worst_ratio"], 1.0, tq["ok"]),
    )
    if hold is not None:
        dev, pos, vend = hold_test(problem, solution, hold["duration"])
        out.update(holds_still_pitch=criterion(dev, hold["pitch_tol"], dev <= hold["pitch_tol"]),
                   holds_still_position=criterion(pos, hold["pos_tol"], pos <= hold["pos_tol"]),
                   still_after_hold=criterion(vend, hold["v_tol"], vend <= hold["v_tol"]))
    return out


#: the default landing ramp of `hop_problem`: (fraction of the distance, landing tolerance)
RAMP = ((1 / 3, 0.05), (2 / 3, 0.02), (5 / 6, 0.01), (0.91625, 0.01), (1.0, 0.01), (1.0, 0.005), (1.0, 0.002),
        (1.0, 5e-4))


#: with ``dense_torque``: the factor on the effort limits of the every-step torque
#: constraint, stage by stage (the sampled solution needs up to 1.11x at the landing)
DENSE_RAMP = (1.25, 1.1, 1.0)


def hop_problem(name, model, active, q_rest, contact, *, distance, t_final, n_ctrl, dt, clearance, max_pitch,
                w_land, min_flight, keyframes, integrator="rk4", schedule=None, intermediate_tol=1e-4,
                intermediate_max_iter=60, n_path_samples=50, trust=1.0, margin=1.0, first_step=None,
                land_tol=1e-6, ramp=None, max_penetration=0.01, shooting=1, dense_torque=False,
                dense_ramp=DENSE_RAMP, end_posture_tol=None, rest_accel=False, extra=(),
                criteria_options=None, final_tol=None):
    """The hop-forward-and-land problem shared by `hopper` and `luxo`: a `MotionProblem`
    that starts at rest in the standing equilibrium ``q_rest`` (nq,: planar base ``root_x,
    root_z, root_pitch`` then the active joints) and ends in the same posture, at rest,
    at least ``distance`` m further along x. ``contact``: `ContactParams` against flat
    ground.

    - active joints ``active``: quintic B-splines (``n_ctrl`` control points), start and
      end at their ``q_rest`` values at rest (by construction);
    - cost: ``integral 1/2 |tau|^2 dt`` plus `LandingPenalty` (weight: the problem
      parameter ``w_land``, 0 by default, so the problem as stated is the torque cost
      alone; the solve plan sets it to ``w_land`` in every stage: a guide for SLSQP's
      first stages, about 0 at the solution, where the landing constraints hold);
    - constraints, stage 0: `ForwardDistance` (``distance``), joint position limits and
      `ScaledTorqueLimits` (sampled), `FlightClearance` (``clearance``: a flight phase,
      not scheduled), `PitchBound` (``|pitch - pitch_rest| <= max_pitch``);
      stage 1: the landing at rest, `AtRest` (base velocities at ``t_final``) and the
      terminal base height and pitch of ``q_rest``, each within ``land_tol`` (m, rad,
      m/s, rad/s; a problem parameter, default 1e-6). With the active joints at rest in
      their rest posture this is the standing equilibrium up to ``land_tol`` (the base
      acceleration at ``T`` is then about ``k land_tol / m``: 2e-3 m/s^2 for the hopper);
    - initial guess: `keyframe_guess` of ``keyframes``;
    - variable bounds (``problem.x_bounds``): every free control point within ``trust``
      rad of the guess's and within ``margin`` rad of the joint's limits. A box trust
      region: SLSQP's first quasi-Newton steps otherwise move control points by radians
      and throw the robot over, where the linearized contact constraints mean nothing.
      The control points of a quintic spline that moves fast (a push-off in 0.15 s with
      knots 0.1 s apart) lie well outside the range of the path itself, so bounding them
      by the joint limits (`cstorm.optimize.solve.variable_bounds`' default) would forbid a
      hop; the path's limits are the sampled `JointLimits` constraints instead;
    - solve plan ``schedule`` (``[{"params": {...}, "level": k}, ...]``; default: a
      third of the distance with the landing as the penalty only (stage 0; ``w_land``
      ramped 1 %, 10 %, then 100 % from here on), then with the landing constraints
      (stage 1) along ``ramp`` (``(fraction of the distance, landing tolerance)`` pairs,
      default `RAMP`: the distance ramped to 100 % at a 1 cm tolerance, then the
      tolerance tightened 5, 2, 0.5 mm), then ``land_tol``: the robot first learns to land
      at rest, then to go further, then to land precisely, and no stage starts far from
      its constraints; changing distance and tolerance in one stage made SLSQP diverge),
      intermediate stages solved to
      ``intermediate_tol`` in at most ``intermediate_max_iter`` iterations; with
      ``first_step`` (rad) SLSQP's first step of each stage is about that long (see
      `cstorm.solve`'s ``objective_scale``), not a radian;
    - ``problem.success_criteria``: `hop_criteria` with ``min_flight`` (s) and
      ``max_penetration`` (m);
    - ``shooting``: `MotionProblem`'s multiple shooting intervals (default 1: single
      shooting); the node states are not bounded by ``trust``;
    - ``dense_torque``: the motor limits on every integration step too (stage 2,
      `ScaledTorqueLimits` with ``dense=True`` and the factor ``tau_factor`` on the limits):
      after the landing ramp, at its last tolerance, the factor goes along ``dense_ramp``
      (default `DENSE_RAMP`, 1.25 -> 1), then the final ``land_tol`` stage keeps it at 1.
      The sampled limits (stage 0) alone let a contact impact between two samples need
      more than the motor has;
    - ``end_posture_tol`` (rad): the active joints' end positions are free, each within
      this of its ``q_rest`` value (stage 1; `TerminalState` inequalities), instead of
      pinned; ``rest_accel=True``: the base's end is `AtRest` with velocities within
      ``land_tol`` and accelerations within the parameter ``acc_tol``, the terminal
      height and pitch within the parameter ``pose_tol``; the ``ramp`` entries are
      ``(fraction, land_tol, acc_tol, pose_tol)``, the last one is the final stage (no
      separate ``land_tol`` stage; the ``land_tol`` argument is not used) and gives the
      parameters' initial values;
    - ``extra``: more constraint terms (e.g. `cstorm.optimize.SlipPower`); ``criteria_options``:
      keyword arguments of `hop_criteria` (``acc_tol``, ``hold``, ...); ``final_tol``:
      the last stage's SLSQP tolerance.
    Parameters ``distance, clearance, max_pitch, w_land`` are problem parameters."""
    q_rest = np.asarray(q_rest, float)
    ia = [model.joint_q(n).start for n in active]
    ramp = RAMP if ramp is None else ramp
    # the landing tolerances: with rest_accel, (land_tol, acc_tol, pose_tol) start at the
    # ramp's last entry (the final stage's); otherwise one land_tol for every quantity
    rest_params = dict(land_tol=ramp[-1][1], acc_tol=ramp[-1][2], pose_tol=ramp[-1][3]) if rest_accel else \
        dict(land_tol=land_tol)
    pose = "pose_tol" if rest_accel else "land_tol"
    z_rest, pitch_rest = float(q_rest[model.joint_q("root_z").start]), float(q_rest[model.joint_q("root_pitch").start])
    prob = MotionProblem(
        model, active=active, t_final=t_final, n_ctrl=n_ctrl, dt=dt, q0=q_rest, env=Environment([ground()]),
        contact=contact, q_final_active=None if end_posture_tol is not None else q_rest[ia], rest_end=True,
        rest_start=True,
        costs=[costs.TorqueSquared(weight=1.0), LandingPenalty("w_land", dict(root_z=z_rest, root_pitch=pitch_rest))],
        constraints=[
            ForwardDistance("distance"),
            AtRest(acceleration=bool(rest_accel), tol="land_tol", stage=1,
                   accel_tol="acc_tol" if rest_accel else None),
            constraints.TerminalState("root_z", q=z_rest, kind="ineq", tol=pose, stage=1),
            constraints.TerminalState("root_pitch", q=pitch_rest, kind="ineq", tol=pose, stage=1),
        ] + ([constraints.TerminalState(n, q=float(q_rest[i]), kind="ineq", tol=float(end_posture_tol), stage=1)
              for n, i in zip(active, ia)] if end_posture_tol is not None else []) + list(extra) + [
            constraints.JointLimits(list(active), velocity=False),
            ScaledTorqueLimits(),
            FlightClearance("clearance"),
            PitchBound("max_pitch", center=pitch_rest),
        ] + ([ScaledTorqueLimits("tau_factor", dense=True, stage=2, name="torque_limits_every_step")]
             if dense_torque else []),
        params={"distance": distance, "clearance": clearance, "max_pitch": max_pitch, "w_land": 0.0,
                **rest_params, **({"tau_factor": 1.0} if dense_torque else {})},
        integrator=integrator, name=name, n_path_samples=n_path_samples,
        initial_guess=keyframe_guess(keyframes, t_final, active), shooting=shooting,
    )
    lb, ub = variable_bounds(prob)  # the joint limits
    x0 = np.asarray(prob.x0, float)
    prob.x_bounds = (np.maximum(lb - margin, x0 - trust), np.minimum(ub + margin, x0 + trust))
    if shooting > 1:  # the node states (after the control points) are not bounded
        ns = prob.n_spline_vars
        prob.x_bounds[0][ns:], prob.x_bounds[1][ns:] = -np.inf, np.inf
    d_on = float(np.max(np.asarray(contact.d_on)))

    def criteria(solution):
        return hop_criteria(prob, solution, distance=distance, min_flight=min_flight, z_rest=z_rest,
                            pitch_rest=pitch_rest, d_on=d_on, max_penetration=max_penetration,
                            **(criteria_options or {}))

    prob.success_criteria = criteria
    if schedule is None:
        d0 = distance / 3.0

        def at(entry):  # (fraction of the distance, land_tol[, acc_tol, pose_tol])
            f, tl, *rest = entry
            return dict(distance=distance * f, land_tol=tl, w_land=w_land,
                        **(dict(acc_tol=rest[0], pose_tol=rest[1]) if rest else {}))

        schedule = [dict(params=dict(distance=d0, w_land=w_land * 0.01), level=0),
                    dict(params=dict(distance=d0, w_land=w_land * 0.1), level=0)] + [
            dict(params=at(e), level=1) for e in ramp]
        if dense_torque:  # the limits on every step, tightened at the ramp's last tolerance
            schedule += [dict(params=dict(at(ramp[-1]), distance=distance, tau_factor=f), level=2) for f in dense_ramp]
        if not rest_accel:  # (with rest_accel the ramp's last stage is the final one)
            schedule += [dict(params=dict(distance=distance, land_tol=land_tol, w_land=w_land,
                                          **({"tau_factor": 1.0} if dense_torque else {})),
                              level=2 if dense_torque else 1)]
    if schedule and final_tol is not None:
        schedule[-1] = dict(schedule[-1], tol=float(final_tol))
    if schedule:
        prob.solve_options["schedule"] = schedule
        prob.solve_options.update(intermediate_tol=intermediate_tol, intermediate_max_iter=intermediate_max_iter)
    if first_step is not None:
        prob.solve_options["first_step"] = float(first_step)
    return prob
