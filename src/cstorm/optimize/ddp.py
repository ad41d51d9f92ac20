"""Constrained feasibility-driven DDP: FDDP (Mastalli et al. 2020) with control boxes in
the backward pass (Tassa, Mansard & Todorov 2014, as Crocoddyl's BoxFDDP) and an
augmented-Lagrangian outer loop for equality and inequality constraints (as ALTRO,
Howell et al. 2019). The solver works on an `OCP`, a discrete optimal control problem
given as pure JAX functions; `cstorm.optimize.ddp_problem` builds one from a
`MotionProblem`.

Problem (nodes ``k = 0..N``, ``N = n_steps``)::

    min   sum_k  cost(y_k, k)  +  AL penalties of c_eq(y_k, k) = 0, c_in(y_k, k) >= 0
    s.t.  x_{k+1} = step(x_k, u_k, k)          k = 0..N-1
          x_0 fixed,  lb_k <= u_k <= ub_k      k = 0..N
          y_k = point(x_k, u_k, k)             (what cost and constraints read)

Every node has a control; node ``N``'s control enters no dynamics, only the terminal
point ``y_N`` (e.g. the motor torques that hold the final posture). States live on a
manifold: ``integrate(x, dx)`` and ``difference(x0, x1)`` (``x1 = x0 (+) dx``) map
between an ambient state ``x`` (n_xa,) and tangents ``dx`` (nx,).

One iteration
-------------
1. *Linearize* every node at once (``vmap`` of ``jacfwd``): ``A_k = d x_{k+1}/d x_k``,
   ``B_k = d x_{k+1}/d u_k`` in tangent coordinates, and ``J_k = d y_k / d(x_k, u_k)``.
   Cost and constraint derivatives follow from ``J_k`` by the chain rule; their
   Hessians by Gauss-Newton (``J^T H_y J`` with ``H_y`` the cost's exact Hessian in
   ``y`` and the penalties' ``mu`` on active rows), so no second derivative of the
   dynamics is ever formed.
2. *Backward pass* (``lax.scan`` from ``N`` to ``0``): the Riccati recursion with the
   gaps ``f_k`` of the current iterate (FDDP: ``V_x' = V_x + V_xx f``), the state
   regularization ``V_xx + rho I`` and control regularization ``Q_uu + rho I``; the
   control step is the box-constrained QP ``min 1/2 du' Q_uu du + Q_u' du`` s.t. the
   box, solved by projected Newton; the feedback gains act on the free controls only.
3. *Forward pass with feedback* and a backtracking line search over ``alpha``:
   ``x^_k = f(x^_{k-1}, u^_{k-1}) (+) (alpha - 1) f_k`` (the gaps shrink by
   ``1 - alpha``), ``u^_k = clip(u_k + alpha k_k + K_k (x^_k (-) x_k))``. While gaps
   remain, a step is accepted when its rollout stays finite (FDDP); once the iterate is
   dynamically feasible, by the Armijo test on the merit (cost plus penalties) against
   the quadratic model's prediction. A failed search or a failed factorization raises
   ``rho`` tenfold; a full step lowers it.

With ``DDPOptions.second_order`` the Hessians also carry the dynamics' curvature weighted
by the costates of a Gauss-Newton pass at the iterate (DDP proper rather than iLQR): on
contact the Gauss-Newton model can miss most of the curvature along its own step, so
its full steps overshoot and the tail converges slowly.

Outer loop: after each inner solve of at least one iteration (stationarity below a
tolerance that tightens with the constraint violation, or an iteration cap), the
multipliers take their first-order update (``lambda_eq += mu c``, ``lambda_in = max(0,
lambda_in - mu c)``) and every row whose violation did not fall below a quarter of its
last value gets a tenfold ``mu``.
The rules and constants are the solver's, the same for every problem.

Compiled once per problem shape: the iterate, multipliers, penalties, ``alpha`` and
``rho`` are dynamic arguments.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Callable

import numpy as np
import jax
import jax.numpy as jnp

__all__ = ["OCP", "DDPOptions", "DDPResult", "solve_ocp", "box_qp"]


@dataclasses.dataclass(frozen=True, eq=False)
class OCP:
    """A discrete optimal control problem for `solve_ocp` (see the module docstring).

    Attributes:
      n_steps: ``N``. nx: tangent dimension of the state. nu: controls per node.
      n_eq, n_in: equality / inequality rows per node (the same at every node; rows a
        node does not enforce are masked out by ``mask_eq`` / ``mask_in``).
      integrate: ``(x, dx) -> x``. difference: ``(x0, x1) -> dx`` with ``x1 = x0 (+) dx``.
      step: ``(x, u, k, data) -> (x_next, y)``: one integration step and the node's
        point ``y`` (a flat (n_y,) array), the same as ``point(x, u, k, data)``.
      point: ``(x, u, k, data) -> y``.
      cost: ``(y, k, data) -> scalar`` (node ``k``'s share of the objective).
      constraints: ``(y, k, data) -> (c_eq (n_eq,), c_in (n_in,))``.
      mask_eq, mask_in: (N+1, n_eq) / (N+1, n_in) bool host arrays: which rows each node
        enforces.
      x_bad: ``(x) -> bool``: a state the rollout must not pass (non-finite or beyond
        bounds); the rollout freezes there and the trial point is rejected.
      traj_constraints: optional ``(Y (N+1, n_y), data) -> (g_eq (n_geq,), g_in
        (n_gin,))``: rows that read the whole trajectory at once (a flight phase "at some
        instant"). Their penalties' gradients reach every node; their Gauss-Newton
        Hessians keep each node's own block (the couplings between nodes are dropped).
    """

    n_steps: int
    nx: int
    nu: int
    n_eq: int
    n_in: int
    integrate: Callable
    difference: Callable
    step: Callable
    point: Callable
    cost: Callable
    constraints: Callable
    mask_eq: np.ndarray
    mask_in: np.ndarray
    x_bad: Callable
    n_geq: int = 0
    n_gin: int = 0
    traj_constraints: Callable | None = None


@dataclasses.dataclass
class DDPOptions:
    """Solver settings (the defaults are used for every problem).

    max_iter: DDP iterations in all (outer loops included). tol: convergence tolerance,
    relative to ``1 + |merit|``: the model's predicted merit decrease of a full step
    below it, or the merit's change over the last ``stall_window`` iterations below it
    (as SLSQP's ``ftol``), at a feasible iterate.
    constraint_tol: largest constraint violation accepted (units of the rows). gap_tol:
    largest dynamics gap (tangent norm) of a feasible iterate. mu0: initial penalty.
    mu_max: largest penalty. reg0, reg_min, reg_max: regularization; a full step
    multiplies it by ``reg_down``, an accepted step shorter than ``reg_up_below`` by 10.
    alpha_min: the shortest line-search step. project_end: try the step that meets the
    final node's rows' linearization (`_Compiled._project`) before the penalty-only step.
    second_order: once the iterate is gap-free, add the dynamics' curvature weighted by
    the costates (`_Compiled._curvature`, DDP's ``V_x . f_zz``) to the Gauss-Newton
    Hessians, where the Riccati pass stays positive definite with it (Gauss-Newton's pass
    otherwise). The term is refreshed when a full step fails on a term computed at an
    earlier iterate. About 9 times a linearization's cost per refresh.
    verbose: print one line per iteration.
    """

    max_iter: int = 500
    tol: float = 1e-9
    constraint_tol: float = 1e-6
    gap_tol: float = 1e-9
    mu0: float = 10.0
    mu_max: float = 1e10
    reg0: float = 1e-9
    reg_min: float = 1e-9
    reg_max: float = 1e9
    alpha_min: float = 2.0 ** -12
    reg_down: float = 1.0 / 3.0
    reg_up_below: float = 0.5
    project_end: bool = True
    second_order: bool = False
    armijo: float = 0.1
    inner_max_iter: int = 60
    stall_window: int = 5
    verbose: bool = False


@dataclasses.dataclass
class DDPResult:
    """What `solve_ocp` returns: ``X`` (N+1, n_xa) states, ``U`` (N+1, nu) controls,
    ``Y`` (N+1, n_y) points, ``cost`` (objective without penalties), ``violation`` (max
    constraint violation over enforced rows), ``gap`` (max dynamics gap), ``converged``,
    ``status`` (a short reason: "converged", "max_iter", "line_search", "interrupted",
    "diverged"), ``iterations``, ``history`` (per-iteration dicts), ``lam_eq``,
    ``lam_in``, ``mu_eq``, ``mu_in`` (final multipliers and penalties), ``worst`` (the
    most violated row, `_worst_row`) and ``multipliers`` (every multiplier and penalty,
    node and trajectory rows: what `solve_ocp` takes back as ``multipliers`` to warm-start)
    and ``K`` (N+1, nu, nx): the feedback gains of the Riccati pass at ``(X, U)``, the
    local policy ``u = U_k + K_k (x (-) X_k)``. ``reason``: which test stopped a
    converged solve ("stationary": the full step's predicted decrease is below ``tol``;
    "stalled": the merit changed by less than ``tol`` over the last ``stall_window``
    steps)."""

    X: np.ndarray
    U: np.ndarray
    Y: np.ndarray
    cost: float
    violation: float
    gap: float
    converged: bool
    status: str
    iterations: int
    history: list
    lam_eq: np.ndarray
    lam_in: np.ndarray
    mu_eq: np.ndarray
    mu_in: np.ndarray
    worst: tuple = None
    multipliers: dict = None
    K: np.ndarray = None
    reason: str = ""


def _worst_row(ev):
    """``(kind, node, row, violation)`` of the most violated constraint row, or None."""
    out = None
    for kind, v in (("eq", np.asarray(ev["ve"])), ("ineq", np.asarray(ev["vi"]))):
        if v.size and (out is None or v.max() > out[3]):
            node, row = np.unravel_index(int(np.argmax(v)), v.shape)
            out = (kind, int(node), int(row), float(v.max()))
    for kind, key in (("traj-eq", "vge"), ("traj-ineq", "vgi")):
        v = np.asarray(ev.get(key, np.zeros(0)))
        if v.size and (out is None or v.max() > out[3]):
            out = (kind, -1, int(np.argmax(v)), float(v.max()))
    return out


# ---------------------------------------------------------------------------------------
# Per-node merit: cost plus augmented-Lagrangian penalties
# ---------------------------------------------------------------------------------------
def _penalty(ce, ci, me, mi, le, li, mue, mui):
    """Augmented-Lagrangian penalty of one node (PHR form for the inequalities):
    ``sum_eq (l c + mu/2 c^2) + sum_in ((max(0, l - mu c))^2 - l^2) / (2 mu)``, masked."""
    pe = jnp.sum(jnp.where(me, le * ce + 0.5 * mue * ce * ce, 0.0))
    s = jnp.maximum(0.0, li - mui * ci)
    pi = jnp.sum(jnp.where(mi, (s * s - li * li) / (2.0 * mui), 0.0))
    return pe + pi


def _violation(ce, ci, me, mi):
    """Per-row violation: ``|c_eq|`` and ``max(0, -c_in)`` (0 on masked rows)."""
    return jnp.where(me, jnp.abs(ce), 0.0), jnp.where(mi, jnp.maximum(0.0, -ci), 0.0)


class _Compiled:
    """The compiled pieces of one `OCP`: evaluation, linearization, backward pass and
    forward pass (one XLA compile each per problem shape)."""

    def __init__(self, ocp: OCP):
        self.ocp = ocp
        self.linearize = jax.jit(self._linearize)
        self.curvature = jax.jit(self._curvature)
        self.backward = jax.jit(self._backward)
        self._forward_jit = jax.jit(self._forward)
        self.project = jax.jit(self._project)
        self.node_terms = jax.jit(self._node_terms)

    # -- evaluation of a trajectory --------------------------------------------------
    def _node_terms(self, Y, data, al):
        o = self.ocp
        ks = jnp.arange(o.n_steps + 1)
        cost = jax.vmap(lambda y, k: o.cost(y, k, data))(Y, ks)
        ce, ci = jax.vmap(lambda y, k: o.constraints(y, k, data))(Y, ks)
        me, mi = jnp.asarray(o.mask_eq), jnp.asarray(o.mask_in)
        pen = jnp.sum(jax.vmap(_penalty)(ce, ci, me, mi, al["lam_eq"], al["lam_in"], al["mu_eq"], al["mu_in"]))
        ve, vi = _violation(ce, ci, me, mi)
        out = dict(cost=jnp.sum(cost), ce=ce, ci=ci, ve=ve, vi=vi)
        if o.traj_constraints is not None:
            ge, gi = o.traj_constraints(Y, data)
            te, ti = jnp.ones(ge.shape, bool), jnp.ones(gi.shape, bool)
            pen = pen + _penalty(ge, gi, te, ti, al["lam_geq"], al["lam_gin"], al["mu_geq"], al["mu_gin"])
            vge, vgi = _violation(ge, gi, te, ti)
            out.update(ge=ge, gi=gi, vge=vge, vgi=vgi)
        out["merit"] = out["cost"] + pen
        return out

    def evaluate(self, X, U, data, al):
        """Values of an iterate (multiple shooting: every step starts at its own node
        ``X_k``): ``dict(cost, merit, ce, ci, ve, vi (per-row violations), gaps (N+1, nx),
        Y (N+1, n_y), bad)``. The forward pass's compiled function in its shooting mode,
        so an evaluation costs no compile of its own."""
        z = jnp.zeros_like(U)
        K0 = jnp.zeros(U.shape + (self.ocp.nx,), U.dtype)
        inf = jnp.full(U.shape, jnp.inf, U.dtype)
        return self.forward(X, U, z, K0, jnp.zeros(X.shape[:1] + (self.ocp.nx,), X.dtype), 0.0, -inf, inf, data,
                            al, shoot=True)

    # -- linearization -------------------------------------------------------------------
    def _local_step(self, x, xn_ref, k, data):
        """Node ``k``'s step in local coordinates: ``z = (dx (nx,), u (nu,)) -> (f(x (+) dx,
        u) (-) xn_ref (nx,), y (n_y,))``, what the linearization and the curvature term
        differentiate."""
        o = self.ocp

        def f(z):
            xn, y = o.step(o.integrate(x, z[:o.nx]), z[o.nx:], k, data)
            return o.difference(xn_ref, xn), y

        return f

    def _linearize(self, X, U, data, al):
        """Derivatives of every node: dynamics ``A (N, nx, nx)``, ``B (N, nx, nu)``, gaps
        ``(N+1, nx)`` and the merit's gradient and Gauss-Newton Hessian blocks ``lx, lu,
        lxx, luu, lux``."""
        o = self.ocp
        nx, nu = o.nx, o.nu
        N = o.n_steps

        def node(x, u, xn_ref, k):
            f = self._local_step(x, xn_ref, k, data)
            z0 = jnp.concatenate([jnp.zeros(nx, x.dtype), u])
            # values and Jacobians from one batched forward pass over the nx + nu tangents
            (dxn, y), (Jx, Jy) = jax.vmap(lambda t: jax.jvp(f, (z0,), (t,)), out_axes=(None, -1))(
                jnp.eye(nx + nu, dtype=x.dtype))
            return dxn, y, Jx, Jy

        # every node, the last one included: its point and the point's Jacobian come from
        # the same compiled step (its own step past t_final is discarded), so the
        # dynamics and its derivatives are compiled once, not once more for node N
        ks = jnp.arange(N + 1)
        gaps, Y, Jn, JY = jax.vmap(node)(X, U, jnp.concatenate([X[1:], X[-1:]]), ks)
        gaps, Jn = gaps[:-1], Jn[:-1]
        yN, JyN = Y[-1], JY[-1]
        me, mi = jnp.asarray(o.mask_eq), jnp.asarray(o.mask_in)

        def merit_derivs(y, J, k, me_, mi_, le, li, mue, mui):
            lf = lambda yy: o.cost(yy, k, data)
            cf = lambda yy: o.constraints(yy, k, data)
            gy = jax.grad(lf)(y)
            HJ = jax.vmap(lambda t: jax.jvp(jax.grad(lf), (y,), (t,))[1], in_axes=1, out_axes=1)(J)
            H = J.T @ HJ
            (ce, ci), (Je, Ji) = cf(y), jax.vmap(lambda t: jax.jvp(cf, (y,), (t,))[1], in_axes=1, out_axes=1)(J)
            # penalty gradient and Gauss-Newton Hessian in z = (dx, u)
            we = jnp.where(me_, le + mue * ce, 0.0)
            act = mi_ & (li - mui * ci > 0)
            wi = jnp.where(act, -(li - mui * ci), 0.0)
            g = J.T @ gy + Je.T @ we + Ji.T @ wi
            H = H + Je.T @ (jnp.where(me_, mue, 0.0)[:, None] * Je) + Ji.T @ (jnp.where(act, mui, 0.0)[:, None] * Ji)
            return g, 0.5 * (H + H.T)

        g, H = jax.vmap(merit_derivs)(Y, JY, jnp.arange(N + 1), me, mi, al["lam_eq"], al["lam_in"], al["mu_eq"],
                                       al["mu_in"])
        if o.traj_constraints is not None:
            (ge, gi), (Ge, Gi) = o.traj_constraints(Y, data), jax.jacrev(lambda YY: o.traj_constraints(YY, data))(Y)
            we = al["lam_geq"] + al["mu_geq"] * ge
            act = al["lam_gin"] - al["mu_gin"] * gi > 0
            wi = jnp.where(act, -(al["lam_gin"] - al["mu_gin"] * gi), 0.0)
            he, hi = al["mu_geq"], jnp.where(act, al["mu_gin"], 0.0)
            # per node: the rows' Jacobians w.r.t. (dx, u), (n_g, nz)
            Ze = jnp.einsum("gky,kyz->kgz", Ge, JY)
            Zi = jnp.einsum("gky,kyz->kgz", Gi, JY)
            g = g + jnp.einsum("kgz,g->kz", Ze, we) + jnp.einsum("kgz,g->kz", Zi, wi)
            H = H + jnp.einsum("kgz,g,kgw->kzw", Ze, he, Ze) + jnp.einsum("kgz,g,kgw->kzw", Zi, hi, Zi)
        # gaps[k] = f(x_{k-1}, u_{k-1}) (-) x_k (tangent at x_k), none at the fixed start
        gaps = jnp.concatenate([jnp.zeros((1, nx), X.dtype), gaps])
        # the final node's rows and their Jacobians in z = (dx, u): `_project` treats them
        # as linearized constraints of the LQ subproblem
        cfN = lambda yy: jnp.concatenate(o.constraints(yy, N, data))
        cN = cfN(yN)
        CN = jax.jacfwd(cfN)(yN) @ JyN
        return dict(A=Jn[:, :, :nx], B=Jn[:, :, nx:], gaps=gaps, lx=g[:, :nx], lu=g[:, nx:], lxx=H[:, :nx, :nx],
                    luu=H[:, nx:, nx:], lux=H[:, nx:, :nx], cN=cN, CN=CN)

    def _curvature(self, X, U, data, costate):
        """The dynamics' second-order term of the Lagrangian's Hessian, per node: ``D_k =
        d^2/dz^2 (lambda_{k+1} . (f(x_k (+) dx, u) (-) X_{k+1}))`` at ``z = (0, U_k)``
        (N+1, nx + nu, nx + nu), with the costates ``lambda_{k+1}`` the value function's
        gradients of a Riccati pass (``costate`` (N+1, nx)); zero at node ``N``."""
        o = self.ocp
        nx = o.nx
        Xn = jnp.concatenate([X[1:], X[-1:]])
        lam = jnp.concatenate([costate[1:], jnp.zeros_like(costate[:1])])

        def node(x, u, xn_ref, lamn, k):
            f = self._local_step(x, xn_ref, k, data)
            z0 = jnp.concatenate([jnp.zeros(nx, x.dtype), u])
            H = jax.jacfwd(jax.grad(lambda z: lamn @ f(z)[0]))(z0)
            return 0.5 * (H + H.T)

        return jax.vmap(node)(X, U, Xn, lam, jnp.arange(self.ocp.n_steps + 1))

    # -- backward pass -------------------------------------------------------------------
    def _backward(self, lin, U, lb, ub, reg):
        """Riccati recursion with gaps and control boxes. Returns ``k (N+1, nu), K (N+1,
        nu, nx)``, the end rows' gain columns ``ke (N+1, nu, m)`` (see `_project`), the
        model terms ``d1 = sum Q_u k``, ``d2 = sum k' Q_uu k`` and ``ok`` (every
        factorization succeeded)."""
        o = self.ocp
        nx, nu = o.nx, o.nu
        eye_x, eye_u = jnp.eye(nx), jnp.eye(nu)
        A, B, fn = _padded(lin)
        # the end rows' Jacobians enter as extra gradient columns at node N only (their
        # value functions are linear: the same Riccati recursion, no Hessian of their own)
        m = lin["CN"].shape[0]
        CNt = lin["CN"].T  # (nx + nu, m)
        N = o.n_steps
        LX = jnp.zeros((N + 1, nx, m)).at[-1].set(CNt[:nx])
        LU = jnp.zeros((N + 1, nu, m)).at[-1].set(CNt[nx:])
        xs = (A, B, fn, lin["lx"], lin["lu"], lin["lxx"], lin["luu"], lin["lux"], U, lb, ub, LX, LU)

        def body(carry, z):
            Vx, Vxx, Wx = carry
            A_, B_, f_, lx, lu, lxx, luu, lux, u, lo, hi, lxe, lue = z
            Vxr = Vxx + reg * eye_x
            Vx1 = Vx + Vxx @ f_  # FDDP: the value gradient at the end of the gap
            Qx = lx + A_.T @ Vx1
            Qu = lu + B_.T @ Vx1
            Qxx = lxx + A_.T @ Vxr @ A_
            Quu = luu + B_.T @ Vxr @ B_ + reg * eye_u
            Qux = lux + B_.T @ Vxr @ A_
            Quu = 0.5 * (Quu + Quu.T)
            du, K_, free, ok = box_qp(Quu, Qu, Qux, lo - u, hi - u)
            Vx_n = Qx + K_.T @ Quu @ du + K_.T @ Qu + Qux.T @ du
            Vxx_n = Qxx + K_.T @ Quu @ K_ + K_.T @ Qux + Qux.T @ K_
            Vxx_n = 0.5 * (Vxx_n + Vxx_n.T)
            # the end rows' columns: gains on the same free controls
            Wux = lue + B_.T @ Wx
            Hf = jnp.where(free[:, None] & free[None, :], Quu, eye_u)
            ke = jnp.where(free[:, None], -jnp.linalg.solve(Hf, jnp.where(free[:, None], Wux, 0.0)), 0.0)
            Wx_n = lxe + A_.T @ Wx + K_.T @ Quu @ ke + K_.T @ Wux + Qux.T @ ke
            return (Vx_n, Vxx_n, Wx_n), (du, K_, ke, Qu @ du, du @ Quu @ du, ok, Vx_n, Vxx_n)

        init = (jnp.zeros(nx), jnp.zeros((nx, nx)), jnp.zeros((nx, m)))
        _, (k, K, ke, d1, d2, ok, Vx, Vxx) = jax.lax.scan(body, init, xs, reverse=True)
        ok = jnp.all(ok) & jnp.all(jnp.isfinite(k)) & jnp.all(jnp.isfinite(K))
        # the gap terms of the predicted change (FDDP): sum_k Vx_k . f_k and f_k' Vxx_k f_k
        f = lin["gaps"]
        dg = jnp.sum(jnp.einsum("ki,ki->k", Vx, f))
        dq = jnp.sum(jnp.einsum("ki,kij,kj->k", f, Vxx, f))
        return dict(k=k, K=K, ke=ke, d1=jnp.sum(d1), d2=jnp.sum(d2), dg=dg, dq=dq, ok=ok, Vxx=Vxx, Vx=Vx)

    # -- the end rows as constraints of the LQ subproblem ---------------------------------
    def _project(self, lin, bw, me_N, mi_N):
        """The step of the LQ subproblem with the final node's active rows as linearized
        equalities ``c_N + C_N dz_N = 0`` (active: the equality rows the node enforces and
        the violated inequality rows; the others stay penalties): the gains' columns
        ``ke`` make the step affine in the rows' multipliers ``nu`` (``k + ke nu``); a
        linear rollout gives ``dz_N(nu)``, and ``nu`` solves ``S nu = r`` on the active
        rows (``S = -C_N d(dz_N)/d(nu)``, ``r = c_N + C_N dz_N(0)``; 0 elsewhere). Returns
        the gains ``k`` (N+1, nu), the model's ``d1 = g' dz``, ``d2 = dz' H dz`` of the
        whole step, the multipliers and the linearized residual of the end rows."""
        nx = self.ocp.nx
        m = lin["CN"].shape[0]
        A, B, fn = _padded(lin)
        KA = jnp.concatenate([bw["k"][:, :, None], bw["ke"]], axis=2)  # (N+1, nu, 1+m)

        def body(dX, z):
            A_, B_, f_, ka, K_ = z
            dU = ka + K_ @ dX
            dXn = A_ @ dX + B_ @ dU + jnp.zeros_like(dX).at[:, 0].set(f_)
            return dXn, (dX, dU)

        _, (DX, DU) = jax.lax.scan(body, jnp.zeros((nx, 1 + m)), (A, B, fn, KA, bw["K"]))
        DZ = jnp.concatenate([DX, DU], axis=1)  # (N+1, nz, 1+m): dz_k = DZ_k [1; nu]
        R = lin["CN"] @ DZ[-1]  # (m, 1+m)
        r = lin["cN"] + R[:, 0]
        n_eq = me_N.shape[0]
        act = jnp.concatenate([me_N, mi_N & (lin["cN"][n_eq:] < 0)])
        S = -0.5 * (R[:, 1:] + R[:, 1:].T)
        both = act[:, None] & act[None, :]
        scale = jnp.max(jnp.where(act, jnp.abs(jnp.diagonal(S)), 0.0)) + 1e-300
        S = jnp.where(both, S, jnp.eye(m)) + 1e-12 * scale * jnp.eye(m)
        nu_ = jnp.where(act, jnp.linalg.solve(S, jnp.where(act, r, 0.0)), 0.0)
        ok = jnp.all(jnp.isfinite(nu_))
        w = jnp.concatenate([jnp.ones(1), nu_])
        dz = DZ @ w  # (N+1, nz)
        g = jnp.concatenate([lin["lx"], lin["lu"]], axis=1)
        H = jnp.concatenate([jnp.concatenate([lin["lxx"], jnp.swapaxes(lin["lux"], 1, 2)], axis=2),
                             jnp.concatenate([lin["lux"], lin["luu"]], axis=2)], axis=1)
        d1 = jnp.sum(g * dz)
        d2 = jnp.einsum("ki,kij,kj->", dz, H, dz)
        k = jnp.einsum("kuj,j->ku", KA, w)
        resid = lin["cN"] + R @ w
        ok = ok & jnp.all(jnp.isfinite(k)) & jnp.isfinite(d1) & jnp.isfinite(d2)
        return dict(k=k, d1=d1, d2=d2, nu=nu_, resid=resid, ok=ok)

    # -- forward pass --------------------------------------------------------------------
    def forward(self, X, U, k, K, gaps, alpha, lb, ub, data, al, shoot=False):
        """`_forward`, compiled once for both modes (``shoot`` is traced)."""
        return self._forward_jit(X, U, k, K, gaps, alpha, lb, ub, data, al, jnp.asarray(shoot))

    def _forward(self, X, U, k, K, gaps, alpha, lb, ub, data, al, shoot):
        """Rollout with feedback at step ``alpha``: the new ``(X, U)``, its values (cost,
        merit, rows, as `_node_terms`), its gaps (N+1, nx) (``f(x_{k-1}, u_{k-1}) (-)
        x_k``, the tangent at ``x_k``; 0 at the start) and ``bad`` (the rollout left the
        valid states). ``shoot=True``: every step starts at its node ``X_k`` instead (the
        evaluation of a multiple-shooting iterate, `evaluate`)."""
        o = self.ocp

        def body(carry, z):
            xpred, bad = carry
            x_ref, u_ref, kk, KK, f, lo, hi, i = z
            x = jnp.where(shoot, x_ref, o.integrate(xpred, (alpha - 1.0) * f))
            dx = o.difference(x_ref, x)
            u = jnp.clip(u_ref + alpha * kk + KK @ dx, lo, hi)
            xn, y = o.step(x, u, i, data)
            nbad = bad | o.x_bad(xn)
            xn = jnp.where(nbad, x, xn)  # frozen once bad: nothing downstream turns NaN
            return (xn, nbad), (x, u, y, xn, dx)

        N = o.n_steps
        xs = (X[:-1], U[:-1], k[:-1], K[:-1], gaps[:-1], lb[:-1], ub[:-1], jnp.arange(N))
        (xpred, bad), (Xn, Un, Yh, Xpred, dX) = jax.lax.scan(body, (X[0], jnp.zeros((), bool)), xs)
        xN = jnp.where(shoot, X[-1], o.integrate(xpred, (alpha - 1.0) * gaps[-1]))
        dxN = o.difference(X[-1], xN)
        uN = jnp.clip(U[-1] + alpha * k[-1] + K[-1] @ dxN, lb[-1], ub[-1])
        yN = o.point(xN, uN, N, data)
        Xn = jnp.concatenate([Xn, xN[None]])
        Un = jnp.concatenate([Un, uN[None]])
        Y = jnp.concatenate([Yh, yN[None]])
        out = self._node_terms(Y, data, al)
        bad = bad | ~jnp.all(jnp.isfinite(Y)) | ~jnp.isfinite(out["merit"])
        # the gaps left (FDDP: (1 - alpha) of the old ones, up to the transport)
        new_gaps = jax.vmap(o.difference)(Xn[1:], Xpred)
        new_gaps = jnp.concatenate([jnp.zeros((1, o.nx), X.dtype), new_gaps])
        return dict(out, X=Xn, U=Un, Y=Y, gaps=new_gaps, bad=bad, dX=jnp.concatenate([dX, dxN[None]]))


def _padded(lin):
    """The dynamics Jacobians ``A (N+1, nx, nx)``, ``B (N+1, nx, nu)`` and the gaps
    ``f_{k+1}`` as seen from node ``k`` (N+1, nx), each with a zero entry for node ``N``
    (no dynamics after it): the per-node inputs of the backward pass and of `_project`'s
    linear rollout."""
    A, B, gaps = lin["A"], lin["B"], lin["gaps"]
    pad = lambda a: jnp.concatenate([a, jnp.zeros((1,) + a.shape[1:], a.dtype)])
    return pad(A), pad(B), pad(gaps[1:])


def box_qp(H, g, Hux, lo, hi, n_iter=12):
    """``min 1/2 du' H du + g' du`` s.t. ``lo <= du <= hi`` (projected Newton with a
    backtracking search, ``n_iter`` iterations), and the feedback gain ``K = -H_ff^-1
    H_ux`` on the free rows (zero on rows clamped at a bound).

    Args:
      H: (nu, nu) positive definite. g: (nu,). Hux: (nu, nx), the cross term of the
        feedback gain. lo, hi: (nu,), infinite entries allowed.
    Returns:
      ``(du (nu,), K (nu, nx), free (nu,) bool: rows not clamped at a bound, ok: scalar
      bool, False where the Cholesky factorization of H failed)``. Pure JAX (jit, vmap)."""
    nu = g.shape[0]
    eye = jnp.eye(nu, dtype=g.dtype)
    L = jnp.linalg.cholesky(H)
    ok = jnp.all(jnp.isfinite(L))
    sol = lambda M, b: jax.scipy.linalg.cho_solve((M, True), b)
    du0 = jnp.clip(-sol(L, g), lo, hi)
    q = lambda d: 0.5 * d @ H @ d + g @ d

    def free_set(du):
        grad = H @ du + g
        clamped = ((du <= lo) & (grad > 0)) | ((du >= hi) & (grad < 0))
        return ~clamped, grad

    def body(_, du):
        free, grad = free_set(du)
        Hf = jnp.where(free[:, None] & free[None, :], H, eye)
        d = jnp.where(free, jnp.linalg.solve(Hf, -jnp.where(free, grad, 0.0)), 0.0)
        f0 = q(du)
        best = du
        found = jnp.zeros((), bool)
        for s in (1.0, 0.5, 0.25, 0.125, 0.0625):
            cand = jnp.clip(du + s * d, lo, hi)
            better = (~found) & (q(cand) < f0 - 1e-14 * jnp.abs(f0))
            best = jnp.where(better, cand, best)
            found = found | better
        return best

    has_box = jnp.any(jnp.isfinite(lo) | jnp.isfinite(hi))
    du = jax.lax.cond(has_box, lambda d: jax.lax.fori_loop(0, n_iter, body, d), lambda d: d, du0)
    free, _ = free_set(du)
    Hf = jnp.where(free[:, None] & free[None, :], H, eye)
    K = jnp.where(free[:, None], -jnp.linalg.solve(Hf, jnp.where(free[:, None], Hux, 0.0)), 0.0)
    return du, K, free, ok


# ---------------------------------------------------------------------------------------
# The solver loop
# ---------------------------------------------------------------------------------------
def _max(a):
    a = np.asarray(a)
    return float(a.max()) if a.size else 0.0


def solve_ocp(ocp: OCP, X0, U0, data, lb, ub, options: DDPOptions | None = None, *, compiled=None, callback=None,
              log=print, multipliers=None, row_label=None):
    """Solve ``ocp`` from the (possibly infeasible) iterate ``X0`` (N+1, n_xa), ``U0``
    (N+1, nu); ``X0[0]`` is the fixed initial state. ``lb``, ``ub``: (N+1, nu) control
    bounds (``+-inf`` where unbounded). ``data``: the dynamic inputs of the OCP's
    functions. ``compiled``: a `_Compiled` of this OCP to reuse (`compile_ocp`).
    ``callback(info)``: called after every iteration with its history entry; raising
    KeyboardInterrupt stops the solve, which returns the best iterate so far. Returns
    `DDPResult`. ``multipliers``: a `DDPResult.multipliers` to start from (default: zero
    multipliers, penalty ``mu0``). ``row_label(kind, node, row) -> str``: names the most
    violated row in the verbose lines (default: kind, node and row numbers)."""
    opt = options or DDPOptions()
    C = compiled or _Compiled(ocp)
    X = jnp.asarray(X0, jnp.float64)
    U = jnp.asarray(U0, jnp.float64)
    lb, ub = jnp.asarray(lb, jnp.float64), jnp.asarray(ub, jnp.float64)
    U = jnp.clip(U, lb, ub)
    # the rows the final node enforces (`_project`)
    me_N, mi_N = jnp.asarray(ocp.mask_eq[-1], bool), jnp.asarray(ocp.mask_in[-1], bool)
    n_end = int(me_N.sum() + mi_N.sum())
    al = initial_multipliers(ocp, opt.mu0)
    if multipliers is not None:
        al = {k: jnp.asarray(multipliers[k], jnp.float64) for k in al}
    t0 = time.perf_counter()
    ev = C.evaluate(X, U, data, al)
    gap = float(jnp.max(jnp.linalg.norm(ev["gaps"], axis=1)))
    feasible = gap <= opt.gap_tol
    reg = opt.reg0
    history = []
    status, it, converged, reason = "max_iter", 0, False, ""
    best = None
    row_prev = _row_state(ev)
    inner = outer = 0
    if opt.verbose:
        log(f"{'iter':>5} {'cost':>13} {'merit':>13} {'viol':>9} {'gap':>9} {'reg':>8} {'step':>8} {'stat':>9} "
            f"{'time':>7}  most violated")
    D, D_fresh = None, False  # `second_order`'s curvature term, and whether it is the iterate's
    try:
        lin = None
        while it < opt.max_iter:
            if lin is None:  # (kept when the iterate and the multipliers did not change)
                lin = C.linearize(X, U, data, al)
            bw = C.backward(lin, U, lb, ub, reg)
            if not bool(bw["ok"]):
                reg *= 10.0
                if reg > opt.reg_max:
                    status = "regularization"
                    break
                continue
            lin_used = lin
            so_used = False
            if opt.second_order and feasible:
                if D is None:
                    D, D_fresh = C.curvature(X, U, data, bw["Vx"]), True
                n = ocp.nx
                lin_so = dict(lin, lxx=lin["lxx"] + D[:, :n, :n], luu=lin["luu"] + D[:, n:, n:],
                              lux=lin["lux"] + D[:, n:, :n])
                bw_so = C.backward(lin_so, U, lb, ub, reg)
                if bool(bw_so["ok"]):
                    bw, lin_used, so_used = bw_so, lin_so, True
            d1, d2 = float(bw["d1"]), float(bw["d2"])
            merit = float(ev["merit"])
            stat = -d1 / (1.0 + abs(merit))
            viol = _max(_rows(ev))
            inner_tol = max(opt.tol, min(1e-3, viol * 1e-2)) if viol > opt.constraint_tol else opt.tol
            # no progress: the merit changed by less than tol (relative) over the last
            # `stall_window` iterations (as SLSQP's ftol)
            taken = [h["merit"] for h in history[-3 * opt.stall_window:] if h["step"] > 0 and h["outer"] == outer]
            stalled = len(taken) >= opt.stall_window and \
                abs(taken[-opt.stall_window] - merit) <= opt.tol * (1.0 + abs(merit))
            if feasible and (stat <= inner_tol or stalled or inner >= opt.inner_max_iter):
                if viol <= opt.constraint_tol and (stat <= opt.tol or stalled):
                    status, converged = "converged", True
                    reason = "stationary" if stat <= opt.tol else "stalled"
                    break
                if inner > 0:
                    # outer update: multipliers, and penalties of rows that did not
                    # improve; then at least one iteration before the next (a second
                    # update at the same iterate would add mu c to the multipliers again
                    # and raise the penalties tenfold again, with nothing solved between)
                    al = _update_al(al, ev, ocp, opt, row_prev)
                    outer += 1
                    lin = None
                    D = None
                    row_prev = _row_state(ev)
                    inner = 0
                    ev = dict(ev, **C.node_terms(ev["Y"], data, al))
                    continue
            # line search: first along the step that meets the end rows' linearization
            # (`_project`), then along the penalty-only step
            # (its merit adds the exact penalty sigma |c_N|_1 with sigma above the rows'
            # multipliers, as an SQP's: a step that meets the rows can raise the cost)
            steps = []
            if n_end and opt.project_end:
                pj = C.project(lin_used, bw, me_N, mi_N)
                if bool(pj["ok"]):
                    sigma = 2.0 * float(jnp.max(jnp.abs(pj["nu"])))
                    steps.append((pj["k"], float(pj["d1"]) - sigma * _end_viol(ev), float(pj["d2"]), "end"))
            steps.append((bw["k"], d1, d2, "al"))
            alpha, accepted, kind = 1.0, None, None
            for k_try, e1, e2, kind in steps:
                if feasible and e1 + 0.5 * e2 >= 0 and kind == "end":
                    continue  # not a descent direction of the merit
                # the end rows' step only where their linearization holds (a full or half
                # step); otherwise the penalty-only step decides, and the regularization
                alpha, a_min = 1.0, (0.5 if kind == "end" else opt.alpha_min)
                while alpha >= a_min:
                    tr = C.forward(X, U, k_try, bw["K"], lin["gaps"], alpha, lb, ub, data, al)
                    if not bool(tr["bad"]):
                        dm = float(tr["merit"]) - merit
                        if kind == "end":
                            dm += sigma * (_end_viol(tr) - _end_viol(ev))
                        pred = alpha * e1 + 0.5 * alpha * alpha * e2
                        if not feasible:
                            # FDDP's model of the change along a step that closes alpha of
                            # the gaps f (Mastalli et al. 2020, the value function's terms at
                            # the gaps, with the trial's deviation dx from the iterate); a
                            # predicted increase (closing gaps costs) is accepted up to twice
                            # itself. Accepting any step while gaps remain (Crocoddyl's
                            # FDDP) closed them all at once into a rollout that tipped the
                            # lamp over in 2 of 3 perturbed Luxo hops; an exact penalty on
                            # the gaps did too, whatever it weighed the gaps by
                            dv = float(jnp.einsum("ki,kij,kj->", ev["gaps"], bw["Vxx"], tr["dX"]))
                            pred = alpha * (e1 + float(bw["dg"]) - dv) + \
                                0.5 * alpha * alpha * (e2 - float(bw["dq"]) + 2.0 * dv)
                            ok_step = dm <= opt.armijo * pred if pred < 0 else dm <= 2.0 * pred
                        else:
                            ok_step = dm <= opt.armijo * pred
                        if ok_step or (pred > -1e-14 * (1 + abs(merit)) and dm <= 0):
                            accepted = tr
                            break
                    alpha *= 0.5
                if accepted is not None:
                    break
            it += 1
            inner += 1
            if (accepted is None or alpha < 1.0) and not D_fresh:
                D = None  # a stale curvature term failed the full step: refresh it
            if accepted is None:
                reg *= 10.0
                step = 0.0
                if reg > opt.reg_max:
                    status = "line_search"
                    break
            else:
                X, U = accepted["X"], accepted["U"]
                lin, D_fresh = None, False
                if kind == "end":
                    # the rows now hold to first order: their multipliers become the LQ
                    # step's (the penalties' gradient at c = 0 plus nu), so that the
                    # penalty-only steps that follow do not pull the rows back
                    al = _shift_end_multipliers(al, pj["nu"], ocp.n_eq, ev)
                    accepted = dict(accepted, **C.node_terms(accepted["Y"], data, al))
                gap_new = float(jnp.max(jnp.linalg.norm(accepted["gaps"], axis=1)))
                ev = dict(accepted)
                feasible = feasible or gap_new <= opt.gap_tol or alpha == 1.0
                step = alpha
                if alpha == 1.0:
                    reg = max(opt.reg_min, reg * opt.reg_down)
                elif alpha < opt.reg_up_below:
                    reg = min(opt.reg_max, reg * 10.0)
            gap = float(jnp.max(jnp.linalg.norm(ev["gaps"], axis=1))) if not feasible else 0.0
            viol = _max(_rows(ev))
            entry = dict(iteration=it, outer=outer, cost=float(ev["cost"]), merit=float(ev["merit"]), violation=viol,
                         gap=gap, reg=reg, step=step, stationarity=stat, time=time.perf_counter() - t0,
                         direction=kind if accepted is not None else None, second_order=so_used)
            history.append(entry)
            if feasible and (best is None or _better(entry, best[0], opt)):
                best = (entry, X, U)
            if opt.verbose:
                w = _worst_row(ev) if viol > opt.constraint_tol else None
                where = "" if w is None else (row_label(*w[:3]) if row_label else f"{w[0]} node {w[1]} row {w[2]}")
                mark = ("*" if entry["direction"] == "end" else " ") + ("2" if so_used else " ")
                log(f"{it:5d} {entry['cost']:13.6e} {entry['merit']:13.6e} {viol:9.2e} {gap:9.2e} {reg:8.1e} "
                    f"{step:8.2e}{mark}{stat:9.2e} {entry['time']:7.2f}  {where}")
            if callback is not None:
                callback(entry)
    except KeyboardInterrupt:
        status = "interrupted"
        if best is not None:
            _, X, U = best
    ev = C.evaluate(X, U, data, al)
    gap = float(jnp.max(jnp.linalg.norm(ev["gaps"], axis=1)))
    viol = _max(_rows(ev))
    worst = _worst_row(ev)
    # at convergence the loop's last Riccati pass is at (X, U) already
    K = np.asarray(bw["K"]) if status == "converged" else _feedback_gains(C, X, U, data, al, lb, ub, reg, opt)
    return DDPResult(worst=worst, X=np.asarray(X), U=np.asarray(U), Y=np.asarray(ev["Y"]), cost=float(ev["cost"]),
                     K=K,
                     violation=viol, gap=gap, converged=converged and gap <= max(opt.gap_tol, 1e-8),
                     status=status, reason=reason, iterations=it, history=history, lam_eq=np.asarray(al["lam_eq"]),
                     lam_in=np.asarray(al["lam_in"]), mu_eq=np.asarray(al["mu_eq"]), mu_in=np.asarray(al["mu_in"]),
                     multipliers={k: np.asarray(v) for k, v in al.items()})


def _feedback_gains(C, X, U, data, al, lb, ub, reg, opt):
    """The feedback gains ``K`` (N+1, nu, nx) of the Riccati pass at the iterate ``(X,
    U)``: the local policy ``u = U_k + K_k (x (-) X_k)`` (zero rows for controls at a
    bound). The regularization is the solver's last, raised until the pass succeeds;
    zeros if it never does."""
    lin = C.linearize(X, U, data, al)
    r = max(reg, opt.reg_min)
    while r <= opt.reg_max:
        bw = C.backward(lin, U, lb, ub, r)
        if bool(bw["ok"]):
            return np.asarray(bw["K"])
        r *= 10.0
    return np.zeros(U.shape + (lin["A"].shape[1],))


def _shift_end_multipliers(al, nu, n_eq, ev):
    """``al`` with the final node's multipliers moved by the LQ multipliers ``nu``
    (`_Compiled._project`; the equality rows' ``lambda + nu``, the inequality rows'
    ``max(0, lambda - nu)``: PHR's ``lambda`` multiplies ``-c_in``), each move no larger
    than the larger of the augmented Lagrangian's own update at the iterate before the
    step (``mu |c|`` of the row, ``ev``) and ``|lambda| + 1`` (a multiplier may double
    per step): a nearly singular row system gives huge ``nu``, which would make the
    penalties unbounded below. Capped at ``mu |c|`` alone, the multipliers of rows that
    are nearly met (``c -> 0``) could not move, and the iterates zig-zagged between the
    rows' step and the penalties' for hundreds of iterations (two perturbed Luxo hops:
    500 iterations unconverged; with this cap 271 and 118)."""
    cap = jnp.concatenate([al["mu_eq"][-1] * jnp.abs(ev["ce"][-1]), al["mu_in"][-1] * jnp.abs(ev["ci"][-1])])
    lam = jnp.concatenate([jnp.abs(al["lam_eq"][-1]), jnp.abs(al["lam_in"][-1])])
    cap = jnp.maximum(cap, lam + 1.0)
    nu = jnp.clip(nu, -cap, cap)
    out = dict(al)
    out["lam_eq"] = al["lam_eq"].at[-1].add(nu[:n_eq])
    out["lam_in"] = al["lam_in"].at[-1].set(jnp.maximum(0.0, al["lam_in"][-1] - nu[n_eq:]))
    return out


def _end_viol(ev):
    """The final node's total constraint violation (the l1 norm of its rows')."""
    return float(np.sum(np.asarray(ev["ve"][-1])) + np.sum(np.asarray(ev["vi"][-1])))


def _better(a, b, opt):
    """Is history entry ``a`` a better iterate than ``b`` (feasible first, then cost)?"""
    fa, fb = a["violation"] <= opt.constraint_tol, b["violation"] <= opt.constraint_tol
    if fa != fb:
        return fa
    return a["cost"] < b["cost"] if fa else a["violation"] < b["violation"]


def initial_multipliers(ocp, mu0):
    """Zero multipliers and the penalty ``mu0`` on every row (a dict of float64 arrays,
    not weakly typed: the updates' arrays are not, and a change of type recompiles every
    compiled function that takes them)."""
    N = ocp.n_steps
    f = lambda shape, v: jnp.full(shape, v, dtype=jnp.float64)
    return dict(lam_eq=f((N + 1, ocp.n_eq), 0.0), lam_in=f((N + 1, ocp.n_in), 0.0),
                mu_eq=f((N + 1, ocp.n_eq), mu0), mu_in=f((N + 1, ocp.n_in), mu0),
                lam_geq=f(ocp.n_geq, 0.0), lam_gin=f(ocp.n_gin, 0.0), mu_geq=f(ocp.n_geq, mu0),
                mu_gin=f(ocp.n_gin, mu0))


def _rows(ev):
    """Every row's violation, flattened: node rows then trajectory rows."""
    parts = [np.asarray(ev["ve"]).ravel(), np.asarray(ev["vi"]).ravel()]
    if "vge" in ev:
        parts += [np.asarray(ev["vge"]), np.asarray(ev["vgi"])]
    return np.concatenate(parts)


def _update_al(al, ev, ocp, opt, row_prev):
    """The outer loop's first-order multiplier update and per-row penalty increase: a
    row whose violation did not fall below a quarter of the last update's gets 10 times
    the penalty. A path row (one per node) has one penalty, the largest of its nodes':
    the scale of a constraint is the row's, and an active arc whose ends move between
    updates (a joint resting on its limit from some instant on) would otherwise meet the
    initial penalty at every node it newly reaches, so that its violation wandered along
    the arc for hundreds of iterations (the tumbler's `start` segment). Rows that are not
    active cost nothing at any penalty (PHR)."""
    ce, ci = ev["ce"], ev["ci"]
    me, mi = jnp.asarray(ocp.mask_eq), jnp.asarray(ocp.mask_in)
    out = dict(al)
    out["lam_eq"] = jnp.where(me, al["lam_eq"] + al["mu_eq"] * ce, 0.0)
    out["lam_in"] = jnp.where(mi, jnp.maximum(0.0, al["lam_in"] - al["mu_in"] * ci), 0.0)
    if "ge" in ev:
        out["lam_geq"] = al["lam_geq"] + al["mu_geq"] * ev["ge"]
        out["lam_gin"] = jnp.maximum(0.0, al["lam_gin"] - al["mu_gin"] * ev["gi"])
    pairs = [("mu_eq", "ve"), ("mu_in", "vi")] + ([("mu_geq", "vge"), ("mu_gin", "vgi")] if "ge" in ev else [])
    for (mu, v), prev in zip(pairs, row_prev):
        now = np.asarray(ev[v])
        up = (now > opt.constraint_tol) & (now > 0.25 * prev)
        new = jnp.where(up, jnp.minimum(al[mu] * 10.0, opt.mu_max), al[mu])
        if new.ndim == 2:  # a path row's penalty is the row's, at every node
            new = jnp.broadcast_to(jnp.max(new, axis=0), new.shape)
        out[mu] = new
    return out


def _row_state(ev):
    """The per-row violations `_update_al` compares with at the next outer update."""
    keys = ("ve", "vi", "vge", "vgi") if "vge" in ev else ("ve", "vi")
    return tuple(np.asarray(ev[k]) for k in keys)


def compile_ocp(ocp: OCP):
    """The compiled functions of ``ocp`` (reuse across solves of the same shape)."""
    return _Compiled(ocp)
