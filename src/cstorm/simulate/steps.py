"""One integration step of a rollout: the static active/passive layout, a dynamics stage
(contact, passive forces, hybrid dynamics at one instant), the RK4 and semi-implicit
Euler steps (RKMK4 on free and ball joints), the divergence guard and the checkpointed
scan over steps. Conventions: `cstorm.simulate.rollout`."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import jax
import jax.numpy as jnp

from .. import spatial as sp
from ..dynamics.hybrid import hybrid_unchecked
from ..dynamics.derivatives_fast import hybrid_fast
from ..dynamics.passive import passive_forces
from ..errors import InputError, ProblemError
from ..model.joints import Ball, Free
from ..trajectory import QuinticBSpline
from .contact_hybrid import contact_hybrid

INTEGRATORS = ("rk4", "euler")
DERIVATIVES = ("parallel", "analytic", "autodiff")
REASONS = ("", "non-finite position", "non-finite velocity", "position bound exceeded", "velocity bound exceeded")


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
    """``(N, dt_exact, t (N+1,))``: the number of steps ``N = t_final / dt`` and the step
    that makes ``N dt = t_final`` exactly (``dt`` up to rounding, relative 1e-9). Raises
    `InputError` naming both when ``t_final`` is not a whole number of steps ``dt``: a
    silently changed step would change the physics (stability and accuracy of the
    integrator)."""
    N = n_steps(t_final, dt)
    T = float(t_final)
    return N, T / N, np.linspace(0.0, T, N + 1)


def n_steps(t_final: float, dt: float) -> int:
    """The number of steps of `time_grid`, checked as there, without allocating."""
    T, h = float(t_final), float(dt)
    if not (math.isfinite(T) and T > 0):
        raise InputError(f"t_final must be finite and > 0, got {t_final!r}")
    if not (math.isfinite(h) and 0 < h <= T):
        raise InputError(f"dt must be finite, > 0 and <= t_final={T}, got {dt!r}")
    r = T / h
    N = max(1, int(round(r)))
    if abs(N - r) > 1e-9 * max(1.0, r):
        down = T / math.ceil(r)
        raise InputError(f"t_final={T:g} s is not a multiple of dt={h:g} s (t_final / dt = {r:.6g}); choose a dt "
                         f"that divides it, e.g. dt={down:.6g} ({math.ceil(r)} steps)")
    return N


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
def passive_exp(model, layout, q, theta):
    """q with every passive joint moved by ``q_j exp(theta_j)`` (theta: (n_passive_v,))."""
    out = q
    k = 0
    for i in layout.passive_joints:
        j = model.joints[i]
        qs = model.q_starts[i]
        out = out.at[qs: qs + j.nq].set(j.integrate(q[qs: qs + j.nq], theta[k: k + j.nv]))
        k += j.nv
    return out


def dexpinv(model, layout, theta, xi):
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


def dynamics_stage(model, layout, q, v, qa, va, aa, t, contact_fn, cost_fn, params, derivatives="analytic"):
    """Dynamics at one instant. q, v: full vectors whose passive entries are the
    integrated state; the active entries are overwritten with (qa, va). ``derivatives``:
    "analytic" (the custom-JVP hybrid dynamics), "parallel" (that, with the contact
    forces' Jacobian evaluated first and composed with it: `cstorm.simulate.contact_hybrid`) or
    "autodiff". Returns (q, v, a (nv,), tau (nv,), contact data, running-cost integrand)."""
    iva, ivp = np.array(layout.va_idx, int), np.array(layout.vp_idx, int)
    q, v = _with_active(layout, q, v, qa, va)
    pf = passive_forces(model, q, v)
    if contact_fn is not None and derivatives == "parallel":

        tau_a, a_p, f_ext, cdata = contact_hybrid(model, contact_fn, q, v, aa, pf[ivp], layout.active)
    else:
        f_ext, cdata = (None, None) if contact_fn is None else contact_fn(q, v)
        hyb = hybrid_unchecked if derivatives == "autodiff" else hybrid_fast
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
def step_core(model, layout, h, t0, contact_fn, cost_fn, params, integrator, derivatives, record):
    """``core(q, v, x) -> (qn, vn, dJ, out)``: one step from the grid state ``(q, v)``
    (full vectors; only the passive entries matter) with the step's inputs ``x`` (a dict:
    the active paths at ``t_k``, ``t_k + h/2``, ``t_k + h`` and the step index ``k``).
    ``dJ``: the step's running-cost increment. ``out``: the grid point's ``(q, v)`` with
    the active entries from the paths, and, if ``record``, its ``a``, ``tau`` and contact
    data. No divergence handling (see `_guard`)."""
    ivp = np.array(layout.vp_idx, int)
    nvp = len(ivp)

    def stage(q, v, qa_, va_, aa_, t):
        return dynamics_stage(model, layout, q, v, qa_, va_, aa_, t, contact_fn, cost_fn, params, derivatives)

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
                qi = passive_exp(model, layout, q, th)
                vi = v.at[ivp].add(c * h * Wp)
                qi, vi, ai, taui, ci, Li = stage(qi, vi, qa_, va_, aa_, t + c * h)
                Ki = dexpinv(model, layout, th, vi[ivp])
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
            # `stage` sets them; its passive increment is exactly zero)
            q1_, v1_ = _with_active(layout, q, v, x["qa0"], x["va0"])
            out = (q1_, v1_, ys[0][0], ys[1][0], rec) if record else (q1_, v1_)
            qn = passive_exp(model, layout, q1_, h * sK)
            vn = v1_.at[ivp].add(h * sW)
            return qn, vn, h * sL, out
        q1_, v1_, a1, tau1, c1, L1 = stage(q, v, x["qa0"], x["va0"], x["aa0"], t)
        vn = v1_.at[ivp].add(h * a1[ivp])
        qn = passive_exp(model, layout, q1_, h * vn[ivp])
        out = (q1_, v1_, a1, tau1, c1) if record else (q1_, v1_)
        return qn, vn, h * L1, out

    return core


def point_fn(model, layout, h, t0, contact_fn, cost_fn, params, derivatives, record):
    """``point(q, v, x) -> out``: the grid point's recorded data alone, as `step_core`
    emits it (the stage at ``t_k`` with the paths' ``qa0, va0, aa0``)."""

    def point(q, v, x):
        q1_, v1_, a1, tau1, c1, _ = dynamics_stage(model, layout, q, v, x["qa0"], x["va0"], x["aa0"], t0 + x["k"] * h,
                                           contact_fn, cost_fn, params, derivatives)
        return (q1_, v1_, a1, tau1, c1) if record else _with_active(layout, q, v, x["qa0"], x["va0"])

    return point


def initial_carry(q0, v0):
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


def run_steps(core, carry0, xs, n_run, q_bound, v_bound, layout, emit=True):
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


