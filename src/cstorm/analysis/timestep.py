"""Is a problem's time step inside its integrator's stability region? (`check_time_step`)

Why: a fixed-step rollout whose step is past the integrator's absolute-stability limit
for a fast, decaying mode of the dynamics does not blow up when the dynamics is
nonlinear enough to saturate it: it settles into a hidden oscillation of that mode, and
the rollout's velocities are no longer the dynamics' while its positions may agree. The
stiffest mode of penalty contact is usually friction near zero slip, a viscous damper of
slope ``1.5 mu N / v_max`` per contact point (`cstorm.contact`). An example: the
tumbler standing on its foot with its arms down: RK4 at 4 ms biases the base pitch rate
by 0.035 rad/s (3 ms and below agree with 0.25 ms to 5 digits); the linearization here
puts RK4's limit at 3.77 ms (a mode of rate 738 1/s dominated by ``root_pitch``), and
simulations at 3.7 / 3.85 ms from that posture agree / disagree with 0.25 ms.

Method
------
1. **Linearization.** At a state ``(q, v)`` with the active joints frozen (their
   position and velocity from ``q, v``, their acceleration ``a_a``), the passive state is
   perturbed in the tangent space the rollout integrates in: ``q_p(delta) = q_p exp(delta)``
   (`cstorm.simulate.passive_exp`: plain addition for 1-DoF joints, the group
   exponential for free and ball joints) and ``v_p + w``. The vector field is the
   rollout's own: ``delta' = dexp^-1_delta(v_p + w)`` (`cstorm.simulate.dexpinv`, the
   RKMK4 map; the identity for 1-DoF joints) and ``w' = a_p`` from
   `cstorm.simulate.dynamics_stage` (passive forces, the problem's contact, hybrid dynamics).
   ``A = d(delta', w') / d(delta, w)`` at 0 by `jax.jacfwd` (2 n_vp tangents), i.e. for
   1-DoF joints ``A = [[0, I], [da_p/dq_p, da_p/dv_p]]``; eigenvalues ``lambda`` by
   ``numpy.linalg.eig``.
2. **Stability of the frozen linear ODE** ``x' = A x`` under one step ``h``:

   - ``"rk4"``: each mode is multiplied by ``R(h lambda)`` per step,
     ``R(z) = 1 + z + z^2/2 + z^3/6 + z^4/24`` (the absolute-stability region
     ``|R| <= 1`` reaches ``-2.785`` on the real axis and ``+-2.828 i`` on the
     imaginary axis).
   - ``"euler"`` (semi-implicit: ``w+ = w + h (A_vq delta + A_vv w)``,
     ``delta+ = delta + h (A_qq delta + A_qv w+)``, as the rollout steps): a
     partitioned method has no scalar ``R(z)``, so the one-step matrix ``M(h)`` is formed
     and its eigenvalues ``mu`` are the per-step factors; each is paired with the mode
     ``lambda`` of ``A`` that its eigenvector is mostly made of (largest coefficient in
     ``A``'s eigenvector basis). For one DoF ``x'' = -k/m x - c/m x'`` this is exact and
     gives ``h <= (sqrt(c^2 + 4 k m) - c) / k`` (``2 / omega`` undamped).

   A mode is **stable at h** when its factor ``|R|`` (or ``|mu|``) is at most
   ``max(1, |exp(h lambda)|)``: a decaying or neutral mode (``Re lambda <= 0``) must not
   grow (tolerance 1e-9 for rounding), a mode the dynamics itself lets grow
   (``Re lambda > 0``: tipping, falling) may grow as the dynamics does, and is flagged only
   when the integrator amplifies it more than 1 % beyond ``exp(h Re lambda)`` (the
   order-star excess of a 4th-order method is ``~|z|^5 / 120`` there, far below 1 % for
   resolved modes).
3. **The step limit** ``dt_limit``: the largest ``h`` such that every mode of every
   checked state is stable at every step up to ``h`` (a scan of 800 steps up to
   ``8 / max |lambda|``, then bisection to ~1e-12 relative); None if nothing limits it.

Which states: the stiffness of a contact model depends on the state (normal forces,
slip, which contacts touch) and the modes' rates on the posture (inertia). By default the
check linearizes along the problem's **initial guess**: its rollout at ``dt / 4`` (the
dynamics' states, not those of a possibly unstable step; the same compiled rollout as
`cstorm.analysis.fidelity`'s ``"fine"`` check), sampled at ``n_states`` (201) times from
the initial state to the end. The tumbler's ``start`` segment shows why: its initial
state (arms overhead) allows 4.84 ms, the arms-down posture it moves to 3.75-3.77 ms
(along its guess: past 4 ms for the last 0.52 s). Give ``along=solution``
(a `Solution`: its controls rolled out likewise) to check a planned motion,
``along="start"`` for the initial state alone, ``q``/``v`` for one state of your
choice, or ``along={"q": ..., "v": ...}`` for given states. It is a linear,
frozen-coefficient check: necessary, not sufficient, for an accurate rollout (stability
says nothing about accuracy at ``|h lambda| ~ 1``), and blind to states it does not
visit (contacts the guess never makes, an impact between two samples). ``n_unstable``
and ``unstable_s`` tell a sustained contact (the hidden-oscillation case: resting,
standing) from a brief one (an impact: a few steps of amplification, then the mode decays
again); both make ``ok`` False.

Cost (2-core machine, load ~3-6): the linearization compiles once per joint split and
contact structure (shared by the segments of a sequence and by every state), ~10 s for
the tumbler with contact (~1 s for a two-joint model without contact), then ~3 ms per
state (~0.6 s for 201 states); the rollout at ``dt / 4`` compiles once per horizon and
structure (~5 s for the tumbler; `cstorm.analysis.fidelity` reuses it) and runs in ~1 s.
``cstorm solve`` runs the check on every segment before solving and along the
solution after it.
"""

from __future__ import annotations

import math
import time

import numpy as np
import jax
import jax.numpy as jnp

from ..contact import contact_forces
from ..errors import DivergenceError, InputError
from ..mapguard import relieve_map_pressure
from ..optimize.problem import MotionProblem, require_x64
from ..simulate import INTEGRATORS, dexpinv, dynamics_stage, passive_exp
from .fidelity import resimulate, static_contact_fn

__all__ = ["check_time_step", "passive_jacobian", "rk4_factor"]

#: root of R(-x) = 1 for RK4 (x^3 - 4 x^2 + 12 x - 24 = 0): the real-axis limit of |h lambda|
RK4_REAL_LIMIT = 2.785293563405282
_TOL_DECAY = 1e-9    # |R| <= 1 + this for modes with Re lambda <= 0
_TOL_GROWTH = 1e-2   # |R| <= |exp(h lambda)| (1 + this) for modes the dynamics lets grow
_NAMES = {"rk4": "RK4", "euler": "semi-implicit Euler"}


def rk4_factor(z):
    """``|R(z)|`` of classical RK4, ``R(z) = 1 + z + z^2/2 + z^3/6 + z^4/24`` (any shape,
    complex)."""
    z = np.asarray(z, complex)
    return np.abs(1 + z * (1 + z / 2 * (1 + z / 3 * (1 + z / 4))))


# ---------------------------------------------------------------------------------------
# The linearization (compiled once per joint split and contact structure)
# ---------------------------------------------------------------------------------------
_jac_cache: dict = {}


def _env_contact_fn(model, env, contact):

    def cf(q_, v_):
        out = contact_forces(model, env, contact, q_, v_)
        return out.f_ext, out
    return cf


def _jacobian_fn(problem):
    """A jitted ``(model, q, v, aa, env, contact) -> A (2 n_vp, 2 n_vp)``."""

    layout = problem.layout
    has_env = problem.env is not None
    user_cf = None if has_env or problem.contact_fn is None else static_contact_fn(problem)
    key = (layout, has_env, user_cf)
    if key in _jac_cache:
        return _jac_cache[key]
    ivp = np.array(layout.vp_idx, int)
    iqa, iva = np.array(layout.qa_idx, int), np.array(layout.va_idx, int)
    n = len(ivp)

    def jac(model, q, v, aa, env, contact):
        cf = _env_contact_fn(model, env, contact) if has_env else user_cf

        def field(x):
            d, w = x[:n], x[n:]
            qi = passive_exp(model, layout, q, d)
            vi = v.at[ivp].add(w)
            _, vi, a, _, _, _ = dynamics_stage(model, layout, qi, vi, q[iqa], v[iva], aa, 0.0, cf, None, None)
            return jnp.concatenate([dexpinv(model, layout, d, vi[ivp]), a[ivp]])

        return jax.jacfwd(field)(jnp.zeros(2 * n, v.dtype))

    fn = jax.jit(jac)
    _jac_cache[key] = fn
    return fn


def passive_jacobian(problem, q=None, v=None, a_active=None) -> np.ndarray:
    """The Jacobian ``A`` (2 n_vp, 2 n_vp) of the passive dynamics of ``problem`` (a
    `MotionProblem`) at the state ``(q, v)`` (default the problem's ``q0``, ``v0``),
    active joints frozen there with acceleration ``a_active`` (n_active,) in layout
    order (default 0), w.r.t. the passive tangent offsets and velocities, in the order
    ``problem.layout.vp_idx`` (see the module docstring)."""

    require_x64("check_time_step")
    m = problem.model
    q = np.asarray(problem.q0 if q is None else q, float).reshape(-1)
    v = np.asarray(problem.v0 if v is None else v, float).reshape(-1)
    if q.shape != (m.nq,) or v.shape != (m.nv,):
        raise InputError(f"check_time_step: q must have shape ({m.nq},) and v ({m.nv},), got {q.shape}, {v.shape}")
    na = problem.layout.n_active
    aa = np.zeros(na) if a_active is None else np.asarray(a_active, float).reshape(-1)
    if aa.shape != (na,):
        raise InputError(f"check_time_step: a_active must have shape ({na},), got {aa.shape}")
    A = _jacobian_fn(problem)(m, jnp.asarray(q), jnp.asarray(v), jnp.asarray(aa), problem.env, problem.contact)
    return np.asarray(A)


# ---------------------------------------------------------------------------------------
# Stability of the frozen linear ODE under one step
# ---------------------------------------------------------------------------------------
class _Modes:
    """Eigen-analysis of one linearization ``A`` for one integrator."""

    def __init__(self, A, integrator):
        self.A = np.asarray(A, float)
        self.n = self.A.shape[0] // 2
        self.integrator = integrator
        self.lam, self.V = np.linalg.eig(self.A)
        self.lam_max = float(np.max(np.abs(self.lam))) if self.lam.size else 0.0
        self.growing = self.lam.real > 1e-9 * max(1.0, self.lam_max)
        self.tol = np.where(self.growing, _TOL_GROWTH, _TOL_DECAY)

    def factors(self, h):
        """``(factor (m,), mode index into lam (m,))``: per-step factors and the mode of
        ``A`` each belongs to."""
        if self.integrator == "rk4":
            return rk4_factor(h * self.lam), np.arange(self.lam.size)
        n, A = self.n, self.A
        Aqq, Aqv, Avq, Avv = A[:n, :n], A[:n, n:], A[n:, :n], A[n:, n:]
        I = np.eye(n)
        Wv = I + h * Avv
        M = np.block([[I + h * Aqq + h * h * Aqv @ Avq, h * Aqv @ Wv], [h * Avq, Wv]])
        mu, U = np.linalg.eig(M)
        coef = np.linalg.lstsq(self.V, U, rcond=None)[0]
        return np.abs(mu), np.argmax(np.abs(coef), axis=0)

    def ratios(self, h):
        """``(ratio (m,), mode index (m,), fails (m,))``: factor over the allowed growth
        ``max(1, |exp(h lambda)|)``."""
        f, k = self.factors(h)
        bound = np.maximum(1.0, np.exp(h * self.lam.real[k]))
        r = f / bound
        return r, k, r > 1.0 + self.tol[k]

    def fails(self, h) -> bool:
        return bool(np.any(self.ratios(h)[2]))

    def _first_fail(self, grid):
        """Index of the first step of ``grid`` that fails, or None."""
        if self.integrator == "rk4":  # vectorized: factors of every mode at every step
            z = grid[:, None] * self.lam[None, :]
            r = rk4_factor(z) / np.maximum(1.0, np.exp(z.real))
            bad = np.any(r > 1.0 + self.tol[None, :], axis=1)
            return int(np.argmax(bad)) if bad.any() else None
        for i, h in enumerate(grid):
            if self.fails(h):
                return i
        return None

    def limit(self):
        """``(dt_limit or inf, index of the limiting mode or None)``."""
        if self.lam_max == 0.0:
            return math.inf, None
        H = 8.0 / self.lam_max
        grid = H * np.arange(1, 801) / 800.0
        i = self._first_fail(grid)
        if i is None:
            return math.inf, None
        lo, hi = (grid[i - 1] if i else 0.0), grid[i]
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            if hi - lo <= 1e-13 * hi:
                break
            lo, hi = (lo, mid) if self.fails(mid) else (mid, hi)
        r, k, bad = self.ratios(hi)
        j = int(np.argmax(np.where(bad, r, -np.inf)))
        return lo, int(k[j])


# ---------------------------------------------------------------------------------------
# The check
# ---------------------------------------------------------------------------------------
def _passive_names(model, layout):
    out = []
    for i in layout.passive_joints:
        j, name = model.joints[i], model.joint_names[i]
        out += [name] if j.nv == 1 else [f"{name}_{k}" for k in range(j.nv)]
    return out


def _fmt_dt(h):
    return f"{h * 1e3:.3g} ms" if h < 0.1 else f"{h:.3g} s"


def _floor2(h):
    """``h`` rounded down to 2 significant digits (a step that is inside the limit)."""
    e = math.floor(math.log10(h)) - 1
    return math.floor(h / 10.0 ** e * (1 + 1e-12)) * 10.0 ** e


def _rollout_states(problem, ctrl, q0, v0):
    """The rollout of control points ``ctrl`` (layout order) from ``(q0, v0)`` at
    ``dt / 4`` (`cstorm.analysis.fidelity`'s ``"fine"`` re-simulation: the same compiled
    function)."""

    return resimulate(problem, np.asarray(ctrl), np.asarray(q0), np.asarray(v0), problem.dt / 4, problem.integrator)


def _states(problem, q, v, along, n_states):
    """``(list of (t or None, q, v, aa), where-label, rollout status or None, sample
    spacing s or None)``."""
    lay = problem.layout
    iva = np.array(lay.va_idx, int)
    na = lay.n_active
    if q is not None or v is not None:
        if along is not None:
            raise InputError("check_time_step: give a state (q, v) or along=..., not both")
        q_ = problem.q0 if q is None else q
        v_ = problem.v0 if v is None else v
        return [(None, q_, v_, np.zeros(na))], "at the given state", None, None
    along = "guess" if along is None else along
    if isinstance(along, str) and along == "start":
        return [(0.0, problem.q0, problem.v0, np.zeros(na))], "at the initial state", None, None
    status = label = None
    if isinstance(along, str) and along == "guess":
        data = problem.data()
        x0 = jnp.asarray(problem.x0)
        ctrl, (q0, v0) = problem.ctrl(x0, data), problem.initial_state(x0, data)
        what = "the initial guess"
    elif hasattr(along, "trajectory") and isinstance(along.trajectory, dict) and "ctrl" in along.trajectory:
        tr = along.trajectory
        ctrl, q0, v0 = tr["ctrl"], np.asarray(tr["q"])[0], np.asarray(tr["v"])[0]
        what = "the solution"
        if problem.shooting > 1:  # an open-loop rollout of the whole horizon is not the plan: its own states
            along, what = tr, None
            label = "along the solution's planned states (multiple shooting)"
    elif hasattr(along, "trajectory") and isinstance(along.trajectory, dict):  # a DDP solution: its own states
        along, what = along.trajectory, None
        label = "along the solution's planned states"
    elif isinstance(along, dict) and "q" in along and "v" in along:
        what = None
    else:
        raise InputError(f"check_time_step: along must be None, 'guess', 'start', a Solution or a trajectory dict "
                         f"with 'q' and 'v' arrays, got {along!r}")
    if what is None:
        Q, Vv = np.asarray(along["q"], float), np.asarray(along["v"], float)
        Aa = np.asarray(along["a"], float) if along.get("a") is not None else None
        T = np.asarray(along["t"], float) if along.get("t") is not None else None
        label = label or "along the given trajectory"
    else:
        try:
            sim = _rollout_states(problem, ctrl, q0, v0)
        except DivergenceError as e:
            return ([(0.0, np.asarray(q0), np.asarray(v0), np.zeros(na))], "at the initial state",
                    f"{what}'s rollout at dt/4 diverged ({e})", None)
        Q, Vv, Aa, T = sim.q, sim.v, sim.a, sim.t
        label = f"along {what} (rolled out at dt/4)"
        status = "ok"
    K = Q.shape[0]
    idx = np.unique(np.round(np.linspace(0, K - 1, max(1, min(int(n_states), K)))).astype(int))
    out = [(None if T is None else float(T[k]), Q[k], Vv[k], Aa[k][iva] if Aa is not None else np.zeros(na))
           for k in idx]
    spacing = None if T is None or len(idx) < 2 else float(T[-1] - T[0]) / (len(idx) - 1)
    return out, label, status, spacing


def _hint(problem, lam, growing):
    """``(what the mode likely is, remedy)`` for the message."""
    contact = problem.env is not None or problem.contact_fn is not None
    if growing:
        return "a mode the dynamics lets grow, amplified further by the step", ""
    if abs(lam.imag) <= abs(lam.real):
        if contact:
            return ("a damper (typically the friction law's viscous slope 1.5 mu N / v_max or a contact damper)",
                    " or a larger v_max")
        return "a damper (typically a stiff joint damper)", " or less joint damping"
    if contact:
        return "an oscillation (typically a contact spring)", " or a softer contact"
    return "an oscillation (typically a stiff joint spring)", " or a softer spring"


def check_time_step(problem, q=None, v=None, *, integrator=None, dt=None, along=None, n_states: int = 201) -> dict:
    """Check that the time step of ``problem`` (a `MotionProblem`) is inside its
    fixed-step integrator's absolute-stability region for every mode of the linearized
    passive dynamics (see the module docstring for the method, its limits and its cost:
    ~10 s of compile for a robot with contact the first time, then ~1 s).

    Args:
      problem: the `MotionProblem` (one segment; for a `MotionSequence` check each of
        ``sequence.segments``).
      q, v: one state to linearize at (default ``problem.q0`` / ``problem.v0`` for the one
        not given); the active joints are frozen there with zero acceleration. With
        neither given, ``along`` chooses the states.
      integrator: ``"rk4"`` or ``"euler"`` (default: the problem's).
      dt: the step to judge (default: the problem's ``dt``).
      along: ``None``/``"guess"`` (default): the initial guess rolled out at ``dt/4``
        from the initial state (active joints on their paths, with their accelerations);
        a `Solution` of the problem: its controls rolled out likewise from its start
        state (with multiple shooting, whose open-loop rollout need not follow the plan:
        the planned states themselves); ``"start"``: the initial state alone; a dict with ``q`` (K, nq), ``v``
        (K, nv) and optionally ``a`` (K, nv), ``t`` (K,): those states.
      n_states: how many states to sample (evenly in time, both ends included) along a
        trajectory.
    Returns:
      A JSON-able dict: ``ok`` (every mode of every state stable at ``dt``), ``dt``,
      ``integrator``, ``dt_limit`` (s, the largest stable step, min over the states; None
      if nothing limits it), ``max_abs_lambda`` (1/s, over the states), ``worst_lambda``
      and ``worst_lambda_dt`` (``{"real", "imag"}``: the mode that sets ``dt_limit``, or
      the fastest mode), ``amplification`` (its per-step factor ``|R(lambda dt)|``, for
      Euler ``|mu|``, at ``dt``), ``dof`` (the passive DoF that dominates its
      eigenvector; joint name, ``name_k`` for component k of a multi-DoF joint),
      ``dof_shares`` (each passive DoF's share of that eigenvector, velocity-weighted),
      ``t`` (s: the time of the limiting state, None for a given state), ``where``,
      ``n_states``, ``n_unstable`` (states at which ``dt`` is past their limit),
      ``unstable_s`` (about how long the trajectory is past it: ``n_unstable`` times the
      sample spacing; None without times), ``eigenvalues`` (``[re, im]`` at the limiting
      state, fastest first), ``rollout`` (``"ok"``, a divergence message, or None when
      nothing was rolled out), ``message`` (one line: what to do), ``wall_time_s``.
    """

    if not isinstance(problem, MotionProblem):
        raise InputError(f"check_time_step: expected a MotionProblem (for a sequence, check each of its .segments), "
                         f"got {type(problem).__name__}")
    return _check(problem, q, v, integrator=integrator, dt=dt, along=along, n_states=n_states)


class _Rollout:
    """What the check reads of a problem, for a plain rollout (`check_rollout`)."""

    def __init__(self, model, layout, integrator, dt, env, contact, contact_fn):
        self.model, self.layout, self.integrator, self.dt = model, layout, integrator, float(dt)
        self.env, self.contact = env, contact
        self.contact_fn = None if contact_fn is None else (lambda m, e, c, q, v: contact_fn(q, v))
        self.q0 = self.v0 = None
        self.shooting = 1


_rollout_adapters: dict = {}


def check_rollout(model, layout, trajectory, *, dt, integrator="rk4", env=None, contact=None, contact_fn=None,
                  n_states: int = 51) -> dict:
    """`check_time_step` along a trajectory of `cstorm.simulate` (``q``, ``v``, ``a``,
    ``t`` arrays of a `Trajectory` or dict) rolled out with ``layout`` (a
    `cstorm.simulate.RolloutLayout`), step ``dt`` and ``integrator``, with the contact
    of ``env``/``contact`` or the user's ``contact_fn`` (``(q, v) -> (f_ext, data)``; the
    compiled linearization is kept per function). Returns the same dict."""
    key = (id(contact_fn), layout) if contact_fn is not None else None
    if key is not None and key in _rollout_adapters:
        ad = _rollout_adapters[key][1]
        ad.model, ad.integrator, ad.dt, ad.env, ad.contact = model, integrator, float(dt), env, contact
    else:
        ad = _Rollout(model, layout, integrator, dt, env, contact, contact_fn)
        if key is not None:
            _rollout_adapters[key] = (contact_fn, ad)  # keeps the function alive: its id stays its own
    tr = trajectory if isinstance(trajectory, dict) else dict(q=trajectory.q, v=trajectory.v, a=trajectory.a,
                                                               t=trajectory.t)
    return _check(ad, along=dict(tr), n_states=n_states)


def _check(problem, q=None, v=None, *, integrator=None, dt=None, along=None, n_states=201):
    t0 = time.perf_counter()
    integ = problem.integrator if integrator is None else integrator
    if integ not in INTEGRATORS:
        raise InputError(f"check_time_step: integrator must be one of {INTEGRATORS}, got {integ!r}")
    h = float(problem.dt if dt is None else dt)
    if not (math.isfinite(h) and h > 0):
        raise InputError(f"check_time_step: dt must be finite and > 0, got {dt!r}")
    name = _NAMES[integ]
    lay, m = problem.layout, problem.model
    base = dict(dt=h, integrator=integ)
    if not lay.vp_idx:
        return dict(ok=True, **base, dt_limit=None, max_abs_lambda=0.0, worst_lambda=None, worst_lambda_dt=None,
                    amplification=None, dof=None, dof_shares={}, t=None, where="no passive DoFs", n_states=0,
                    n_unstable=0, unstable_s=None, eigenvalues=[], rollout=None,
                    message="no passive DoFs: nothing to check", wall_time_s=time.perf_counter() - t0)

    relieve_map_pressure(where="check_time_step")
    states, where, rollout, spacing = _states(problem, q, v, along, n_states)
    names = _passive_names(m, lay)
    best = None   # ((dt_limit, -max |lambda|), state index, modes, limiting mode)
    n_bad, t_bad = 0, []
    lam_all = 0.0
    for i, (t, qs, vs, aa) in enumerate(states):
        md = _Modes(passive_jacobian(problem, qs, vs, aa), integ)
        lam_all = max(lam_all, md.lam_max)
        if md.fails(h):
            n_bad += 1
            t_bad.append(t)
        lim, k = md.limit()
        if k is None and md.lam.size:
            k = int(np.argmax(np.abs(md.lam)))
        key = (lim, -md.lam_max)
        if best is None or key < best[0]:
            best = (key, i, md, k)
    (lim, _), i, md, k = best
    t_w = states[i][0]
    lam = md.lam[k]
    vec = md.V[:, k]
    n = md.n
    score = np.sqrt(np.abs(lam * vec[:n]) ** 2 + np.abs(vec[n:]) ** 2)
    if not np.any(score > 0):
        score = np.abs(vec[:n]) + np.abs(vec[n:])
    shares = score / np.sum(score)
    dof = names[int(np.argmax(shares))]
    r, kk, _ = md.ratios(h)
    f_h = md.factors(h)[0]
    amp = float(f_h[np.argmax(np.where(kk == k, r, -np.inf))] if np.any(kk == k) else np.max(f_h))
    order = np.argsort(-np.abs(md.lam), kind="stable")
    diverged = rollout not in (None, "ok")
    ok = n_bad == 0 and not diverged
    lim_out = None if not math.isfinite(lim) else float(lim)
    unstable_s = None if spacing is None else n_bad * spacing
    timed = t_w is not None and where != "at the initial state"
    rate = abs(lam)
    if ok:
        limtxt = f"within {name}'s stability limit ({_fmt_dt(lim)})" if lim_out else \
            f"within {name}'s stability region (no step limit found)"
        msg = (f"dt = {_fmt_dt(h)} is {limtxt} for every mode of the passive dynamics linearized {where} "
               f"(limiting mode: rate {rate:.3g} 1/s, dominated by {dof}" + (f", at t = {t_w:.3g} s" if timed else "")
               + ")")
    elif diverged and n_bad == 0:
        msg = (f"{rollout}: dt = {_fmt_dt(h)} is likely far too large (the initial state alone allows "
               f"{_fmt_dt(lim) if lim_out else 'any step'}); check the model and the initial guess, or reduce dt")
    else:
        hint, remedy = _hint(problem, lam, bool(md.growing[k]))
        lim_txt = f" ({_fmt_dt(lim)})" if lim_out else ""
        sug = f"dt <= {_fmt_dt(_floor2(lim))}" if lim_out and lim < h else "a smaller dt"
        at = where + (f" at t = {t_w:.3g} s" if timed else "")
        if unstable_s is not None:
            tb = [x for x in t_bad if x is not None]
            at += (f" and for about {unstable_s:.2g} s of it ({n_bad} of {len(states)} states"
                   + (f", t = {min(tb):.3g}-{max(tb):.3g} s" if len(tb) > 1 else "") + ")")
        msg = (f"dt = {_fmt_dt(h)} is past {name}'s stability limit{lim_txt} for a mode of rate {rate:.3g} 1/s "
               f"dominated by {dof}, {hint}, {at}: velocities of the rollout are not the dynamics'; "
               f"use {sug}{remedy}")
        if diverged:
            msg += f"; also {rollout}"
    return dict(
        ok=bool(ok), **base, dt_limit=lim_out, max_abs_lambda=float(lam_all),
        worst_lambda=dict(real=float(lam.real), imag=float(lam.imag)),
        worst_lambda_dt=dict(real=float(lam.real * h), imag=float(lam.imag * h)), amplification=amp,
        dof=dof, dof_shares={nm: float(s_) for nm, s_ in zip(names, shares)}, t=t_w, where=where,
        n_states=len(states), n_unstable=n_bad, unstable_s=unstable_s,
        eigenvalues=[[float(z.real), float(z.imag)] for z in md.lam[order]], rollout=rollout,
        message=msg, wall_time_s=time.perf_counter() - t0)
