"""Rollouts of the hybrid dynamics (DESIGN.md, "The method", items 2 and 5; the draft's
"Generating Motions", eq. (sysint)): active joints follow prescribed paths, the passive
state ``(q_p, v_p, J_int)`` is integrated forward.

Conventions
-----------
- Time grid ``t_k = k dt``, ``k = 0..N`` with ``N = n_steps``; ``t_N = t_final``.
- *Active* joints must be 1-DoF (revolute, prismatic). Their position, velocity and
  acceleration are prescribed on the grid (and, for RK4, at the half steps
  ``t_k + dt/2``): `rollout` takes them as arrays, `simulate` computes them from a
  `QuinticBSpline` with basis matrices precomputed on the host (one matmul per rollout).
- *Passive* DoFs get the generalized force ``tau_p = passive_forces(q, v)[passive]``
  (springs, dampers, limit penalties) and, when a contact model is given, the contact
  wrenches ``f_ext``; their acceleration comes from `hybrid_dynamics`.
- **Torque convention.** ``tau`` (nv,) in the trajectory is the force each joint's
  actuator (or, for passive DoFs, its spring/damper/limit) applies:
  ``tau_motor = tau_active_from_hybrid - passive_forces[active]`` on active DoFs (the
  motor supplies what the rigid-body dynamics needs minus what the joint's own spring and
  damper already supply) and ``tau = passive_forces[passive]`` on passive DoFs.
- Integrators: ``"rk4"`` (default): classical RK4; free and ball joints are integrated on
  their group by the Runge-Kutta-Munthe-Kaas method (RKMK4: RK4 on the exponential
  coordinates ``theta`` with ``q = q_0 exp(theta)`` and the ``dexp^-1`` series truncated
  after the second-order term), which is 4th-order accurate on SE(3)/SO(3) (plain RK4 on
  quaternion components is not). ``"euler"``: semi-implicit (symplectic) Euler,
  ``v+ = v + dt a(q, v)``, ``q+ = q (+) dt v+``, order 1. The running cost is
  integrated by the same rule (it is the third component of the ODE state).
- Reverse-mode memory: the scan over steps is nested, an outer scan over segments of
  ``segment`` steps whose inner scan is wrapped in `jax.checkpoint`, so reverse-mode
  differentiation stores one state per segment plus one segment's intermediates:
  O(N / segment + segment) instead of O(N) (default segment ~ sqrt(N)).
- Derivatives: by default the hybrid dynamics in a rollout carries the analytic
  recursive Jacobians as its JAX derivative rule (`cstorm.dynamics.derivatives_fast`: one
  evaluation of the full Jacobians per stage, shared by every tangent or cotangent), so
  ``jax.jvp``/``jax.vjp``/``jacfwd`` of a rollout do not differentiate through the
  recursive algorithm; tangents of model parameters (masses, lengths: design
  derivatives) fall back to autodiff and are never dropped. ``derivatives="autodiff"``
  differentiates through the algorithm instead (the reference; same values to rounding).
  ``derivatives="parallel"`` replaces JAX's differentiation of the scan by
  `cstorm.simulate.tangents`: the step Jacobians of all steps are evaluated at once
  (batched, the analytic hybrid-dynamics rule inside) and the tangents follow from a
  linear recurrence (transposed by JAX for reverse mode). It runs about 3x faster
  than differentiating the scan (Gymnasium's hopper, 500 RK4 steps), but compiles about
  1.7x longer, so it is not the default.
- Divergence: a step whose new passive state has a NaN/inf entry or exceeds the bounds
  (``|q_p| > q_bound``, ``|v_p| > v_bound``) marks the rollout diverged; the state is
  frozen from then on (so nothing downstream turns NaN), the running cost becomes inf,
  and the result records the first bad step, DoF and reason. `simulate` raises
  `DivergenceError` naming the time and the joint; optimizers treat it as a rejected
  step.

Performance
-----------
On CPU, XLA runs each fusion of a loop body as a separate kernel ("thunk"), and a loop
body's kernels run in order on the calling thread only if every buffer they touch holds
at most 512 bytes (64 float64 numbers); otherwise XLA's dataflow executor schedules them
over its thread pool, which for the hundreds of tiny kernels of a dynamics evaluation
cost ~3x (the tumbler's hybrid dynamics). The
four RK4 stages therefore run in a loop whose buffers are all small for small robots:
it stacks no per-stage outputs (the recorded grid point rides in the carry) and the
contact code forms no ``(k, 3, 3)`` arrays. Larger intermediates in a stage (more than
~20 contact points, more than 10 bodies in ``f_ext``) switch the stage loop to the slower
executor: correct, just slower.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any, Callable

import numpy as np
import jax
import jax.numpy as jnp

from ..contact import contact_forces
from ..errors import DivergenceError, InputError
from ..mapguard import relieve_map_pressure
from .steps import (DERIVATIVES, INTEGRATORS, REASONS, RolloutLayout, active_paths, initial_carry, point_fn,
                    run_steps, step_core, time_grid)
from .tangents import scan_steps

__all__ = ["simulate", "rollout", "Trajectory", "check_divergence"]


# ---------------------------------------------------------------------------------------
# The rollout
# ---------------------------------------------------------------------------------------
def rollout(model, layout: RolloutLayout, q0, v0, paths, dt: float, n_steps: int, *, integrator: str = "rk4",
            contact_fn: Callable | None = None, cost_fn: Callable | None = None, params: Any = None,
            segment: int | None = None, q_bound: float = 1e4, v_bound: float = 1e4, record: bool = True,
            n_valid=None, derivatives: str = "analytic", t0=0.0, record_rows=None):
    """Integrate the passive state with prescribed active paths (pure JAX; jit/grad/vmap).

    Args:
      model: the `Model` (a pytree; may be traced).
      layout: `RolloutLayout.make(model, active_names)` (static).
      q0: (nq,) initial configuration (active entries are replaced by ``paths``).
      v0: (nv,) initial velocity (likewise).
      paths: dict of active-joint arrays in the layout's active order: ``qa, va, aa``
        ((N+1, n_active) on the grid) and, for RK4, ``qm, vm, am`` ((N, n_active) at the
        half steps).
      dt: step (s; may be traced). n_steps: N, a static int (the scan length).
      n_valid: optional (traced) int ``<= N``: only the first ``n_valid`` steps are taken
        (the rest of the scan is padding), so runs of different lengths share one compiled
        function; the final state is then at ``t = n_valid dt``.
      integrator: ``"rk4"`` or ``"euler"``.
      contact_fn: optional ``(q, v) -> (f_ext (n_bodies, 6), data pytree)``.
      cost_fn: optional running-cost integrand ``(t, q, v, a, tau, contact_data, params) ->
        scalar``; integrated into ``J``.
      params: pytree passed to ``cost_fn``.
      segment: steps per checkpointed segment (default ~sqrt(N)).
      q_bound, v_bound: divergence bounds on the passive positions and velocities (may be
        traced).
      record: if False, the trajectory arrays are not returned (``traj`` is None).
      record_rows: None (every grid point), or grid indices in ``[0, N]`` (static): the
        trajectory arrays hold these points only, sorted and without repeats,
        ``(R, ...)`` (with ``derivatives="parallel"`` only their grid-point Jacobians are
        evaluated, which is most of the saving: a constraint grid of ~40 points instead
        of every step).
      derivatives: ``"analytic"`` (default: the hybrid dynamics' JAX derivative is the
        analytic recursive one, model-parameter tangents by autodiff), ``"parallel"``
        (that, plus the time-parallel tangent rule of `cstorm.simulate.tangents`: step
        Jacobians of all steps at once, then a linear recurrence) or ``"autodiff"``
        (differentiate through the recursive algorithm). Values are identical.
      t0: time (s) of the first grid point, as ``cost_fn`` sees it (may be traced: the
        intervals of a multiple-shooting problem are one vmapped rollout).
    Returns:
      dict with ``J`` (running-cost integral; inf if diverged), ``qT``, ``vT`` (final
      state, active entries from the paths), ``diverged`` (bool), ``div_step`` (int, first
      bad step or -1), ``div_dof`` (int; index into q for position problems, into v for
      velocity problems), ``div_reason`` (int code, see `check_divergence`), and, if
      ``record``, ``traj``: dict ``q (N+1, nq), v, a, tau (N+1, nv)`` and ``contact``
      (the contact data pytree stacked over the grid, or None).
    """
    if integrator not in INTEGRATORS:
        raise InputError(f"integrator must be one of {INTEGRATORS}, got {integrator!r}")
    if derivatives not in DERIVATIVES:
        raise InputError(f"derivatives must be one of {DERIVATIVES}, got {derivatives!r}")
    N = int(n_steps)
    h = dt
    n_run = N if n_valid is None else n_valid
    # N + 1 scan steps: the last one (and any padding) only evaluates the dynamics at the
    # final state (its outputs are the trajectory's last point); the state stays frozen
    NT = N + 1
    seg = int(segment) if segment else max(1, int(math.ceil(math.sqrt(NT))))
    seg = min(seg, NT)
    n_seg = int(math.ceil(NT / seg))
    pad = n_seg * seg - NT
    q0 = jnp.asarray(q0)
    v0 = jnp.asarray(v0)
    dtype = v0.dtype
    ivp = np.array(layout.vp_idx, int)
    iqp = np.array(layout.qp_idx, int)
    nvp = len(ivp)
    rows = None
    if record and record_rows is not None:
        rows = np.unique(np.asarray(record_rows, dtype=int).reshape(-1))
        if rows.size == 0 or rows[0] < 0 or rows[-1] > N:
            raise InputError(f"record_rows must be grid indices in [0, {N}], got {record_rows!r}")

    def padded(x):
        if pad:
            x = jnp.concatenate([x, jnp.repeat(x[-1:], pad, axis=0)], axis=0)
        return x.reshape((n_seg, seg) + x.shape[1:])

    qa, va, aa = paths["qa"], paths["va"], paths["aa"]
    ext = lambda y: jnp.concatenate([y, y[-1:]], axis=0)
    xs = dict(qa0=qa, va0=va, aa0=aa, qa1=ext(qa[1:]), va1=ext(va[1:]), aa1=ext(aa[1:]))
    if integrator == "rk4":
        xs.update(qam=ext(paths["qm"]), vam=ext(paths["vm"]), aam=ext(paths["am"]))
    xs = {k: padded(x) for k, x in xs.items()}
    xs["k"] = jnp.arange(n_seg * seg, dtype=jnp.int32).reshape(n_seg, seg)  # steps >= N are padding

    core = step_core(model, layout, h, t0, contact_fn, cost_fn, params, integrator, derivatives, record)
    q_init = jnp.asarray(q0, dtype=dtype)
    if derivatives == "parallel":

        point = point_fn(model, layout, h, t0, contact_fn, cost_fn, params, derivatives, record)
        (zq, zv, J, bad, bstep, bdof, breason), ys, _ = scan_steps(core, point, layout, q_init, v0, xs, n_run,
                                                                 q_bound, v_bound, run=run_steps, rows=rows)
        qN = q_init.at[iqp].set(zq) if len(iqp) else q_init
        vN = v0.at[ivp].set(zv) if nvp else v0
    else:
        carry0 = initial_carry(q_init, v0)
        (qN, vN, J, bad, bstep, bdof, breason), (ys, _) = run_steps(core, carry0, xs, n_run, q_bound, v_bound,
                                                                     layout, emit=record)
    out = dict(J=jnp.where(bad, jnp.inf, J), diverged=bad, div_step=bstep, div_dof=bdof, div_reason=breason)
    if record:
        if rows is None:
            flat = lambda y: y.reshape((n_seg * seg,) + y.shape[2:])[:NT]
        elif derivatives == "parallel":  # the rule returned these rows only
            flat = lambda y: y
        else:
            flat = lambda y: y.reshape((n_seg * seg,) + y.shape[2:])[rows]
        qs, vs, as_, taus, cs_ = ys
        traj = dict(q=flat(qs), v=flat(vs), a=flat(as_), tau=flat(taus))
        traj["contact"] = None if cs_ is None else jax.tree_util.tree_map(flat, cs_)
        out["traj"] = traj
    if record and rows is None:
        out["qT"], out["vT"] = traj["q"][n_run], traj["v"][n_run]
    else:
        ia, iva = np.array(layout.qa_idx, int), np.array(layout.va_idx, int)
        out["qT"] = qN.at[ia].set(qa[n_run]) if len(ia) else qN
        out["vT"] = vN.at[iva].set(va[n_run]) if len(iva) else vN
    return out


def check_divergence(model, result, dt: float, where: str = "rollout"):
    """Raise `DivergenceError` if a (concrete) rollout result diverged, naming the time,
    the joint and the reason."""
    if not bool(np.asarray(result["diverged"])):
        return
    k = int(np.asarray(result["div_step"]))
    dof = int(np.asarray(result["div_dof"]))
    code = int(np.asarray(result["div_reason"]))
    is_q = code in (1, 3)
    starts = model.q_starts if is_q else model.v_starts
    sizes = [j.nq if is_q else j.nv for j in model.joints]
    joint = "?"
    for name, s, n in zip(model.joint_names, starts, sizes):
        if s <= dof < s + n:
            joint = name
            comp = "" if n == 1 else f" (component {dof - s})"
            joint = f"{name!r}{comp}"
            break
    t = (k + 1) * float(dt)
    raise DivergenceError(
        f"{where} diverged at t = {t:.6g} s (step {k + 1}): {REASONS[code]} of joint {joint}; "
        "reduce dt, soften contact stiffness, or check the model and the initial state")


# ---------------------------------------------------------------------------------------
# Convenience front end
# ---------------------------------------------------------------------------------------
@dataclasses.dataclass
class Trajectory:
    """A simulated motion on the grid ``t`` (N+1,): ``q`` (N+1, nq), ``v``, ``a``, ``tau``
    (N+1, nv) (``tau``: motor torques on active DoFs, spring/damper/limit forces on
    passive ones; see the module docstring), ``cost`` (running-cost integral) and
    ``contact`` (per-point contact data stacked over the grid, or None)."""

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    a: np.ndarray
    tau: np.ndarray
    cost: float
    contact: Any = None


def simulate(model, q0, v0=None, *, t_final: float, dt: float, active=(), ctrl=None, spline=None,
             integrator: str = "rk4", env=None, contact=None, contact_fn=None, cost_fn=None, params=None,
             segment=None, q_bound: float = 1e4, v_bound: float = 1e4, check: bool = True) -> Trajectory:
    """Simulate a motion (eager, host-side results).

    Args:
      model: the `Model`. q0: (nq,) initial configuration; v0: (nv,) initial velocity
        (default zeros).
      t_final, dt: duration and step (s); ``t_final`` must be a whole number of steps.
      active: names of the active (1-DoF) joints; () for a free (all-passive) rollout.
      ctrl: (n_ctrl, n_active) control points of the active paths (in the order of
        ``active`` as given) on ``spline`` (a `QuinticBSpline` over ``[0, t_final]``). With
        ``ctrl=None`` the active joints are held at their ``q0`` values.
      env, contact: optional `cstorm.Environment` and `ContactParams` (or a per-pair
        mapping, see `cstorm.contact_forces`): contact wrenches act on the robot and the
        trajectory's ``contact`` holds the per-point `ContactData` on the grid. Both are
        dynamic arguments (new values reuse the compiled rollout).
      integrator, contact_fn, cost_fn, params, segment, q_bound, v_bound: as `rollout`
        (``contact_fn`` and ``cost_fn`` are static: pass module-level functions).
      check: run the time-step check (`cstorm.check_time_step`, method in
        `cstorm.analysis.timestep`) along the result, at 51 of its states, and warn
        (`cstorm.errors.TimeStepWarning`, saying what step would do) when ``dt`` is past
        the integrator's stability limit there: such a rollout can settle into a hidden
        oscillation whose velocities are not the dynamics'. Skipped without passive
        DoFs. It compiles a linearization once per joint split and contact structure
        (~1-10 s) and costs ~3 ms per state after; ``check=False`` skips it.
    Returns:
      `Trajectory`. Raises `DivergenceError` if the rollout diverges.
    """

    relieve_map_pressure(where="simulate")
    layout = RolloutLayout.make(model, active)
    N, h, t = time_grid(t_final, dt)
    q0 = jnp.asarray(q0, dtype=jnp.float64 if jax.config.jax_enable_x64 else None)
    if q0.shape != (model.nq,):
        raise InputError(f"simulate: q0 must have shape ({model.nq},), got {q0.shape}")
    v0 = jnp.zeros(model.nv, q0.dtype) if v0 is None else jnp.asarray(v0, q0.dtype)
    if v0.shape != (model.nv,):
        raise InputError(f"simulate: v0 must have shape ({model.nv},), got {v0.shape}")
    na = layout.n_active
    given_names = tuple([active] if isinstance(active, str) else active)
    if ctrl is None:
        qa0 = q0[np.array(layout.qa_idx, int)] if na else jnp.zeros(0, q0.dtype)
        paths = dict(qa=jnp.broadcast_to(qa0, (N + 1, na)), va=jnp.zeros((N + 1, na), q0.dtype),
                     aa=jnp.zeros((N + 1, na), q0.dtype))
        paths.update(qm=paths["qa"][:-1], vm=paths["va"][:-1], am=paths["aa"][:-1])
    else:
        if spline is None or abs(spline.t_final - float(t_final)) > 1e-12 * float(t_final):
            raise InputError("simulate: ctrl needs spline=QuinticBSpline(n_ctrl, t_final) with the same t_final")
        ctrl = jnp.asarray(ctrl, q0.dtype).reshape(spline.n_ctrl, -1)
        if ctrl.shape[1] != na:
            raise InputError(f"simulate: ctrl must have shape ({spline.n_ctrl}, {na}), got {ctrl.shape}")
        perm = np.array([given_names.index(n) for n in layout.active_names], int)
        ctrl = ctrl[:, perm]
        Bs = active_paths(spline, N, integrator)
        paths = dict(qa=Bs["B0"] @ ctrl, va=Bs["B1"] @ ctrl, aa=Bs["B2"] @ ctrl)
        if integrator == "rk4":
            paths.update(qm=Bs["M0"] @ ctrl, vm=Bs["M1"] @ ctrl, am=Bs["M2"] @ ctrl)
    if env is not None:
        if contact_fn is not None:
            raise InputError("simulate: give env/contact or contact_fn, not both")
        if contact is None:
            raise InputError("simulate: env given without contact parameters (contact=cs.ContactParams(...))")
    contact_arg = contact
    res = _simulate_jit(model, q0, v0, paths, params, jnp.asarray(h, q0.dtype), env, contact, layout=layout, N=N,
                        integrator=integrator,
                        contact_fn=contact_fn, cost_fn=cost_fn, segment=segment, q_bound=jnp.asarray(float(q_bound)),
                        v_bound=jnp.asarray(float(v_bound)))
    check_divergence(model, res, h, "simulate")
    tr = res["traj"]
    contact = None if tr["contact"] is None else jax.tree_util.tree_map(np.asarray, tr["contact"])
    out = Trajectory(t=t, q=np.asarray(tr["q"]), v=np.asarray(tr["v"]), a=np.asarray(tr["a"]),
                     tau=np.asarray(tr["tau"]), cost=float(res["J"]), contact=contact)
    if check and layout.vp_idx:
        import warnings

        from ..analysis.timestep import check_rollout
        from ..errors import TimeStepWarning

        r = check_rollout(model, layout, out, dt=float(h), integrator=integrator, env=env, contact=contact_arg,
                          contact_fn=contact_fn)
        if r["ok"] is False:
            warnings.warn(f"simulate: {r['message']}", TimeStepWarning, stacklevel=2)
    return out


@functools.partial(jax.jit, static_argnames=("layout", "N", "integrator", "contact_fn", "cost_fn", "segment"))
def _simulate_jit(model, q0, v0, paths, params, h, env, contact, *, layout, N, integrator, contact_fn, cost_fn,
                  segment, q_bound, v_bound):
    if env is not None:

        def contact_fn(q, v):
            out = contact_forces(model, env, contact, q, v)
            return out.f_ext, out
    return rollout(model, layout, q0, v0, paths, h, N, integrator=integrator, contact_fn=contact_fn,
                   cost_fn=cost_fn, params=params, segment=segment, q_bound=q_bound, v_bound=v_bound)
