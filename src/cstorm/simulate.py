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
  `cstorm.rollout_tangents`: the step Jacobians of all steps are evaluated at once
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

from . import spatial as sp
from .dynamics.hybrid import _hybrid
from .dynamics.derivatives_fast import _hybrid_fast
from .dynamics.passive import passive_forces
from .errors import DivergenceError, InputError, ProblemError
from .model.joints import Ball, Free
from .trajectory import QuinticBSpline

__all__ = ["simulate", "rollout", "Trajectory", "RolloutLayout", "time_grid", "active_paths", "check_divergence"]

INTEGRATORS = ("rk4", "euler")
DERIVATIVES = ("parallel", "analytic", "autodiff")
_REASONS = ("", "non-finite position", "non-finite velocity", "position bound exceeded", "velocity bound exceeded")


# ---------------------------------------------------------------------------------------
# Static layout of a model split into active and passive joints
# ---------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class RolloutLayout:
    """Static index maps for a model with the given active joints (host data).

    Attributes: ``active`` (nv bools), ``active_joints`` / ``passive_joints`` (joint
    indices), ``qa_idx`` / ``va_idx`` (q / v indices of the active 1-DoF joints, in the
    order of ``active_names``), ``qp_idx`` / ``vp_idx`` (q / v indices of passive DoFs, in
    model order), ``active_names``."""

    active: tuple
    active_names: tuple
    active_joints: tuple
    passive_joints: tuple
    qa_idx: tuple
    va_idx: tuple
    qp_idx: tuple
    vp_idx: tuple

    @staticmethod
    def make(model, active_names) -> "RolloutLayout":
        if isinstance(active_names, str):
            active_names = [active_names]
        active_names = tuple(active_names)
        if len(set(active_names)) != len(active_names):
            raise ProblemError(f"active joints listed twice: {list(active_names)}")
        ajs = []
        for n in active_names:
            if n not in model.joint_names:
                raise ProblemError(
                    f"model {model.name!r}: no joint named {n!r} to make active; joints with DoFs are "
                    f"{list(model.joint_names)}")
            i = model.joint_names.index(n)
            j = model.joints[i]
            if j.nq != 1 or j.nv != 1:
                raise ProblemError(
                    f"active joint {n!r} is a {j.name} joint with nq={j.nq}, nv={j.nv}; active joints must be "
                    "1-DoF (revolute or prismatic): their paths are scalar splines")
            ajs.append(i)
        # active order: model order, so that a_active in hybrid_dynamics matches
        order = sorted(range(len(ajs)), key=lambda k: ajs[k])
        ajs = [ajs[k] for k in order]
        active_names = tuple(active_names[k] for k in order)
        pjs = [i for i in range(len(model.joints)) if i not in ajs]
        qa = tuple(model.q_starts[i] for i in ajs)
        va = tuple(model.v_starts[i] for i in ajs)
        qp = tuple(model.q_starts[i] + k for i in pjs for k in range(model.joints[i].nq))
        vp = tuple(model.v_starts[i] + k for i in pjs for k in range(model.joints[i].nv))
        act = [False] * model.nv
        for k in va:
            act[k] = True
        return RolloutLayout(tuple(act), active_names, tuple(ajs), tuple(pjs), qa, va, qp, vp)

    @property
    def n_active(self) -> int:
        return len(self.va_idx)

    @property
    def n_passive_v(self) -> int:
        return len(self.vp_idx)


def time_grid(t_final: float, dt: float):
    """``(N, dt_exact, t (N+1,))``: the number of steps ``N = round(t_final / dt)`` (>= 1)
    and the step that makes ``N dt = t_final`` exactly."""
    T, h = float(t_final), float(dt)
    if not (math.isfinite(T) and T > 0):
        raise InputError(f"t_final must be finite and > 0, got {t_final!r}")
    if not (math.isfinite(h) and 0 < h <= T):
        raise InputError(f"dt must be finite, > 0 and <= t_final={T}, got {dt!r}")
    N = max(1, int(round(T / h)))
    return N, T / N, np.linspace(0.0, T, N + 1)


def active_paths(spline: QuinticBSpline, n_steps: int, integrator: str = "rk4"):
    """Host-side basis matrices for the active paths on the grid: a dict with ``B0, B1,
    B2`` ((N+1, n_ctrl) at ``t_k``) and, for RK4, ``M0, M1, M2`` ((N, n_ctrl) at the half
    steps). ``q_a = B0 @ ctrl`` etc."""
    N = int(n_steps)
    t = np.linspace(0.0, spline.t_final, N + 1)
    out = dict(zip(("B0", "B1", "B2"), spline.basis(t)))
    if integrator == "rk4":
        tm = (t[:-1] + t[1:]) / 2
        out.update(zip(("M0", "M1", "M2"), spline.basis(tm)))
    return out


# ---------------------------------------------------------------------------------------
# Lie-group helpers for the passive joints
# ---------------------------------------------------------------------------------------
def _passive_exp(model, layout, q, theta):
    """q with every passive joint moved by ``q_j exp(theta_j)`` (theta: (n_passive_v,))."""
    out = q
    k = 0
    for i in layout.passive_joints:
        j = model.joints[i]
        qs = model.q_starts[i]
        out = out.at[qs: qs + j.nq].set(j.integrate(q[qs: qs + j.nq], theta[k: k + j.nv]))
        k += j.nv
    return out


def _dexpinv(model, layout, theta, xi):
    """``dexp^-1`` of the right-trivialized exponential, truncated after the second
    order: ``xi + 1/2 [theta, xi] + 1/12 [theta, [theta, xi]]`` per free/ball joint
    (identity on 1-DoF joints, whose group is abelian)."""
    parts = []
    k = 0
    for i in layout.passive_joints:
        j = model.joints[i]
        th, x = theta[k: k + j.nv], xi[k: k + j.nv]
        if isinstance(j, Free):
            A = sp.ad(th)
            c1 = A @ x
            parts.append(x + 0.5 * c1 + (A @ c1) / 12.0)
        elif isinstance(j, Ball):
            c1 = jnp.cross(th, x)
            parts.append(x + 0.5 * c1 + jnp.cross(th, c1) / 12.0)
        else:
            parts.append(x)
        k += j.nv
    return jnp.concatenate(parts) if parts else xi


# ---------------------------------------------------------------------------------------
# One evaluation of the dynamics at a stage
# ---------------------------------------------------------------------------------------
def _with_active(layout, q, v, qa, va):
    """q, v with the active entries replaced by (qa, va)."""
    ia, iva = np.array(layout.qa_idx, int), np.array(layout.va_idx, int)
    if len(ia):
        q = q.at[ia].set(qa)
        v = v.at[iva].set(va)
    return q, v


def _stage(model, layout, q, v, qa, va, aa, t, contact_fn, cost_fn, params, derivatives="analytic"):
    """Dynamics at one instant. q, v: full vectors whose passive entries are the
    integrated state; the active entries are overwritten with (qa, va). ``derivatives``:
    "analytic" (the custom-JVP hybrid dynamics), "parallel" (that, with the contact
    forces' Jacobian evaluated first and composed with it: `rollout_tangents.contact_hybrid`) or
    "autodiff". Returns (q, v, a (nv,), tau (nv,), contact data, running-cost integrand)."""
    iva, ivp = np.array(layout.va_idx, int), np.array(layout.vp_idx, int)
    q, v = _with_active(layout, q, v, qa, va)
    pf = passive_forces(model, q, v)
    if contact_fn is not None and derivatives == "parallel":
        from .rollout_tangents import contact_hybrid

        tau_a, a_p, f_ext, cdata = contact_hybrid(model, contact_fn, q, v, aa, pf[ivp], layout.active)
    else:
        f_ext, cdata = (None, None) if contact_fn is None else contact_fn(q, v)
        hyb = _hybrid if derivatives == "autodiff" else _hybrid_fast
        tau_a, a_p = hyb(model, q, v, aa, pf[ivp], layout.active, f_ext)
    a = jnp.zeros(model.nv, dtype=v.dtype)
    tau = pf
    if len(iva):
        a = a.at[iva].set(aa)
        tau = tau.at[iva].set(tau_a - pf[iva])
    if len(ivp):
        a = a.at[ivp].set(a_p)
    L = cost_fn(t, q, v, a, tau, cdata, params) if cost_fn is not None else jnp.zeros((), v.dtype)
    return q, v, a, tau, cdata, L


# ---------------------------------------------------------------------------------------
# One integration step, the divergence guard and the scan over steps
# ---------------------------------------------------------------------------------------
def _step_core(model, layout, h, t0, contact_fn, cost_fn, params, integrator, derivatives, record):
    """``core(q, v, x) -> (qn, vn, dJ, out)``: one step from the grid state ``(q, v)``
    (full vectors; only the passive entries matter) with the step's inputs ``x`` (a dict:
    the active paths at ``t_k``, ``t_k + h/2``, ``t_k + h`` and the step index ``k``).
    ``dJ``: the step's running-cost increment. ``out``: the grid point's ``(q, v)`` with
    the active entries from the paths, and, if ``record``, its ``a``, ``tau`` and contact
    data. No divergence handling (see `_guard`)."""
    ivp = np.array(layout.vp_idx, int)
    nvp = len(ivp)

    def stage(q, v, qa_, va_, aa_, t):
        return _stage(model, layout, q, v, qa_, va_, aa_, t, contact_fn, cost_fn, params, derivatives)

    def core(q, v, x):
        dtype = v.dtype
        t = t0 + x["k"] * h
        if integrator == "rk4":
            # the four RK4/RKMK4 stages as a scan, so the dynamics is traced once. The
            # trajectory records stage 0 (the grid point): a and tau as stacked scan outputs
            # (small), the contact data in the carry (selected at i = 0), which keeps every
            # buffer of the stage loop small (see the module docstring, "Performance")
            P = jnp.stack([x["qa0"], x["qam"], x["qam"], x["qa1"]])
            V = jnp.stack([x["va0"], x["vam"], x["vam"], x["va1"]])
            A = jnp.stack([x["aa0"], x["aam"], x["aam"], x["aa1"]])
            cs_ = jnp.array([0.0, 0.5, 0.5, 1.0], dtype)
            bs_ = jnp.array([1.0, 2.0, 2.0, 1.0], dtype) / 6.0
            first = jnp.array([True, False, False, False])

            def rk_stage(sc, z):
                Kp, Wp, sK, sW, sL, rec = sc
                c, b, i0, qa_, va_, aa_ = z
                th = c * h * Kp
                qi = _passive_exp(model, layout, q, th)
                vi = v.at[ivp].add(c * h * Wp)
                qi, vi, ai, taui, ci, Li = stage(qi, vi, qa_, va_, aa_, t + c * h)
                Ki = _dexpinv(model, layout, th, vi[ivp])
                Wi = ai[ivp]
                if record and ci is not None:
                    rec = jax.tree_util.tree_map(lambda new, old: jnp.where(i0, new, old), ci, rec)
                return (Ki, Wi, sK + b * Ki, sW + b * Wi, sL + b * Li, rec), (ai, taui) if record else None

            z0 = jnp.zeros(nvp, dtype)
            rec0 = None
            if record:
                shapes = jax.eval_shape(lambda: stage(q, v, x["qa0"], x["va0"], x["aa0"], t)[4])
                rec0 = jax.tree_util.tree_map(lambda s_: jnp.zeros(s_.shape, s_.dtype), shapes)
            sc0 = (z0, z0, z0, z0, jnp.zeros((), dtype), rec0)
            (_, _, sK, sW, sL, rec), ys = jax.lax.scan(rk_stage, sc0, (cs_, bs_, first, P, V, A))
            # stage 0's state: the grid point with the active entries from the paths (as
            # `_stage` sets them; its passive increment is exactly zero)
            q1_, v1_ = _with_active(layout, q, v, x["qa0"], x["va0"])
            out = (q1_, v1_, ys[0][0], ys[1][0], rec) if record else (q1_, v1_)
            qn = _passive_exp(model, layout, q1_, h * sK)
            vn = v1_.at[ivp].add(h * sW)
            return qn, vn, h * sL, out
        q1_, v1_, a1, tau1, c1, L1 = stage(q, v, x["qa0"], x["va0"], x["aa0"], t)
        vn = v1_.at[ivp].add(h * a1[ivp])
        qn = _passive_exp(model, layout, q1_, h * vn[ivp])
        out = (q1_, v1_, a1, tau1, c1) if record else (q1_, v1_)
        return qn, vn, h * L1, out

    return core


def _point_fn(model, layout, h, t0, contact_fn, cost_fn, params, derivatives, record):
    """``point(q, v, x) -> out``: the grid point's recorded data alone, as `_step_core`
    emits it (the stage at ``t_k`` with the paths' ``qa0, va0, aa0``)."""

    def point(q, v, x):
        q1_, v1_, a1, tau1, c1, _ = _stage(model, layout, q, v, x["qa0"], x["va0"], x["aa0"], t0 + x["k"] * h,
                                           contact_fn, cost_fn, params, derivatives)
        return (q1_, v1_, a1, tau1, c1) if record else _with_active(layout, q, v, x["qa0"], x["va0"])

    return point


def _carry0(q0, v0):
    """The scan's initial carry ``(q, v, J, bad, bad_step, bad_dof, bad_reason)``."""
    return (q0, v0, jnp.zeros((), v0.dtype), jnp.zeros((), bool), jnp.asarray(-1, jnp.int32),
            jnp.asarray(-1, jnp.int32), jnp.asarray(0, jnp.int32))


def _guard(layout, carry, qn, vn, Jn, k, n_run, q_bound, v_bound):
    """Divergence check on the new passive state and the cost: returns the next carry
    (the old state, frozen, once diverged or beyond ``n_run``) and ``keep`` (bool: the
    state was frozen at this step)."""
    q, v, J, bad, bstep, bdof, breason = carry
    ivp = np.array(layout.vp_idx, int)
    iqp = np.array(layout.qp_idx, int)
    qpn, vpn = qn[iqp], vn[ivp]
    checks = []
    if len(iqp):
        checks += [(~jnp.isfinite(qpn), 1, iqp), (jnp.abs(qpn) > q_bound, 3, iqp)]
    if len(ivp):
        checks += [(~jnp.isfinite(vpn), 2, ivp), (jnp.abs(vpn) > v_bound, 4, ivp)]
    new_bad = jnp.zeros((), bool)
    reason = jnp.zeros((), jnp.int32)
    dof = jnp.zeros((), jnp.int32)
    for mask, code, idx in reversed(checks):  # first listed check wins
        hit = jnp.any(mask)
        reason = jnp.where(hit, code, reason)
        dof = jnp.where(hit, jnp.asarray(idx, jnp.int32)[jnp.argmax(mask)], dof)
        new_bad = new_bad | hit
    new_bad = new_bad | ~jnp.isfinite(Jn)
    valid = k < n_run
    first = valid & ~bad & new_bad
    keep = bad | new_bad | ~valid
    carry = (jnp.where(keep, q, qn), jnp.where(keep, v, vn), jnp.where(keep, J, Jn), bad | (valid & new_bad),
             jnp.where(first, k, bstep), jnp.where(first, dof, bdof), jnp.where(first, reason, breason))
    return carry, keep


def _run_steps(core, carry0, xs, n_run, q_bound, v_bound, layout, emit=True):
    """Scan ``core`` over the steps: ``xs`` leaves are ``(n_seg, seg, ...)``; the inner
    scan over one segment is checkpointed (reverse-mode memory O(n_seg + seg)).
    Returns ``(final carry, (outs, keeps))``, both stacked ``(n_seg, seg, ...)`` (outs:
    None unless ``emit``)."""

    def step(carry, x):
        qn, vn, dJ, out = core(carry[0], carry[1], x)
        carry, keep = _guard(layout, carry, qn, vn, carry[2] + dJ, x["k"], n_run, q_bound, v_bound)
        return carry, ((out if emit else None), keep)

    @jax.checkpoint
    def run_segment(carry, xseg):
        return jax.lax.scan(step, carry, xseg)

    return jax.lax.scan(run_segment, carry0, xs)


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
        (that, plus the time-parallel tangent rule of `cstorm.rollout_tangents`: step
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

    core = _step_core(model, layout, h, t0, contact_fn, cost_fn, params, integrator, derivatives, record)
    q_init = jnp.asarray(q0, dtype=dtype)
    if derivatives == "parallel":
        from .rollout_tangents import scan_steps

        point = _point_fn(model, layout, h, t0, contact_fn, cost_fn, params, derivatives, record)
        (zq, zv, J, bad, bstep, bdof, breason), ys, _ = scan_steps(core, point, layout, q_init, v0, xs, n_run,
                                                                 q_bound, v_bound, run=_run_steps, rows=rows)
        qN = q_init.at[iqp].set(zq) if len(iqp) else q_init
        vN = v0.at[ivp].set(zv) if nvp else v0
    else:
        carry0 = _carry0(q_init, v0)
        (qN, vN, J, bad, bstep, bdof, breason), (ys, _) = _run_steps(core, carry0, xs, n_run, q_bound, v_bound,
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
        f"{where} diverged at t = {t:.6g} s (step {k + 1}): {_REASONS[code]} of joint {joint}; "
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
             segment=None, q_bound: float = 1e4, v_bound: float = 1e4) -> Trajectory:
    """Simulate a motion (eager, host-side results).

    Args:
      model: the `Model`. q0: (nq,) initial configuration; v0: (nv,) initial velocity
        (default zeros).
      t_final, dt: duration and step (s); ``N = round(t_final / dt)`` steps.
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
    Returns:
      `Trajectory`. Raises `DivergenceError` if the rollout diverges.
    """
    from .mapguard import relieve_map_pressure

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
    res = _simulate_jit(model, q0, v0, paths, params, jnp.asarray(h, q0.dtype), env, contact, layout=layout, N=N,
                        integrator=integrator,
                        contact_fn=contact_fn, cost_fn=cost_fn, segment=segment, q_bound=jnp.asarray(float(q_bound)),
                        v_bound=jnp.asarray(float(v_bound)))
    check_divergence(model, res, h, "simulate")
    tr = res["traj"]
    contact = None if tr["contact"] is None else jax.tree_util.tree_map(np.asarray, tr["contact"])
    return Trajectory(t=t, q=np.asarray(tr["q"]), v=np.asarray(tr["v"]), a=np.asarray(tr["a"]),
                      tau=np.asarray(tr["tau"]), cost=float(res["J"]), contact=contact)


@functools.partial(jax.jit, static_argnames=("layout", "N", "integrator", "contact_fn", "cost_fn", "segment"))
def _simulate_jit(model, q0, v0, paths, params, h, env, contact, *, layout, N, integrator, contact_fn, cost_fn,
                  segment, q_bound, v_bound):
    if env is not None:
        from .contact import contact_forces

        def contact_fn(q, v):
            out = contact_forces(model, env, contact, q, v)
            return out.f_ext, out
    return rollout(model, layout, q0, v0, paths, h, N, integrator=integrator, contact_fn=contact_fn,
                   cost_fn=cost_fn, params=params, segment=segment, q_bound=q_bound, v_bound=v_bound)
