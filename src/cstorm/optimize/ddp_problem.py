"""A `MotionProblem` as a discrete optimal control problem for the DDP solver
(`cstorm.optimize.ddp`): the same model, contact, costs and constraints, transcribed
with one control per integration step.

Transcription
-------------
- State ``x = (q (nq,), v (nv,))`` at the grid points ``t_k = k dt``, ``k = 0..N``
  (the problem's grid); tangents ``dx = (dq (nv,), dv (nv,))``, ``q (+) dq`` on the
  joints' groups (free joints on SE(3)).
- Control ``u_k`` (n_active,): the active joints' motor torques (N m), held over the
  step ``[t_k, t_k+1)``; every DoF's acceleration comes from forward dynamics (ABA, the
  hybrid algorithm with every DoF passive) with the generalized forces
  ``passive_forces(q, v) + S' u`` and the contact wrenches. Torques rather than
  accelerations because the motor limits are then boxes on ``u`` (exact on every step,
  in the backward pass) and the torque cost is quadratic in ``u``: its Hessian is exact,
  not a Gauss-Newton model through the inverse dynamics. Node ``N`` has a control too:
  the torques at ``t_final`` (the trajectory's last ``tau``, what ``end["a"]`` of a
  terminal term is computed with).
- Integrator: the problem's. ``"rk4"``: RK4 with the torque held over the step, free
  joints by RKMK4 (as `cstorm.simulate`); ``"euler"``: semi-implicit Euler.
- Objective: ``sum_{k<N} dt L(t_k, y_k) + Psi(y_N)`` (running terms by the rectangle
  rule on the grid, which with RK4's held torque is exact for torque-only costs such as
  `costs.TorqueSquared`), plus ``1e-9/2 |u_N|^2`` that keeps the terminal torques
  defined when no term reads them (not part of the reported cost).
- Constraints: each term says how DDP evaluates it (``Constraint.ddp``): ``"path"``
  terms at every node (`Constraint.point_values`, within their time window),
  ``"end"`` terms at node ``N`` (their ``values`` with the start state as the only
  sample), ``"box"`` terms (`constraints.TorqueLimits`) as bounds on ``u`` at every
  node; terms that read the whole trajectory at once (``ddp = None``, e.g. a flight
  phase at some instant) as whole-trajectory rows (`ddp.OCP.traj_constraints`). The
  spline transcription's built-in conditions become rows too: the active joints' end
  position, velocity and rest (equalities at ``N``), ``rest_start`` (at node 0), and
  their position limits at every node (the paper's method keeps them by bounding the
  control points), unless the problem has its own `constraints.JointLimits` or
  ``x_bounds``.
- Initial guess (`initial_guess`): the active joints follow the problem's initial
  guess (its splines), the passive joints its ``node_guess`` (a state-level guess) or
  rest at ``q0``; the controls are the torques that the hybrid dynamics needs along that
  path. It is generally not dynamically consistent: the solver starts from its tracked
  rollout where that is well-conditioned, and from it with its gaps otherwise
  (`first_iterate`).
"""

from __future__ import annotations

import dataclasses
import sys
import time

import numpy as np
import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree

from ..dynamics.configuration import difference as q_difference, integrate as q_integrate
from ..dynamics.crba import mass_matrix
from ..dynamics.derivatives_fast import hybrid_fast
from ..dynamics.hybrid import hybrid_unchecked
from ..dynamics.passive import passive_forces
from ..errors import DivergenceError, ProblemError
from ..version import __version__ as _ver
from ..simulate import RolloutLayout, contact_hybrid, dexpinv, passive_exp
from . import costs as _costs
from .constraints import JointLimits
from .ddp import OCP, DDPOptions, compile_ocp, initial_multipliers, solve_ocp
from .problem import EvalContext
from .solution import Solution, Status, contact_dict

__all__ = ["Transcription", "transcribe"]

_U_REG = 1e-9


@dataclasses.dataclass(eq=False)
class Transcription:
    """`transcribe`'s result: ``ocp`` (`ddp.OCP`), ``data`` (its dynamic inputs), ``lb``,
    ``ub`` ((N+1, n_active) control bounds, N m), ``unravel`` (flat point -> dict ``q, v,
    a, tau, contact``), ``eq_slices`` / ``in_slices`` (per constraint term: its label and
    rows in a node's ``c_eq`` / ``c_in``)."""

    problem: object
    ocp: OCP
    data: dict
    lb: np.ndarray
    ub: np.ndarray
    unravel: object
    eq_terms: list
    in_terms: list
    geq_terms: list = dataclasses.field(default_factory=list)
    gin_terms: list = dataclasses.field(default_factory=list)
    dyn: object = None

    def row_label(self, kind, node, row):
        """The term and time of row ``row`` of node ``node``'s ``c_eq``/``c_in``."""
        k = 0
        terms = dict(eq=self.eq_terms, ineq=self.in_terms, **{"traj-eq": self.geq_terms,
                                                              "traj-ineq": self.gin_terms})[kind]
        for label, n in terms:
            if row < k + n:
                return f"{label!r} (row {row - k} of {n})" + ("" if node < 0 else f" at t = {node * self.problem.dt:.4g} s")
            k += n
        return f"{kind} row {row} at node {node}"

    def initial_guess(self, data=None):
        return initial_guess(self, data)

    def trajectory(self, Y):
        """Per-node points ``Y`` (N+1, n_y) -> dict ``t, q, v, a, tau`` (and ``contact``)
        stacked over the grid (numpy)."""
        pts = jax.vmap(self.unravel)(jnp.asarray(Y))
        out = dict(t=np.asarray(self.problem.t), q=np.asarray(pts["q"]), v=np.asarray(pts["v"]),
                   a=np.asarray(pts["a"]), tau=np.asarray(pts["tau"]))
        if pts.get("contact") is not None:
            out["contact"] = jax.tree_util.tree_map(np.asarray, pts["contact"])
        return out


def _dynamics(problem, layout_all, iva):
    """``dyn(q, v, u, data) -> (a (nv,), tau (nv,), contact data)``: forward dynamics with
    motor torques ``u`` on the active DoFs (``tau``: the trajectory's convention, motor
    torques on active DoFs, spring/damper/limit forces on passive ones). Derivatives: the
    analytic rule of the hybrid algorithm (composed with the contact Jacobian), or with
    the problem's ``derivatives="autodiff"`` JAX's through the algorithm (the reference;
    the same values, derivatives equal to rounding)."""
    model0 = problem.model
    nv = model0.nv
    all_passive = (False,) * nv
    cfn = problem.contact_fn
    autodiff = problem.derivatives == "autodiff"

    def dyn(q, v, u, data):
        model = data["model"]
        pf = passive_forces(model, q, v)
        gen = pf.at[iva].add(u) if len(iva) else pf
        if autodiff:  # the reference: JAX differentiates through the recursive algorithm
            f_ext, cd = (None, None) if cfn is None else cfn(model, data.get("env"), data.get("contact"), q, v)
            _, a = hybrid_unchecked(model, q, v, jnp.zeros(0, q.dtype), gen, all_passive, f_ext)
        elif cfn is None:
            _, a = hybrid_fast(model, q, v, jnp.zeros(0, q.dtype), gen, all_passive, None)
            cd = None
        else:
            fn = lambda q_, v_: cfn(model, data.get("env"), data.get("contact"), q_, v_)
            _, a, _, cd = contact_hybrid(model, fn, q, v, jnp.zeros(0, q.dtype), gen, all_passive)
        tau = pf.at[iva].set(u) if len(iva) else pf
        return a, tau, cd

    return dyn


def _stepper(problem, dyn, layout_all, ravel):
    """``step(x, u, k, data) -> (x_next, y)`` and ``point(x, u, k, data) -> y``."""
    model0 = problem.model
    nq = model0.nq
    h = problem.dt

    def point(x, u, k, data):
        q, v = x[:nq], x[nq:]
        a, tau, cd = dyn(q, v, u, data)
        return ravel(q, v, a, tau, cd)

    if problem.integrator == "euler":
        def step(x, u, k, data):
            q, v = x[:nq], x[nq:]
            a, tau, cd = dyn(q, v, u, data)
            vn = v + h * a
            qn = passive_exp(model0, layout_all, q, h * vn)
            return jnp.concatenate([qn, vn]), ravel(q, v, a, tau, cd)
        return step, point

    def step(x, u, k, data):
        # RK4 / RKMK4 with the torque held; the four stages as a scan (the dynamics is
        # traced once); the grid point's data (stage 0) rides in the carry
        q, v = x[:nq], x[nq:]
        dtype = x.dtype
        cs = jnp.array([0.0, 0.5, 0.5, 1.0], dtype)
        bs = jnp.array([1.0, 2.0, 2.0, 1.0], dtype) / 6.0
        first = jnp.array([True, False, False, False])
        y_shape = jax.eval_shape(lambda: point(x, u, k, data))

        def stage(sc, z):
            Kp, Wp, sK, sW, rec = sc
            c, b, i0 = z
            th = c * h * Kp
            qi = passive_exp(model0, layout_all, q, th)
            vi = v + c * h * Wp
            a, tau, cd = dyn(qi, vi, u, data)
            Ki = dexpinv(model0, layout_all, th, vi)
            y = ravel(qi, vi, a, tau, cd)
            rec = jnp.where(i0, y, rec)
            return (Ki, a, sK + b * Ki, sW + b * a, rec), None

        z0 = jnp.zeros_like(v)
        rec0 = jnp.zeros(y_shape.shape, dtype)
        (_, _, sK, sW, rec), _ = jax.lax.scan(stage, (z0, z0, z0, z0, rec0), (cs, bs, first))
        qn = passive_exp(model0, layout_all, q, h * sK)
        vn = v + h * sW
        return jnp.concatenate([qn, vn]), rec

    return step, point


def transcribe(problem) -> Transcription:
    """The DDP transcription of ``problem`` (a `MotionProblem`; see the module
    docstring). Raises `ProblemError` for what it cannot transcribe: free initial
    states, multiple shooting, whole-trajectory constraint terms."""
    p = problem
    if p.free_initial:
        raise ProblemError(f"{p.name}: method='ddp' starts from a fixed initial state; free_initial "
                           f"({sorted(p.free_initial)}) needs method='slsqp'")
    model0 = p.model
    nq, nv = model0.nq, model0.nv
    N = p.n_steps
    layout = p.layout
    iva = np.array(layout.va_idx, int)
    nu = len(iva)
    layout_all = RolloutLayout.make(model0, ())
    dyn = _dynamics(p, layout_all, iva)
    data = p.data()
    data = {k: v for k, v in data.items() if k != "basis"}

    # the flat point y: (q, v, a, tau, contact data) of one node
    q0 = jnp.asarray(p.q0)
    v0 = jnp.asarray(p.v0)
    a_s, tau_s, cd_s = jax.eval_shape(lambda: dyn(q0, v0, jnp.zeros(nu), data))
    template = dict(q=q0, v=v0, a=jnp.zeros(nv), tau=jnp.zeros(nv),
                    contact=None if cd_s is None else jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype),
                                                                            cd_s))
    flat0, unravel = ravel_pytree(template)

    def ravel(q, v, a, tau, cd):
        return ravel_pytree(dict(q=q, v=v, a=a, tau=tau, contact=cd))[0]

    step, point = _stepper(p, dyn, layout_all, ravel)

    # --- constraint terms
    ctx0 = EvalContext(p, model0, data["params"])
    eq_terms, in_terms = [], []  # (term, where, n_rows, node mask (N+1,))
    geq_terms, gin_terms = [], []  # whole-trajectory terms: (term, n_rows)
    lb = np.full((N + 1, nu), -np.inf)
    ub = np.full((N + 1, nu), np.inf)
    pt0 = unravel(flat0)
    end0 = dict(q=q0, v=v0, a=jnp.zeros(nv), tau=jnp.zeros(nv))
    start0 = dict(t=jnp.zeros(1), q=q0[None], v=v0[None])
    for c in list(p.constraints) + _boundary_terms(p):
        how = getattr(c, "ddp", None)
        if how == "box":
            lo, hi = c.control_bounds(p, {k: np.asarray(v) for k, v in p.params.items()})
            lb = np.maximum(lb, lo)
            ub = np.minimum(ub, hi)
            continue
        if how == "path":
            n = jax.eval_shape(lambda pt: jnp.atleast_1d(c.point_values(ctx0, dict(pt, t=jnp.zeros(()))))
                               .ravel(), pt0).shape[0]
            mask = np.asarray(c.node_mask(p), bool)
        elif how == "end":
            n = jax.eval_shape(lambda e: jnp.atleast_1d(c.values(ctx0, e, start0)).ravel(), end0).shape[0]
            mask = np.zeros(N + 1, bool)
            mask[N] = True
        else:  # a term that reads the whole trajectory (its values on the constraint grid)
            n = jax.eval_shape(lambda: jnp.atleast_1d(c.values(ctx0, end0, _samples(p, jnp.tile(flat0, (N + 1, 1)),
                                                                                     unravel, data))).ravel()).shape[0]
            (geq_terms if c.kind == "eq" else gin_terms).append((c, n))
            continue
        (eq_terms if c.kind == "eq" else in_terms).append((c, how, n, mask))
    if np.any(lb > ub):
        raise ProblemError(f"{p.name}: the torque limits leave no admissible torque (lower > upper bound)")

    def rows(terms):
        n = sum(t[2] for t in terms)
        M = np.zeros((N + 1, n), bool)
        k = 0
        for _, _, m, mask in terms:
            M[:, k:k + m] = mask[:, None]
            k += m
        return n, M

    n_eq, mask_eq = rows(eq_terms)
    n_in, mask_in = rows(in_terms)

    running = [c for c in p.costs if type(c).running is not _costs.Cost.running]
    terminal = [c for c in p.costs if type(c).terminal is not _costs.Cost.terminal]
    h = p.dt

    def cost(y, k, data):
        ctx = EvalContext(p, data["model"], data["params"])
        pt = unravel(y)
        t = k * h
        L = jnp.zeros((), y.dtype)
        for c in running:
            r = c.running(ctx, t, pt["q"], pt["v"], pt["a"], pt["tau"], pt["contact"])
            if r is not None:
                L = L + r
        out = jnp.where(k < N, h * L, 0.0)
        if terminal:
            end = dict(q=pt["q"], v=pt["v"], a=pt["a"], tau=pt["tau"])
            T = jnp.zeros((), y.dtype)
            for c in terminal:
                r = c.terminal(ctx, end)
                if r is not None:
                    T = T + r
            out = out + jnp.where(k == N, T, 0.0)
        if nu:
            ua = pt["tau"][iva]
            out = out + jnp.where(k == N, 0.5 * _U_REG * jnp.sum(ua * ua), 0.0)
        return out

    def constraints(y, k, data):
        ctx = EvalContext(p, data["model"], data["params"])
        pt = dict(unravel(y), t=k * h)
        end = dict(q=pt["q"], v=pt["v"], a=pt["a"], tau=pt["tau"])
        start = dict(t=jnp.zeros(1), q=data["q0"][None], v=data["v0"][None])

        def vals(terms):
            out = []
            for c, how, _, _ in terms:
                v_ = c.point_values(ctx, pt) if how == "path" else c.values(ctx, end, start)
                out.append(jnp.atleast_1d(v_).ravel())
            return jnp.concatenate(out) if out else jnp.zeros(0, y.dtype)

        return vals(eq_terms), vals(in_terms)

    def traj_constraints(Y, data):
        ctx = EvalContext(p, data["model"], data["params"])
        samples = _samples(p, Y, unravel, data)
        yN = unravel(Y[-1])
        end = dict(q=yN["q"], v=yN["v"], a=yN["a"], tau=yN["tau"])

        def vals(terms):
            out = [jnp.atleast_1d(c.values(ctx, end, samples)).ravel() for c, _ in terms]
            return jnp.concatenate(out) if out else jnp.zeros(0, Y.dtype)

        return vals(geq_terms), vals(gin_terms)

    qb, vb = p.q_bound, p.v_bound

    def x_bad(x):
        return ~jnp.all(jnp.isfinite(x)) | jnp.any(jnp.abs(x[:nq]) > qb) | jnp.any(jnp.abs(x[nq:]) > vb)

    def integrate(x, dx):
        return jnp.concatenate([q_integrate(model0, x[:nq], dx[:nv]), x[nq:] + dx[nv:]])

    def diff(x0, x1):
        return jnp.concatenate([q_difference(model0, x0[:nq], x1[:nq]), x1[nq:] - x0[nq:]])

    ocp = OCP(n_steps=N, nx=2 * nv, nu=nu, n_eq=n_eq, n_in=n_in, integrate=integrate, difference=diff, step=step,
              point=point, cost=cost, constraints=constraints, mask_eq=mask_eq, mask_in=mask_in, x_bad=x_bad,
              n_geq=sum(n for _, n in geq_terms), n_gin=sum(n for _, n in gin_terms),
              traj_constraints=traj_constraints if geq_terms or gin_terms else None)
    return Transcription(problem=p, ocp=ocp, data=data, lb=lb, ub=ub, unravel=unravel, dyn=dyn,
                         eq_terms=[(c.label(), n) for c, _, n, _ in eq_terms],
                         in_terms=[(c.label(), n) for c, _, n, _ in in_terms],
                         geq_terms=[(c.label(), n) for c, n in geq_terms],
                         gin_terms=[(c.label(), n) for c, n in gin_terms])


def _samples(p, Y, unravel, data):
    """The `MotionProblem`'s ``samples`` (its constraint grid, and every step under
    ``"steps"``) from the stacked node points ``Y`` (N+1, n_y), for terms that read the
    whole trajectory."""
    pts = jax.vmap(unravel)(Y)
    idx = np.asarray(p.sample_idx)
    t = jnp.asarray(p.t)
    out = dict(t=t[idx], q=pts["q"][idx], v=pts["v"][idx], a=pts["a"][idx], tau=pts["tau"][idx],
               steps=dict(t=t, q=pts["q"], v=pts["v"], a=pts["a"], tau=pts["tau"]))
    if pts.get("contact") is not None:
        out["contact"] = jax.tree_util.tree_map(lambda x: x[idx], pts["contact"])
    return out


class _ActiveBoundary:
    """The active joints' boundary conditions, which the spline transcription imposes by
    construction, as DDP equality rows: at the end, ``q_a = q_final_active``, ``v_a =
    v_final_active`` (or 0 with ``rest_end``) and ``a_a = 0`` (``rest_end``); at the start
    ``a_a = 0`` (``rest_start``). rad and rad/s (m, m/s for prismatic joints); the
    accelerations enter as the velocity change over one step, ``dt a_a`` (rad/s), so that
    they share the velocity rows' units and tolerance: resting on a compliant contact,
    the final accelerations change by ~1e5 rad/s^2 per rad of the final state (and the
    friction law is strongly curved at zero slip), so a tolerance of 1e-6 rad/s^2 would
    ask the end state for a precision no linearization of the trajectory resolves."""

    kind = "eq"

    def __init__(self, problem, at_start):
        lay = problem.layout
        self.ia, self.iva = np.array(lay.qa_idx, int), np.array(lay.va_idx, int)
        self.at_start = at_start
        self.ddp = "path" if at_start else "end"
        self.p = problem

    def label(self):
        return "active joints at the start" if self.at_start else "active joints at the end"

    def node_mask(self, problem):
        m = np.zeros(problem.n_steps + 1, bool)
        m[0] = True
        return m

    def point_values(self, ctx, point):  # rest_start
        return self.p.dt * point["a"][self.iva]

    def values(self, ctx, end, samples):
        p, out = self.p, []
        if p.qa_final is not None:
            out.append(end["q"][self.ia] - jnp.asarray(p.qa_final))
        if p.rest_end:
            out += [end["v"][self.iva], p.dt * end["a"][self.iva]]
        elif p.va_final is not None:
            out.append(end["v"][self.iva] - jnp.asarray(p.va_final))
        return jnp.concatenate(out)


class _ActiveLimits:
    """The active joints' position limits (the model's finite ``q_lower``/``q_upper``) at
    every node, as the paper's method keeps them through its variable bounds
    (`cstorm.optimize.solve.variable_bounds`). Inequalities, rad or m."""

    kind = "ineq"
    ddp = "path"

    def __init__(self, problem):
        m, lay = problem.model, problem.layout
        lo, hi = np.asarray(m.q_lower, float), np.asarray(m.q_upper, float)
        ia = np.array(lay.qa_idx, int)
        self.lo_i, self.hi_i = ia[np.isfinite(lo[ia])], ia[np.isfinite(hi[ia])]
        self.lo, self.hi = lo[self.lo_i], hi[self.hi_i]

    def label(self):
        return "active joint limits"

    def node_mask(self, problem):
        return np.ones(problem.n_steps + 1, bool)

    def point_values(self, ctx, point):
        q = point["q"]
        return jnp.concatenate([q[self.lo_i] - self.lo, self.hi - q[self.hi_i]])


def _boundary_terms(p):
    out = []
    lim = _ActiveLimits(p)
    if (len(lim.lo_i) or len(lim.hi_i)) and not any(isinstance(c, JointLimits) for c in p.constraints) \
            and getattr(p, "x_bounds", None) is None:
        out.append(lim)
    if p.layout.n_active and (p.qa_final is not None or p.rest_end or p.va_final is not None):
        out.append(_ActiveBoundary(p, at_start=False))
    if p.layout.n_active and p.rest_start:
        out.append(_ActiveBoundary(p, at_start=True))
    return out


def initial_guess(tr: Transcription, data=None):
    """``(X0 (N+1, nq+nv), U0 (N+1, n_active))``: the posture-level guess (see the module
    docstring). ``X0[0]`` is the problem's start state."""
    p = tr.problem
    model = p.model
    nv = model.nv
    N = p.n_steps
    data = tr.data if data is None else data
    full = p.data()
    lay = p.layout
    ia, iva = np.array(lay.qa_idx, int), np.array(lay.va_idx, int)
    ctrl = np.asarray(p.ctrl(jnp.asarray(p.x0), full))
    B = {k: np.asarray(v) for k, v in p.basis.items()}
    qa, va, aa = B["B0"] @ ctrl, B["B1"] @ ctrl, B["B2"] @ ctrl
    Q = np.tile(np.asarray(p.q0), (N + 1, 1))
    V = np.zeros((N + 1, nv))
    if p.node_guess is not None:
        for k, t in enumerate(p.t):
            qk, vk = (np.asarray(z, float).reshape(-1) for z in p.node_guess(float(t)))
            Q[k], V[k] = qk, vk
    if len(ia):
        Q[:, ia], V[:, iva] = qa, va
    Q[0], V[0] = p.q0, p.v0
    U = _guess_torques(tr, Q, V, aa, data)
    return np.concatenate([Q, V], axis=1), U


def tracking_gains(tr: Transcription, data=None, bandwidth=None):
    """(N+1, n_active, 2 nv) feedback gains ``u = U + K (x (-) X)`` of a joint-space PD
    law on the active joints, critically damped at ``bandwidth`` rad/s (default ``1 /
    (10 dt)``: stiff enough that the joints hold the guess's postures under the contact
    loads, and well inside what the step resolves): ``K_p = M_jj w^2``, ``K_d = 2 M_jj
    w`` with ``M_jj`` the joint's diagonal inertia (armature included) at the start
    configuration."""
    p = tr.problem
    data = tr.data if data is None else data
    nv, N = p.model.nv, p.n_steps
    iva = np.array(p.layout.va_idx, int)
    w = 1.0 / (10.0 * p.dt) if bandwidth is None else float(bandwidth)
    # compiled once per problem (eager, the CRBA's op-by-op dispatch takes ~2 s every solve)
    M = np.asarray(p.cached("ddp_mass_matrix", lambda: jax.jit(mass_matrix))(data["model"], data["q0"]))
    K = np.zeros((N + 1, len(iva), 2 * nv))
    for j, i in enumerate(iva):
        K[:, j, i] = -M[i, i] * w * w
        K[:, j, nv + i] = -2.0 * M[i, i] * w
    return K


#: the first iterate is the tracked rollout only if a change of ``FOLLOW_DELTA`` N m of
#: every torque moves its states by at most ``FOLLOW_GAIN`` times as much (`first_iterate`)
FOLLOW_DELTA = 1e-8
FOLLOW_GAIN = 1e4


#: what `solve_ddp` started from (``Solution.info["first_iterate"]``)
_STARTS = dict(rollout="the guess tracked by a PD law on the joints (a rollout)", guess="the guess with its gaps",
               given="the given guess")


def first_iterate(C, tr, X, U, data, al):
    """The first iterate ``(X, U, how)`` from the guess ``(X, U)``: a rollout of the
    guess's torques from the start state with the joint-space PD law of `tracking_gains`
    on the active joints, if that rollout is well-conditioned (``how = "rollout"``:
    dynamically consistent and gap-free); otherwise the guess itself with its gaps
    (``how = "guess"``). Well-conditioned: changing every torque by `FOLLOW_DELTA` moves
    the rollout's states by at most `FOLLOW_GAIN` times that.

    Why both. A guess that the robot can hold (stand, balance, lower its arms) is best
    started gap-free: with gaps, the value function's terms ``V_xx f`` over a long horizon
    of a barely stable stance swamp the step (the tumbler's `start` segment stalls in its
    first iterations). A guess that leaves the passive DoFs at rest while the motion needs
    them to move (a hop) makes the tracked rollout chaotic: the lamp lands somewhere
    different for a rounding-level change of the torques, so rounding would decide the
    solve. Measured gains: tumbler `start` 0.74, acrobot 0.15, Luxo hop 1.1e9."""
    lb, ub = jnp.asarray(tr.lb), jnp.asarray(tr.ub)
    K = jnp.asarray(tracking_gains(tr, data))
    X, U = np.asarray(X), np.asarray(U)
    no_gaps = jnp.zeros((X.shape[0], K.shape[2]))  # (a full step closes them: unused)

    def roll(U_):
        return C.forward(jnp.asarray(X), jnp.asarray(U_), jnp.zeros(U.shape), K, no_gaps, 1.0, lb, ub, data, al)

    r0, r1 = roll(U), roll(U + FOLLOW_DELTA)
    if bool(r0["bad"]) or bool(r1["bad"]):
        return X, U, "guess"
    X1, U1 = np.asarray(r0["X"]), np.array(r0["U"])
    if not np.max(np.abs(np.asarray(r1["X"]) - X1)) <= FOLLOW_GAIN * FOLLOW_DELTA:
        return X, U, "guess"
    # the final node's torques enter no dynamics: those that hold the active joints still
    # at the final state (what a rest at the end asks), not the PD law's reaction to the
    # final tracking error (evaluated on N+1 copies: the compiled shape)
    p = tr.problem
    nq = p.model.nq
    xN = np.tile(X1[-1:], (X1.shape[0], 1))
    hold = _guess_torques(tr, xN[:, :nq], xN[:, nq:], np.zeros((xN.shape[0], len(p.layout.va_idx))), data)[0]
    U1[-1] = np.clip(hold, tr.lb[-1], tr.ub[-1])
    return X1, U1, "rollout"


def _guess_torques(tr, Q, V, AA, data):
    """Motor torques (N+1, n_active) that give the active accelerations ``AA`` (N+1,
    n_active) at the states ``(Q, V)`` (N+1 rows each; hybrid dynamics with the passive
    DoFs' own forces and contact). The accelerations are affine in the torques (contact
    and passive forces depend on ``q, v`` only), ``a_a = a_0 + G u``, so ``n_active + 1``
    evaluations of the transcription's own forward dynamics at each node (`_Compiled`'s
    shooting evaluation, torques 0 and each unit torque) give ``a_0`` and ``G`` exactly,
    without compiling an inverse dynamics of its own."""
    p = tr.problem
    iva = np.array(p.layout.va_idx, int)
    nu = len(iva)
    _, C = compiled_transcription(p)
    X = jnp.concatenate([jnp.asarray(Q), jnp.asarray(V)], axis=1)
    al = initial_multipliers(tr.ocp, 1.0)
    acc = lambda U: np.asarray(jax.vmap(tr.unravel)(C.evaluate(X, U, data, al)["Y"])["a"])[:, iva]
    U0 = jnp.zeros((X.shape[0], nu))
    a0 = acc(U0)
    G = np.stack([acc(U0.at[:, j].set(1.0)) - a0 for j in range(nu)], axis=2)  # (N+1, n_active, n_active)
    return np.linalg.solve(G, (np.asarray(AA) - a0)[:, :, None])[:, :, 0]


def resimulate(problem, U, q0, v0, factor=4, integrator=None, X=None, K=None):
    """Re-simulate a DDP solution's controls ``U`` ((N+1, n_active) motor torques, each
    held over its step) from ``(q0, v0)`` with ``integrator`` (default the problem's) at
    ``dt / factor``. With the plan's states ``X`` (N+1, nq+nv) and feedback gains ``K``
    (N+1, n_active, 2 nv) (the solution's ``trajectory["feedback"]``), closed loop: the
    torque of step ``k`` is ``clip(U_k + K_k (x_k (-) X_k))`` within the torque limits,
    evaluated at the step's start and held over its ``factor`` substeps (the solver's
    local policy, as a controller tracking the plan would run it). Returns ``(Q (N+1,
    nq), V (N+1, nv), U_applied (N+1, n_active))`` on the problem's grid; raises
    `DivergenceError` if the states leave the bounds."""

    tr, _ = compiled_transcription(problem)
    integ = integrator or problem.integrator
    key = ("ddp_resim", int(factor), integ)
    diff = tr.ocp.difference

    def build():
        layout_all = RolloutLayout.make(problem.model, ())
        sub = _SubProblem(problem, factor, integ)
        step, _ = _stepper(sub, tr.dyn, layout_all, lambda q, v, a, tau, cd: jnp.zeros(0))

        def run(x0, U, X, K, lb, ub, data):
            def one(x, z):
                u_ref, x_ref, K_, lo, hi = z
                u = jnp.clip(u_ref + K_ @ diff(x_ref, x), lo, hi)

                def inner(xx, _):
                    return step(xx, u, 0, data)[0], None
                xn = jax.lax.scan(inner, x, None, length=int(factor))[0]
                return xn, (xn, u)
            xN, (xs, us) = jax.lax.scan(one, x0, (U[:-1], X[:-1], K[:-1], lb[:-1], ub[:-1]))
            uN = jnp.clip(U[-1] + K[-1] @ diff(X[-1], xN), lb[-1], ub[-1])
            return jnp.concatenate([x0[None], xs]), jnp.concatenate([us, uN[None]])

        return jax.jit(run)

    U = jnp.asarray(U, jnp.float64)
    x0 = jnp.concatenate([jnp.asarray(q0, jnp.float64), jnp.asarray(v0, jnp.float64)])
    if K is None:
        K = jnp.zeros(U.shape + (2 * problem.model.nv,))
        X = jnp.tile(x0, (U.shape[0], 1))
    X, U_applied = problem.cached(key, build)(x0, U, jnp.asarray(X, jnp.float64), jnp.asarray(K, jnp.float64),
                                              jnp.asarray(tr.lb), jnp.asarray(tr.ub), tr.data)
    X = np.asarray(X)
    nq = problem.model.nq
    if not np.all(np.isfinite(X)) or np.any(np.abs(X[:, :nq]) > problem.q_bound) or \
            np.any(np.abs(X[:, nq:]) > problem.v_bound):
        raise DivergenceError(f"{problem.name}: the re-simulation of the torques at dt/{factor} diverged")
    return X[:, :nq], X[:, nq:], np.asarray(U_applied)


@dataclasses.dataclass
class _SubProblem:
    """What `_stepper` reads of a problem, at a finer step."""

    problem: object
    factor: int
    integrator: str

    @property
    def model(self):
        return self.problem.model

    @property
    def dt(self):
        return self.problem.dt / self.factor


def compiled_transcription(problem):
    """The problem's transcription and compiled DDP functions, built once per problem
    (``problem.compiled`` caches them under ``"ddp"``)."""

    def build():
        tr = transcribe(problem)
        return tr, compile_ocp(tr.ocp)

    return problem.cached("ddp", build)


def solve_ddp(problem, *, q0=None, v0=None, guess=None, max_iter=500, tol=1e-9, constraint_tol=1e-6,
              verbose=False, callback=None, out=None, options=None):
    """Solve ``problem`` (a `MotionProblem`) by constrained FDDP (`cstorm.optimize.ddp`)
    from the posture-level guess (`initial_guess`) or ``guess = (X0, U0)``; ``q0``, ``v0``:
    another start state (a sequence's later segments). Returns a `Solution` whose
    ``x`` is the controls ``U.ravel()`` ((N+1) n_active motor torques, N m) and whose
    trajectory carries them as ``u`` (N+1, n_active), and the solver's feedback gains at
    the solution as ``feedback`` (N+1, n_active, 2 nv; the local policy ``u = u_k + K_k
    (x (-) x_k)``, N m per tangent unit of the state, what `resimulate` runs closed
    loop)."""
    t0 = time.perf_counter()
    tr, C = compiled_transcription(problem)
    data = dict(tr.data)
    if q0 is not None:
        data["q0"] = jnp.asarray(q0, jnp.float64)
    if v0 is not None:
        data["v0"] = jnp.asarray(v0, jnp.float64)
    tc = time.perf_counter()  # compile (timed separately): the guess's and one call of each compiled function
    X0, U0 = initial_guess(tr, data) if guess is None else (np.asarray(guess[0], float), np.asarray(guess[1], float))
    X0 = np.array(X0)
    X0[0] = np.concatenate([np.asarray(data["q0"]), np.asarray(data["v0"])])
    opt = DDPOptions(max_iter=int(max_iter), tol=float(tol), constraint_tol=float(constraint_tol),
                     verbose=bool(verbose), **(options or {}))
    stream = out or sys.stdout
    log = lambda s: print(s, file=stream, flush=True)
    al = initial_multipliers(tr.ocp, opt.mu0)
    Xj, Uj = jnp.asarray(X0), jnp.clip(jnp.asarray(U0), tr.lb, tr.ub)
    lin = C.linearize(Xj, Uj, data, al)
    bw = C.backward(lin, Uj, jnp.asarray(tr.lb), jnp.asarray(tr.ub), 1e-9)
    jax.block_until_ready(C.forward(Xj, Uj, bw["k"], bw["K"], lin["gaps"], 0.0, jnp.asarray(tr.lb),
                                    jnp.asarray(tr.ub), data, al))
    ev0 = C.evaluate(Xj, Uj, data, al)
    jax.block_until_ready(C.node_terms(ev0["Y"], data, al))
    if opt.project_end:
        jax.block_until_ready(C.project(lin, bw, jnp.asarray(tr.ocp.mask_eq[-1], bool),
                                        jnp.asarray(tr.ocp.mask_in[-1], bool)))
    compile_s = time.perf_counter() - tc
    start = "given"
    if guess is None:
        X0, U0, start = first_iterate(C, tr, X0, np.asarray(Uj), data, al)
    if verbose:
        log(f"first iterate: {_STARTS[start]}")
    res = solve_ocp(tr.ocp, X0, U0, data, tr.lb, tr.ub, opt, compiled=C, callback=callback, log=log,
                    row_label=tr.row_label)
    traj = tr.trajectory(res.Y)
    traj["u"] = np.asarray(res.U)
    traj["feedback"] = np.asarray(res.K)
    if traj.get("contact") is not None:
        traj["contact"] = contact_dict(traj["contact"])
    success = res.converged and res.violation <= constraint_tol
    message = {"converged": "converged", "max_iter": f"iteration limit ({max_iter}) reached",
               "line_search": "no step decreased the merit at the largest regularization",
               "regularization": "the backward pass failed at the largest regularization",
               "interrupted": "interrupted by the user (KeyboardInterrupt); returning the best iterate so far"
               }.get(res.status, res.status)
    if res.reason == "stalled":
        message += f" (the merit changed by less than tol={tol:g} over the last {opt.stall_window} steps)"
    if res.status == "converged" and not success:
        message += f"; but the constraint violation {res.violation:.3g} exceeds constraint_tol={constraint_tol:g}"
    if res.worst is not None and res.violation > constraint_tol:
        message += f"; most violated: {tr.row_label(*res.worst[:3])} by {res.worst[3]:.3g}"
    info = dict(method="ddp", controls="motor torques held over each step", first_iterate=start,
                max_iter=max_iter, tol=tol,
                constraint_tol=constraint_tol, status=res.status, converged_by=res.reason, gap=res.gap,
                problem_hash=problem.hash(),
                problem_description=problem.describe(), cstorm_version=_ver,
                constraint_rows=dict(eq=tr.eq_terms, ineq=tr.in_terms, trajectory_eq=tr.geq_terms,
                                     trajectory_ineq=tr.gin_terms))
    status = (Status.SOLVED if success else Status.INTERRUPTED if res.status == "interrupted" else
              Status.INFEASIBLE if res.status == "converged" else Status.SOLVER_FAILED)
    sol = Solution(success=bool(success), status=status, message=message, cost=float(res.cost),
                   constraint_violation=float(res.violation), iterations=res.iterations,
                   x=np.asarray(res.U).ravel(), trajectory=traj, history=res.history, problem=problem.name,
                   params={k: np.asarray(v).tolist() for k, v in problem.params.items()},
                   wall_time_s=time.perf_counter() - t0, compile_time_s=compile_s, n_evaluations=res.iterations,
                   info=info)
    sol.segments = [Solution(**{**sol.__dict__, "segments": []})]
    return sol


def spline_guess(problem, solution):
    """The paper's decision vector ``x`` (n_vars,) fitted to a DDP solution: each active
    joint's quintic B-spline fitted by least squares to the solution's joint path on the
    grid, with the problem's boundary conditions imposed (`MotionProblem`'s
    ``initial_guess`` as samples). A start for ``cs.solve(problem, method="slsqp",
    x0=...)`` that polishes a DDP motion in the paper's parametrization; the fitted
    paths are smoother than per-step torques allow, so the rollout of ``x`` is near the
    DDP motion, not on it."""
    tr = solution.trajectory
    t, q = np.asarray(tr["t"], float), np.asarray(tr["q"], float)
    if t.shape[0] != problem.n_steps + 1:
        raise ProblemError(f"{problem.name}: the solution has {t.shape[0]} grid points, the problem "
                           f"{problem.n_steps + 1}")
    model = problem.model
    guess = {n: (t, q[:, model.joint_q(n).start]) for n in problem.active}
    return problem.initial_x(guess)
