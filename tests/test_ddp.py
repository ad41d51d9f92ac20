"""The constrained DDP solver (`cstorm.optimize.ddp`) and its transcription of a
`MotionProblem` (`cstorm.optimize.ddp_problem`): the box QP against scipy, the step
linearization against central finite differences, and the optimum against Crocoddyl's
FDDP and BoxFDDP on a double pendulum discretized identically (same URDF, dt, integrator,
per-step torque controls held over the step, cost)."""

import os

import numpy as np
import pytest
import jax
import jax.numpy as jnp

import cstorm as cs
from cstorm.optimize import costs, constraints, ddp, ddp_problem
from cstorm.optimize.problem import MotionProblem

URDF = os.path.join(os.path.dirname(__file__), "..", "examples", "acrobot.urdf")
T, DT = 1.0, 0.01
N = int(round(T / DT))
W_U, W_X = 1.0, 100.0
TARGET = np.array([np.pi, 0.0])


def test_box_qp_matches_scipy():
    from scipy.optimize import minimize

    rng = np.random.default_rng(0)
    for trial in range(20):
        n = 1 + trial % 4
        A = rng.normal(size=(n, n))
        H = A @ A.T + 0.1 * np.eye(n)
        g = rng.normal(size=n) * 3
        lo, hi = -rng.uniform(0.1, 1.0, n), rng.uniform(0.1, 1.0, n)
        if trial % 5 == 0:
            lo[0], hi[0] = -np.inf, np.inf
        du, K, free, ok = ddp.box_qp(jnp.asarray(H), jnp.asarray(g), jnp.zeros((n, 2)), jnp.asarray(lo),
                                     jnp.asarray(hi))
        ref = minimize(lambda d: 0.5 * d @ H @ d + g @ d, np.zeros(n), jac=lambda d: H @ d + g,
                       bounds=list(zip(lo, hi)), method="L-BFGS-B", options=dict(ftol=1e-15, gtol=1e-12))
        assert bool(ok)
        np.testing.assert_allclose(np.asarray(du), ref.x, atol=1e-7)


def _pendulum_problem(integrator, torque_limit=None):
    model = cs.load_urdf(URDF)
    cons = [] if torque_limit is None else [constraints.TorqueLimits(limits=torque_limit)]
    return MotionProblem(
        model, active=["shoulder", "elbow"], t_final=T, n_ctrl=8, dt=DT, q0=np.zeros(2), integrator=integrator,
        costs=[costs.TorqueSquared(weight=W_U),
               costs.StateTarget("shoulder", q=[TARGET[0]], v=[0.0], weight=W_X),
               costs.StateTarget("elbow", q=[TARGET[1]], v=[0.0], weight=W_X)],
        constraints=cons, name="double_pendulum")


def test_step_linearization_matches_finite_differences():
    p = _pendulum_problem("rk4")
    tr = ddp_problem.transcribe(p)
    o = tr.ocp
    rng = np.random.default_rng(1)
    x = jnp.asarray(rng.normal(size=4))
    u = jnp.asarray(rng.normal(size=2) * 3)
    nx = o.nx
    xn0 = o.step(x, u, 3, tr.data)[0]

    def f(z):
        return o.difference(xn0, o.step(o.integrate(x, z[:nx]), z[nx:], 3, tr.data)[0])

    z0 = jnp.concatenate([jnp.zeros(nx), u])
    J = np.asarray(jax.jacfwd(f)(z0))
    h = 1e-6
    Jfd = np.stack([(np.asarray(f(z0 + h * e)) - np.asarray(f(z0 - h * e))) / (2 * h)
                    for e in np.eye(len(z0))], axis=1)
    np.testing.assert_allclose(J, Jfd, rtol=1e-6, atol=1e-8)


def test_dynamics_curvature_matches_finite_differences():
    """`second_order`'s curvature term at a node, ``d^2/dz^2 (lambda . f(x (+) dx, u))``,
    equals central differences of the step Jacobian's ``J' lambda``."""
    p = _pendulum_problem("rk4")
    tr = ddp_problem.transcribe(p)
    o = tr.ocp
    C = ddp.compile_ocp(o)
    rng = np.random.default_rng(3)
    X = jnp.asarray(rng.normal(size=(N + 1, 4)))
    U = jnp.asarray(rng.normal(size=(N + 1, 2)) * 3)
    lam = jnp.asarray(rng.normal(size=(N + 1, 4)))
    D = np.asarray(C.curvature(X, U, tr.data, lam))
    assert D.shape == (N + 1, 6, 6) and np.all(D[-1] == 0.0)
    nx = o.nx

    @jax.jit
    def g(z, k):  # J' lambda of node k's step at z = (dx, u)
        def f(zz):
            return o.difference(X[k + 1], o.step(o.integrate(X[k], zz[:nx]), zz[nx:], k, tr.data)[0])
        return jax.jacfwd(f)(z).T @ lam[k + 1]

    for k in (0, 41):
        z0 = jnp.concatenate([jnp.zeros(nx), U[k]])
        h = 1e-5
        Dfd = np.stack([(np.asarray(g(z0 + h * e, k)) - np.asarray(g(z0 - h * e, k))) / (2 * h) for e in np.eye(6)],
                       axis=1)
        np.testing.assert_allclose(D[k], Dfd, rtol=1e-6, atol=1e-7 * np.abs(Dfd).max())


def _crocoddyl_cost(integrator, torque_limit=None):
    crocoddyl = pytest.importorskip("crocoddyl")
    pin = pytest.importorskip("pinocchio")
    pm = pin.buildModelFromUrdf(URDF)  # continuous joints: q = (cos, sin) per joint
    state = crocoddyl.StateMultibody(pm)
    act = crocoddyl.ActuationModelFull(state)

    def dam(terminal):
        cm = crocoddyl.CostModelSum(state, act.nu)
        if terminal:
            xr = np.concatenate([np.cos(TARGET[:1]), np.sin(TARGET[:1]), np.cos(TARGET[1:]), np.sin(TARGET[1:]),
                                 np.zeros(2)])
            cm.addCost("x", crocoddyl.CostModelResidual(state, crocoddyl.ResidualModelState(state, xr, act.nu)), W_X)
        else:
            cm.addCost("u", crocoddyl.CostModelResidual(state, crocoddyl.ResidualModelControl(state, act.nu)), W_U)
        return crocoddyl.DifferentialActionModelFreeFwdDynamics(state, act, cm)

    def integrated(d, h):
        if integrator == "euler":
            return crocoddyl.IntegratedActionModelEuler(d, h)
        return crocoddyl.IntegratedActionModelRK(d, crocoddyl.RKType.four, h)

    run, term = integrated(dam(False), DT), integrated(dam(True), 0.0)
    # the models agree on the dynamics first (a mismatched pinocchio build gives garbage)
    q = np.array([0.3, -0.7])
    xp = np.concatenate([np.cos(q[:1]), np.sin(q[:1]), np.cos(q[1:]), np.sin(q[1:]), [0.5, 1.1]])
    dd = run.differential.createData()
    run.differential.calc(dd, xp, np.array([1.0, -2.0]))
    np.testing.assert_allclose(dd.xout, np.asarray(cs.aba(cs.load_urdf(URDF), q, np.array([0.5, 1.1]),
                                                         np.array([1.0, -2.0]))), rtol=1e-10)
    if torque_limit is not None:
        run.u_lb, run.u_ub = -torque_limit * np.ones(2), torque_limit * np.ones(2)
    x0 = np.concatenate([pin.neutral(pm), np.zeros(2)])
    problem = crocoddyl.ShootingProblem(x0, [run] * N, term)
    solver = crocoddyl.SolverBoxFDDP(problem) if torque_limit is not None else crocoddyl.SolverFDDP(problem)
    solver.th_stop = 1e-14
    assert solver.solve([x0] * (N + 1), [np.zeros(2)] * N, 500)
    return solver.cost


@pytest.mark.parametrize("integrator", ["rk4", pytest.param("euler", marks=pytest.mark.slow)])
def test_matches_crocoddyl_fddp_and_boxfddp(integrator):
    """The same optimum as Crocoddyl's FDDP (no limits) and BoxFDDP (torque boxes that
    saturate), to 1e-6 relative in cost; one compiled transcription serves both (the
    boxes are data)."""
    p = _pendulum_problem(integrator, torque_limit=12.0)
    tr, C = ddp_problem.compiled_transcription(p)
    X0 = np.tile(np.zeros(4), (N + 1, 1))
    U0 = np.zeros((N + 1, 2))
    free = ddp.solve_ocp(tr.ocp, X0, U0, tr.data, -np.inf * np.ones_like(tr.lb), np.inf * np.ones_like(tr.ub),
                         ddp.DDPOptions(tol=1e-12), compiled=C)
    boxed = ddp.solve_ocp(tr.ocp, X0, U0, tr.data, tr.lb, tr.ub, ddp.DDPOptions(tol=1e-12), compiled=C)
    assert free.converged and boxed.converged
    assert np.abs(boxed.U).max() <= 12.0 + 1e-12 and np.abs(free.U[:-1]).max() > 12.5  # the boxes bind
    c_free, c_box = _crocoddyl_cost(integrator), _crocoddyl_cost(integrator, torque_limit=12.0)
    assert abs(free.cost - c_free) <= 1e-6 * c_free
    assert abs(boxed.cost - c_box) <= 1e-6 * c_box
    # with the dynamics' curvature in the Riccati pass (`second_order`): the same optimum
    boxed2 = ddp.solve_ocp(tr.ocp, X0, U0, tr.data, tr.lb, tr.ub, ddp.DDPOptions(tol=1e-12, second_order=True),
                           compiled=C)
    assert boxed2.converged and any(h["second_order"] for h in boxed2.history)
    assert abs(boxed2.cost - c_box) <= 1e-6 * c_box


def test_acrobot_swing_up_with_terminal_constraints():
    """The shipped acrobot (shoulder upright at rest: terminal equalities through the
    augmented Lagrangian; the elbow's end at rest as the spline problem imposes it), by
    ``cs.solve(method="ddp")`` from the problem's own guess, no continuation."""
    p = cs.examples.acrobot(continuation=False)
    sol = cs.solve(p, method="ddp")
    assert sol.success, sol.message
    # the swing-up's tracked rollout is well-conditioned: it is the first iterate
    assert sol.info["first_iterate"] == "rollout"
    tr = sol.trajectory
    assert abs(tr["q"][-1, 0] - np.pi) < 1e-5 and abs(tr["v"][-1, 0]) < 1e-5
    assert abs(tr["q"][-1, 1]) < 1e-5 and abs(tr["v"][-1, 1]) < 1e-5
    # per-step torques reach a cheaper motion than the 16-control-point spline (154.3)
    assert sol.cost < 154.3
    # one compile per problem: the outer loop's multiplier and penalty updates (several
    # here) change values, not the compiled functions' input types
    C = ddp_problem.compiled_transcription(p)[1]
    assert max(h["outer"] for h in sol.history) >= 2
    # at least one iteration between outer updates (repeated at one iterate, an update
    # adds mu c to the multipliers again and raises the penalties tenfold again)
    assert all(b["outer"] - a["outer"] <= 1 for a, b in zip(sol.history, sol.history[1:]))
    for name in ("linearize", "backward", "_forward_jit", "project", "node_terms"):
        assert getattr(C, name)._cache_size() == 1, name
    assert tr["u"].shape == (p.n_steps + 1, 1)
    # `spline_guess`: the paper's control points fitted to the DDP path (a start for
    # polishing with SLSQP): closer to it than the problem's own guess, boundary
    # conditions kept (16 control points cannot follow per-step torques exactly)
    x = ddp_problem.spline_guess(p, sol)
    assert x.shape == (p.n_vars,)
    B0 = np.asarray(p.spline.basis(p.t)[0])
    path = lambda xx: B0 @ np.asarray(p.ctrl(jnp.asarray(xx), p.data()))[:, 0]
    rms = lambda xx: np.sqrt(np.mean((path(xx) - tr["q"][:, 1]) ** 2))
    assert rms(x) < 0.5 * rms(p.x0)
    assert abs(path(x)[0]) < 1e-12 and abs(path(x)[-1]) < 1e-12
    # the solver's feedback gains at the solution: replayed closed loop at the planning
    # step they reproduce the plan (zero correction), and from a start 0.02 rad off they
    # bring the swing-up to the upright end far closer than the open-loop torques
    K = tr["feedback"]
    assert K.shape == (p.n_steps + 1, 1, 4) and np.all(np.isfinite(K))
    Xp = np.concatenate([tr["q"], tr["v"]], axis=1)
    Q, V, Ua = ddp_problem.resimulate(p, tr["u"], tr["q"][0], tr["v"][0], factor=1, X=Xp, K=K)
    assert np.abs(Q - tr["q"]).max() < 1e-8 and np.abs(Ua - tr["u"]).max() < 1e-6
    q_off = tr["q"][0] + np.array([0.02, 0.0])
    end_err = lambda Q: abs(Q[-1, 0] - np.pi)
    Qo = ddp_problem.resimulate(p, tr["u"], q_off, tr["v"][0], factor=1)[0]
    Qc = ddp_problem.resimulate(p, tr["u"], q_off, tr["v"][0], factor=1, X=Xp, K=K)[0]
    assert end_err(Qc) < 0.1 * end_err(Qo), (end_err(Qc), end_err(Qo))


class _PeakElbow(constraints.Constraint):
    """A whole-trajectory row: the elbow's smooth maximum over the constraint grid at
    least 0.5 rad (``ddp = None``: it reads every sample at once)."""

    kind = "ineq"

    def values(self, ctx, end, samples):
        return jnp.atleast_1d(jax.nn.logsumexp(20.0 * samples["q"][:, 1]) / 20.0 - 0.5)


def test_merit_gradient_matches_finite_differences():
    """The linearization's merit gradient at a node (cost, node rows, end rows and a
    whole-trajectory row, with nonzero multipliers) equals central differences of the
    merit in that node's state and control."""
    p = _pendulum_problem("rk4")
    p.constraints = [constraints.TerminalState("shoulder", q=np.pi, v=0.0),
                     constraints.PathConstraint(lambda t, q, v, a, tau, prm: 4.0 - v * v), _PeakElbow()]
    for c in p.constraints:
        c.check(p)
    tr = ddp_problem.transcribe(p)
    o = tr.ocp
    assert o.n_gin == 1 and o.n_in > 0 and o.n_eq == 2
    C = ddp.compile_ocp(o)
    rng = np.random.default_rng(2)
    X = jnp.asarray(rng.normal(size=(N + 1, 4)) * 0.3).at[0].set(0.0)
    U = jnp.asarray(rng.normal(size=(N + 1, 2)))
    al = ddp.initial_multipliers(o, 3.0)
    al = dict(al, lam_eq=al["lam_eq"] + 0.7, lam_in=al["lam_in"] + 0.2, lam_gin=al["lam_gin"] + 0.5)
    lin = C.linearize(X, U, tr.data, al)
    h = 1e-6
    for k in (0, 37, N):
        for i in range(6):
            def merit(s):
                Xp, Up = (X.at[k, i].add(s), U) if i < 4 else (X, U.at[k, i - 4].add(s))
                return float(C.evaluate(Xp, Up, tr.data, al)["merit"])
            if k == 0 and i < 4:
                continue  # the start state is fixed
            fd = (merit(h) - merit(-h)) / (2 * h)
            # the gap of node k+1 moves with x_k too; its contribution is not part of the
            # merit's gradient (the Riccati pass carries it through the dynamics)
            g = float(lin["lx"][k, i]) if i < 4 else float(lin["lu"][k, i - 4])
            assert abs(fd - g) <= 1e-6 * (1 + abs(g)), (k, i, fd, g)


def test_outer_update_shares_a_path_rows_penalty_and_keeps_types():
    """The augmented Lagrangian's outer update: PHR multipliers (``max(0, lambda - mu
    c)`` for inequalities), a row that did not improve 4x gets 10x the penalty, a path
    row's penalty is the largest of its nodes' at every node, and the arrays keep their
    type (float64, not weakly typed: a change recompiles the solver's functions)."""
    n, n_eq, n_in = 4, 1, 2
    ocp = ddp.OCP(n_steps=n, nx=2, nu=1, n_eq=n_eq, n_in=n_in, integrate=None, difference=None, step=None,
                  point=None, cost=None, constraints=None, mask_eq=np.ones((n + 1, n_eq), bool),
                  mask_in=np.ones((n + 1, n_in), bool), x_bad=None)
    opt = ddp.DDPOptions()
    al = ddp.initial_multipliers(ocp, opt.mu0)
    ci = np.zeros((n + 1, n_in))
    ci[2, 0] = -0.1  # row 0 violated at node 2 only
    ev = dict(ce=jnp.zeros((n + 1, n_eq)), ci=jnp.asarray(ci), ve=np.zeros((n + 1, n_eq)),
              vi=np.maximum(0.0, -ci))
    prev = (np.zeros((n + 1, n_eq)), np.zeros((n + 1, n_in)))  # (violations at the last update)
    out = ddp._update_al(al, ev, ocp, opt, prev)
    np.testing.assert_allclose(out["lam_in"][:, 0], [0, 0, opt.mu0 * 0.1, 0, 0])
    np.testing.assert_allclose(out["mu_in"][:, 0], 10 * opt.mu0)  # every node of row 0
    np.testing.assert_allclose(out["mu_in"][:, 1], opt.mu0)  # row 1 is met everywhere
    np.testing.assert_allclose(out["mu_eq"], opt.mu0)
    for k, v in out.items():
        assert v.dtype == jnp.float64 and not v.weak_type, k
        assert al[k].shape == v.shape and not al[k].weak_type, k
