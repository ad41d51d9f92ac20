"""Fidelity of a planned motion: re-simulation at dt/4 and with an independent adaptive
integrator.

`fidelity` re-simulates every segment open-loop with the solution's own spline controls
from the planned start state of that segment, twice:

1. ``"fine"``: the *same* integrator at a quarter of the time step (``dt/4``), with
   cstorm's fixed-step rollout: the plan's time-discretization error (an optimizer that
   exploits integration error shows up here);
2. ``"dop853"``: scipy's adaptive 8th-order Dormand-Prince integrator (``rtol=1e-6``,
   ``atol=1e-8``; tighter tolerances change the reported deviations by < 1 %) on the
   continuous-time ODE, the active joints evaluated on their splines at the
   integrator's own times: an independent, error-controlled integrator,
   i.e. a reference solution of the motion's ODE (it also checks cstorm's rollout code:
   the half-step spline samples, the Lie-group updates).

The obvious second fixed-step rule, semi-implicit Euler at ``dt/4``, is available
(``checks=(..., "other")``) but not a default: its own first-order error dominates on
sensitive motions (the acrobot swing-up planned with RK4 at 20 ms ends 134 deg off with
Euler at 5 ms and still 1.5 deg off at 20 ms / 1024, while RK4 at 5 ms and DOP853 agree
with the plan to 0.04 deg), so it would measure Euler, not the plan.

Each check reports the deviation of the final *passive* state from the plan, positions
(m: prismatic DoFs, free-joint translations) and angles (deg: revolute DoFs, rotation
angle of free/ball joints) separately, and velocities (m/s, deg/s), plus the largest
position/angle deviation along the planned grid. A check is flagged (``ok: false``) when
a final position deviates by more than 1 cm or an angle by more than 2 deg
(``tol_position_m``, ``tol_angle_deg``), or a final velocity by more than 1 cm/s or 1
deg/s (``tol_velocity_m_s``, ``tol_angular_velocity_deg_s``): a plan whose landing "at
rest" is an artefact of a step past the integrator's stability limit (see
`cstorm.check_time_step`) can agree in positions and not in velocities (the Luxo hop
planned at 4 ms: 2.7 mm but 0.024 m/s and 14 deg/s). Segments
of a sequence are checked separately, each from its own planned start (chaining
open-loop re-simulations would measure the instability of, e.g., a handstand, not the
integration). Cost: the fixed-step check reuses `cstorm.simulate.simulate`'s compiled
rollout (segments with the same horizon, step and environment structure compile once);
the DOP853 check compiles one right-hand side per joint split and environment structure
(shared by all segments of a sequence) and then costs about
one dynamics evaluation plus dispatch (~0.5-1 ms for the tumbler with contact) per
right-hand-side call, ~5,000 calls for 2 s of tumbler motion with contact.
"""

from __future__ import annotations

import math
import time

import numpy as np
import jax
import jax.numpy as jnp
from scipy.integrate import solve_ivp
from scipy.interpolate import BSpline

from .. import spatial as sp
from ..contact import contact_forces
from ..errors import DivergenceError, InputError
from ..optimize.ddp_problem import resimulate as resimulate_torques
from ..simulate import dynamics_stage, simulate
from .segments import problem_segments, segment_solutions
from ..progress import bar as progress_bar

__all__ = ["fidelity", "resimulate", "static_contact_fn", "CHECKS", "DEVIATION_KEYS"]

TOL_POSITION_M = 0.01
TOL_ANGLE_DEG = 2.0
TOL_VELOCITY_M_S = 0.01
TOL_ANGULAR_VELOCITY_DEG_S = 1.0


_OTHER = {"rk4": "euler", "euler": "rk4"}
_contact_fn_cache: dict = {}
_rhs_cache: dict = {}


def static_contact_fn(problem):
    """A (q, v) -> (f_ext, data) function for a problem with a user ``contact_fn`` (one
    per problem, so it can be a static argument of a compiled function)."""
    key = id(problem)
    if key not in _contact_fn_cache:
        m = problem.model
        _contact_fn_cache[key] = (problem, lambda q, v: problem.contact_fn(m, None, None, q, v))
    return _contact_fn_cache[key][1]


def resimulate(problem, ctrl, q0, v0, dt, integrator):
    """Fixed-step re-simulation with cstorm's rollout (`cstorm.simulate.simulate`)."""

    kw = {}
    if problem.env is not None:
        kw = dict(env=problem.env, contact=problem.contact)
    elif problem.contact_fn is not None:
        kw = dict(contact_fn=static_contact_fn(problem))
    return simulate(problem.model, q0, v0, t_final=problem.t_final, dt=dt, active=problem.active, ctrl=ctrl,
                    spline=problem.spline, integrator=integrator, q_bound=problem.q_bound, v_bound=problem.v_bound,
                    check=False, **kw)


def _qdot_passive(model, layout, q, v):
    """Time derivative of the passive configuration entries (layout.qp_idx order):
    ``qdot = v`` for 1-DoF joints; a free joint's ``pdot = R v_body``, ``quat_dot = 1/2
    quat (x) (0, omega_body)``; a ball joint's ``quat_dot = 1/2 quat (x) (0, omega)``."""

    parts = []
    for i in layout.passive_joints:
        j = model.joints[i]
        qs, vs = model.q_starts[i], model.v_starts[i]
        qj, vj = q[qs:qs + j.nq], v[vs:vs + j.nv]
        kind = type(j).__name__
        if kind == "Free":
            quat = qj[3:7]
            parts += [sp.quat_to_rot(quat) @ vj[3:], 0.5 * sp.quat_mul(quat, jnp.concatenate([jnp.zeros(1), vj[:3]]))]
        elif kind == "Ball":
            parts.append(0.5 * sp.quat_mul(qj, jnp.concatenate([jnp.zeros(1), vj])))
        else:
            parts.append(vj)
    return jnp.concatenate(parts) if parts else jnp.zeros(0)


def _normalize_passive(model, layout, q):

    for i in layout.passive_joints:
        j = model.joints[i]
        qs = model.q_starts[i]
        kind = type(j).__name__
        if kind == "Free":
            q = q.at[qs + 3:qs + 7].set(q[qs + 3:qs + 7] / jnp.linalg.norm(q[qs + 3:qs + 7]))
        elif kind == "Ball":
            q = q.at[qs:qs + 4].set(q[qs:qs + 4] / jnp.linalg.norm(q[qs:qs + 4]))
    return q


def _rhs_function(problem):
    """A compiled ``f(t, x, q_template, v_template, qa, va, aa, model, env, contact) ->
    xdot`` of the passive state ``x = (q_p, v_p)`` given the active joints' position,
    velocity and acceleration at ``t`` (evaluated on the host from the spline), so one
    compile serves every problem with the same joints split and environment structure
    (all segments of a sequence, whatever their horizon or control points)."""

    layout = problem.layout
    user_cf = None if problem.env is not None or problem.contact_fn is None else static_contact_fn(problem)
    key = (layout, problem.env is not None, user_cf)
    if key in _rhs_cache:
        return _rhs_cache[key]
    iqp, ivp = np.array(layout.qp_idx, int), np.array(layout.vp_idx, int)
    nqp = len(iqp)

    def f(t, x, q_tmpl, v_tmpl, qa, va, aa, model, env, contact):
        q = _normalize_passive(model, layout, q_tmpl.at[iqp].set(x[:nqp]))
        v = v_tmpl.at[ivp].set(x[nqp:])
        if env is not None:

            def cf(q_, v_):
                o = contact_forces(model, env, contact, q_, v_)
                return o.f_ext, o
        else:
            cf = user_cf
        q, v, a, tau, _, _ = dynamics_stage(model, layout, q, v, qa, va, aa, t, cf, None, None)
        return jnp.concatenate([_qdot_passive(model, layout, q, v), a[ivp]])

    fn = jax.jit(f)
    _rhs_cache[key] = fn
    return fn


def _adaptive(problem, ctrl, q0, v0, t_eval, rtol=1e-6, atol=1e-8):
    """Re-simulate with scipy's adaptive DOP853 (8th order, error-controlled) on the
    continuous-time ODE: active joints evaluated on their splines (scipy `BSpline` of
    the same knots and control points) at the solver's own times. Returns
    (q (len(t_eval), nq), v, n_rhs_evaluations)."""

    fn = _rhs_function(problem)
    layout, spl = problem.layout, problem.spline
    iqp, ivp = np.array(layout.qp_idx, int), np.array(layout.vp_idx, int)
    ia, iva = np.array(layout.qa_idx, int), np.array(layout.va_idx, int)
    ctrl = np.asarray(ctrl, float).reshape(spl.n_ctrl, -1)
    B0 = BSpline(np.asarray(spl.knots), ctrl, spl.degree, extrapolate=True)
    B1, B2 = B0.derivative(1), B0.derivative(2)
    q_t, v_t = jnp.asarray(q0, jnp.float64), jnp.asarray(v0, jnp.float64)
    args = (problem.model, problem.env, problem.contact)
    x0 = np.concatenate([np.asarray(q0)[iqp], np.asarray(v0)[ivp]])
    bound = max(problem.q_bound, problem.v_bound)
    T = problem.t_final

    def rhs(t, x):
        # a trial stage of a step that is too long may leave the bounds (a stiff contact
        # damper at an impact): NaN makes the step's error estimate NaN and solve_ivp
        # rejects the step and shortens it; a motion that really diverges ends with the
        # step size underflowing (status -1) or with accepted states out of bounds
        if not np.all(np.abs(x) < bound):
            return np.full_like(x, np.nan)
        tc = min(max(t, 0.0), T)
        return np.asarray(fn(t, jnp.asarray(x), q_t, v_t, B0(tc), B1(tc), B2(tc), *args))

    sol = solve_ivp(rhs, (0.0, T), x0, method="DOP853", t_eval=t_eval, rtol=rtol, atol=atol)
    if sol.status != 0 or sol.y.shape[1] != len(t_eval) or not np.all(np.abs(sol.y) < bound):
        t_end = float(sol.t[-1]) if len(sol.t) else 0.0
        raise DivergenceError(f"adaptive re-simulation (DOP853) failed or left the bounds by t = {t_end:.6g} s: "
                              f"{sol.message}")
    X = sol.y.T
    nqp = len(iqp)
    tt = np.clip(np.asarray(t_eval, float), 0.0, T)
    Q = np.tile(np.asarray(q0, float), (len(t_eval), 1))
    V = np.tile(np.asarray(v0, float), (len(t_eval), 1))
    Q[:, iqp], V[:, ivp] = X[:, :nqp], X[:, nqp:]
    if len(ia):
        Q[:, ia], V[:, iva] = B0(tt), B1(tt)
    for i in layout.passive_joints:  # unit quaternions
        j = problem.model.joints[i]
        qs = problem.model.q_starts[i]
        kind = type(j).__name__
        sl = slice(qs + 3, qs + 7) if kind == "Free" else slice(qs, qs + 4) if kind == "Ball" else None
        if sl is not None:
            Q[:, sl] /= np.linalg.norm(Q[:, sl], axis=1, keepdims=True)
    return Q, V, int(sol.nfev)


def _passive_deviation(model, layout, q_ref, v_ref, q, v):
    """Largest deviations of the passive DoFs between two states (host numpy):
    dict position_m, angle_deg, velocity_m_s, angular_velocity_deg_s (None where the
    model has no such passive DoF)."""
    pos, ang, vel, avel = [], [], [], []
    for i in layout.passive_joints:
        j = model.joints[i]
        qs, vs = model.q_starts[i], model.v_starts[i]
        qa, qb = np.asarray(q_ref[qs:qs + j.nq], float), np.asarray(q[qs:qs + j.nq], float)
        va, vb = np.asarray(v_ref[vs:vs + j.nv], float), np.asarray(v[vs:vs + j.nv], float)
        kind = type(j).__name__
        if kind == "Revolute":
            ang.append(abs(qb[0] - qa[0])), avel.append(abs(vb[0] - va[0]))
        elif kind == "Prismatic":
            pos.append(abs(qb[0] - qa[0])), vel.append(abs(vb[0] - va[0]))
        elif kind == "Free":
            pos.append(float(np.linalg.norm(qb[:3] - qa[:3])))
            ang.append(_quat_angle(qa[3:7], qb[3:7]))
            avel.append(float(np.linalg.norm(vb[:3] - va[:3]))), vel.append(float(np.linalg.norm(vb[3:] - va[3:])))
        elif kind == "Ball":
            ang.append(_quat_angle(qa, qb)), avel.append(float(np.linalg.norm(vb - va)))
        else:  # unknown joint type: count its tangent difference as a position
            pos.append(float(np.linalg.norm(np.asarray(j.difference(qa, qb))))), vel.append(
                float(np.linalg.norm(vb - va)))
    mx = lambda xs, s=1.0: (float(max(xs)) * s) if xs else None
    deg = 180.0 / math.pi
    return dict(position_m=mx(pos), angle_deg=mx(ang, deg), velocity_m_s=mx(vel), angular_velocity_deg_s=mx(avel, deg))


def _quat_angle(a, b):
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    return float(2.0 * math.acos(min(1.0, abs(float(np.dot(a, b))))))


def deviation_flags(dev, tol_position, tol_angle, tol_velocity=TOL_VELOCITY_M_S,
                    tol_angular_velocity=TOL_ANGULAR_VELOCITY_DEG_S):
    """The deviations of ``dev`` (a check's entry) beyond their tolerances, in words."""
    bad = []
    for key, tol, what, unit in (("position_m", tol_position, "position", "m"),
                                 ("angle_deg", tol_angle, "angle", "deg"),
                                 ("velocity_m_s", tol_velocity, "velocity", "m/s"),
                                 ("angular_velocity_deg_s", tol_angular_velocity, "angular velocity", "deg/s")):
        val = dev[key]
        if val is not None and not (val <= tol):
            bad.append(f"final passive {what} off by {val:.3g} {unit} (> {tol:g} {unit})")
    return bad


#: the checks of a torque-controlled (DDP) plan: its integrator at dt/factor and at
#: dt/(4 factor) (the torques are exact controls of the continuous system, held over
#: each step, so the only error is the integration's). Closed loop with the plan's own
#: feedback gains where the solution has them (``trajectory["feedback"]``): held
#: torques alone cannot keep a balance that is unstable open loop (a lamp standing on
#: its foot with constant joint torques has no stiffness), so an open-loop replay would
#: measure that instability, not the integration; the joints of the paper's method
#: follow their splines, which is a stiff position control of its own.
_TORQUE_CHECKS = ("fine", "finer")
DEVIATION_KEYS = ("position_m", "angle_deg", "velocity_m_s", "angular_velocity_deg_s", "path_position_m",
                  "path_angle_deg")
CHECKS = ("fine", "dop853", "other")


def fidelity(problem, solution, *, checks=("fine", "dop853"), factor: int = 4,
             tol_position_m: float = TOL_POSITION_M, tol_angle_deg: float = TOL_ANGLE_DEG,
             tol_velocity_m_s: float = TOL_VELOCITY_M_S,
             tol_angular_velocity_deg_s: float = TOL_ANGULAR_VELOCITY_DEG_S,
             rtol: float = 1e-6, atol: float = 1e-8) -> dict:
    """Re-simulate every segment of ``solution`` open-loop with its own spline controls
    from its planned start state and compare with the plan.

    Checks (``checks``, in order):
      ``"fine"``: the planning integrator at ``dt / factor`` (cstorm's fixed-step
        rollout): the plan's own time-discretization error.
      ``"dop853"``: scipy's adaptive 8th-order Dormand-Prince integrator (``rtol``,
        ``atol``) on the continuous-time ODE, the active joints evaluated on their
        splines at the integrator's own times: an independent integrator whose error is
        controlled, i.e. a reference solution of the motion's ODE.
      ``"other"``: the other fixed-step rule (RK4 <-> semi-implicit Euler) at
        ``dt / factor``. Not a default: Euler's own first-order error dominates on
        sensitive motions (the acrobot swing-up planned with RK4 at 20 ms ends 134 deg
        off with Euler at 5 ms, 1.5 deg at 20 ms / 1024, while RK4 at 5 ms and DOP853
        agree with the plan to 0.03 deg).

    Returns a JSON-able dict: ``ok`` (bool: no check flagged), ``flags`` (list of str),
    the worst final deviations ``position_m``, ``angle_deg``, ``velocity_m_s``,
    ``angular_velocity_deg_s`` and along the grid ``path_position_m``,
    ``path_angle_deg`` (None where the robot has no such passive DoF), ``checks`` (per
    check: ``name``, ``integrator``, ``dt``, the deviations, ``flags``, ``ok``; for a
    sequence under ``segments``, per segment), ``tolerances``, ``method`` and
    ``wall_time_s``.
    """
    bad = [c for c in checks if c not in CHECKS]
    if bad:
        raise InputError(f"fidelity: unknown checks {bad}; known: {list(CHECKS)}")
    t0 = time.perf_counter()
    segs, sols = problem_segments(problem), segment_solutions(solution)
    segs = segs[:len(sols)]  # an interrupted sequence: check the segments that were solved
    seg_reports = []
    with progress_bar(sum(len(_TORQUE_CHECKS if "ctrl" not in s.trajectory else checks) for s in sols), "fidelity") as pbar:
        for p, s in zip(segs, sols):
            tr = s.trajectory
            q_plan, v_plan = np.asarray(tr["q"]), np.asarray(tr["v"])
            t_plan = np.asarray(tr["t"], float)
            torques = "ctrl" not in tr  # a DDP solution: motor torques held over each step
            ctrl = np.asarray(tr["u"] if torques else tr["ctrl"])
            entries = []
            for name in (_TORQUE_CHECKS if torques else checks):
                tc = time.perf_counter()
                if name == "dop853":
                    entry = dict(name=name, integrator="dop853 (scipy, adaptive)", rtol=rtol, atol=atol)
                else:
                    integ = p.integrator if name == "fine" else _OTHER[p.integrator]
                    entry = dict(name=name, integrator=integ, dt=p.dt / factor, steps=p.n_steps * factor)
                if name == "finer":
                    entry = dict(name=name, integrator=p.integrator, dt=p.dt / (4 * factor), steps=p.n_steps * 4 * factor)
                try:
                    if torques:
                        f_ = factor if name == "fine" else 4 * factor
                        K = tr.get("feedback")
                        Q, V, Ua = resimulate_torques(p, ctrl, q_plan[0], v_plan[0], f_, entry["integrator"],
                                                      X=np.concatenate([q_plan, v_plan], axis=1), K=K)
                        entry["feedback"] = K is not None
                        entry["feedback_torque_n_m"] = float(np.max(np.abs(Ua - ctrl), initial=0.0))
                    elif name == "dop853":
                        Q, V, nfev = _adaptive(p, ctrl, q_plan[0], v_plan[0], t_plan, rtol=rtol, atol=atol)
                        entry["rhs_evaluations"] = nfev
                    else:
                        sim = resimulate(p, ctrl, q_plan[0], v_plan[0], p.dt / factor, integ)
                        Q, V = sim.q[::factor], sim.v[::factor]
                except DivergenceError as e:
                    entry.update({k: None for k in DEVIATION_KEYS}, diverged=True, ok=False,
                                 flags=[f"{entry['integrator']}: re-simulation diverged: {e}"],
                                 wall_time_s=time.perf_counter() - tc)
                    entries.append(entry)
                    pbar.update()
                    continue
                dev = _passive_deviation(p.model, p.layout, q_plan[-1], v_plan[-1], Q[-1], V[-1])
                n = min(len(Q), len(q_plan))
                path = [_passive_deviation(p.model, p.layout, q_plan[k], v_plan[k], Q[k], V[k])
                        for k in range(0, n, max(1, n // 400))] + [dev]
                pmax = lambda key: max([d[key] for d in path if d[key] is not None], default=None)
                entry.update(dev, path_position_m=pmax("position_m"), path_angle_deg=pmax("angle_deg"), diverged=False)
                label = entry["integrator"] + (f" at dt={entry['dt']:g} s" if "dt" in entry else "")
                flags_ = deviation_flags(dev, tol_position_m, tol_angle_deg, tol_velocity_m_s, tol_angular_velocity_deg_s)
                entry["flags"] = [f"{label}: {b}" for b in flags_]
                entry["ok"] = not entry["flags"]
                entry["wall_time_s"] = time.perf_counter() - tc
                entries.append(entry)
                pbar.update()
            seg_reports.append(dict(segment=p.name, ok=all(c["ok"] for c in entries), checks=entries,
                                    **_worst(entries)))
    all_checks = [c for r in seg_reports for c in r["checks"]]
    flags = [f"{r['segment']}: {f}" if len(seg_reports) > 1 else f for r in seg_reports for c in r["checks"]
             for f in c["flags"]]
    words = dict(fine=f"the planning integrator at dt/{factor}",
                 dop853=f"scipy's adaptive DOP853 (rtol={rtol:g}, atol={atol:g}) on the continuous-time ODE",
                 other=f"the other fixed-step integrator (rk4 <-> semi-implicit euler) at dt/{factor}",
                 finer=f"the planning integrator at dt/{4 * factor}")
    torque_plan = any("ctrl" not in s.trajectory for s in sols)
    out = dict(ok=not flags, flags=flags, **_worst(all_checks),
               tolerances=dict(position_m=tol_position_m, angle_deg=tol_angle_deg, velocity_m_s=tol_velocity_m_s,
                               angular_velocity_deg_s=tol_angular_velocity_deg_s),
               method=("each segment re-simulated with its solution's " +
                       ("motor torques (held over each step; closed loop with the solution's feedback gains "
                        "u = u_k + K_k (x (-) x_k), evaluated at each step's start, where it has them: "
                        "'feedback_torque_n_m' is the largest correction)" if torque_plan else
                        "spline controls (open loop)") +
                       " from its planned start state with " +
                       " and with ".join(words[c] for c in (_TORQUE_CHECKS if torque_plan else checks)) +
                       "; deviations of the final passive state from the plan (worst over checks and segments)"),
               wall_time_s=None)
    if len(seg_reports) == 1:
        out["checks"] = seg_reports[0]["checks"]
    else:
        out["segments"] = seg_reports
    out["wall_time_s"] = time.perf_counter() - t0
    return out


def _worst(checks):
    out = {}
    for k in DEVIATION_KEYS:
        vals = [c[k] for c in checks if c.get(k) is not None]
        out[k] = max(vals) if vals else None
    return out
