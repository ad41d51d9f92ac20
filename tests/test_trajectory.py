import jax

jax.config.update("jax_enable_x64", True)

import itertools

import numpy as np
import jax.numpy as jnp
import pytest

from cstorm.errors import InputError
from cstorm.trajectory import QuinticBSpline

T = 2.0


def cox_de_boor(knots, p, i, x):
    """Independent oracle: the i-th B-spline of degree p at a scalar x (right-continuous,
    with the last non-empty interval closed at the right end)."""
    if p == 0:
        lo, hi = knots[i], knots[i + 1]
        if lo < hi and (lo <= x < hi or (x == knots[-1] and hi == knots[-1])):
            return 1.0
        return 0.0
    out = 0.0
    if knots[i + p] > knots[i]:
        out += (x - knots[i]) / (knots[i + p] - knots[i]) * cox_de_boor(knots, p - 1, i, x)
    if knots[i + p + 1] > knots[i + 1]:
        out += (knots[i + p + 1] - x) / (knots[i + p + 1] - knots[i + 1]) * cox_de_boor(knots, p - 1, i + 1, x)
    return out


@pytest.fixture(scope="module")
def spl():
    return QuinticBSpline(9, T)


def test_knots_and_basis_match_cox_de_boor():
    for n in (6, 7, 9):
        s = QuinticBSpline(n, T)
        assert s.knots.shape == (n + 6,) and s.n_spans == n - 5
        np.testing.assert_allclose(s.knots[:6], 0.0)
        np.testing.assert_allclose(s.knots[-6:], T)
        t = np.linspace(0.0, T, 37)
        B0 = s.basis_matrix(t)
        ref = np.array([[cox_de_boor(s.knots, 5, i, x) for i in range(n)] for x in t])
        np.testing.assert_allclose(B0, ref, atol=1e-13)


def test_partition_of_unity_and_nonnegativity():
    s = QuinticBSpline(11, T)
    t = np.random.default_rng(0).uniform(0.0, T, 300)
    B0, B1, B2 = s.basis(t)
    np.testing.assert_allclose(B0.sum(axis=1), 1.0, atol=1e-13)
    np.testing.assert_allclose(B1.sum(axis=1), 0.0, atol=1e-11)
    np.testing.assert_allclose(B2.sum(axis=1), 0.0, atol=1e-9)
    assert B0.min() >= -1e-15
    # local support: at most 6 non-zero basis functions at any time
    assert (np.abs(B0) > 1e-15).sum(axis=1).max() <= 6


@pytest.mark.parametrize("n", [6, 7, 13])
def test_fit_reproduces_quintic_polynomials(n):
    s = QuinticBSpline(n, T)
    rng = np.random.default_rng(n)
    coeffs = rng.normal(size=(6, 2))  # two joints, degree-5 polynomials
    t = np.linspace(0.0, T, 4 * n)
    P = np.polynomial.polynomial
    y = np.stack([P.polyval(t, coeffs[:, j]) for j in range(2)], axis=1)
    ctrl = s.fit(t, y)
    tt = np.random.default_rng(1).uniform(0.0, T, 50)
    B0, B1, B2 = s.basis(tt)
    for B, der in ((B0, 0), (B1, 1), (B2, 2)):
        exact = np.stack([P.polyval(tt, P.polyder(coeffs[:, j], der)) for j in range(2)], axis=1)
        np.testing.assert_allclose(B @ ctrl, exact, atol=1e-9 * (1 + np.abs(exact).max()))
    # every lower degree too
    for deg in range(6):
        c1 = s.fit(t, t**deg)
        np.testing.assert_allclose(s.basis_matrix(tt) @ c1, tt**deg, atol=1e-10)


def _f(t):
    return np.sin(3 * t) + np.exp(t / 2), 3 * np.cos(3 * t) + 0.5 * np.exp(t / 2), -9 * np.sin(3 * t) + 0.25 * np.exp(t / 2)


def test_fit_convergence_order():
    """Least-squares fit of a smooth function: max error ~ h^6 (value), h^5, h^4 (derivs)."""
    t = np.linspace(0.0, T, 4001)
    f = _f(t)
    errs = []
    for n_spans in (8, 16, 32, 64):
        s = QuinticBSpline(n_spans + 5, T)
        ctrl = s.fit(t, f[0])
        errs.append([np.abs(B @ ctrl - fk).max() for B, fk in zip(s.basis(t), f)])
    errs = np.array(errs)
    orders = np.log2(errs[:-1] / errs[1:])  # rows: successive halvings of h
    # measured (h = T/16 -> T/32 -> T/64): value 6.09, 6.02; first 5.50, 5.34; second 4.55, 4.37
    assert np.all(np.abs(orders[-2:, 0] - 6.0) < 0.3), orders
    assert np.all(orders[-2:, 1] > 4.8), orders
    assert np.all(orders[-2:, 2] > 3.8), orders
    assert errs[-1, 0] < 1e-10


def test_derivative_consistency_finite_differences(spl):
    t = np.linspace(0.01, T - 0.01, 57)
    dt = 1e-6
    Bp, Bm = spl.basis_matrix(t + dt), spl.basis_matrix(t - dt)
    B1p, B1m = spl.basis_matrix(t + dt, 1), spl.basis_matrix(t - dt, 1)
    B1, B2 = spl.basis_matrix(t, 1), spl.basis_matrix(t, 2)
    np.testing.assert_allclose((Bp - Bm) / (2 * dt), B1, atol=1e-7 * np.abs(B1).max())
    np.testing.assert_allclose((B1p - B1m) / (2 * dt), B2, atol=1e-7 * np.abs(B2).max())


def test_second_derivative_continuous_across_knots(spl):
    """C4 at simple knots: in particular value, velocity and acceleration are continuous."""
    knots = np.unique(spl.knots)[1:-1]
    d = 1e-9
    for nu in range(3):
        left, right = spl.basis_matrix(knots - d, nu), spl.basis_matrix(knots + d, nu)
        np.testing.assert_allclose(left, right, atol=1e-6 * (1 + np.abs(left).max()))


def test_evaluate_matches_basis(spl):
    rng = np.random.default_rng(3)
    ctrl1 = rng.normal(size=spl.n_ctrl)
    ctrl3 = rng.normal(size=(spl.n_ctrl, 3))
    t = np.concatenate([[0.0, T], spl.knots[6:-6], rng.uniform(0, T, 40)])
    B = spl.basis(t)
    ev_all = jax.jit(spl.evaluate_all)
    ev = jax.jit(spl.evaluate, static_argnames="nu")
    for ctrl in (ctrl1, ctrl3):
        for nu, (val, Bk) in enumerate(zip(ev_all(ctrl, t), B)):
            assert val.shape == (t.size,) + ctrl.shape[1:]
            np.testing.assert_allclose(val, Bk @ ctrl, atol=1e-11 * (1 + np.abs(Bk).max()))
        np.testing.assert_allclose(ev(ctrl, t, nu=2), B[2] @ ctrl, atol=1e-11 * (1 + np.abs(B[2]).max()))
    # scalar and 2-D time arrays
    assert ev(ctrl3, 0.5).shape == (3,)
    assert ev(ctrl1, t[:40].reshape(5, 8)).shape == (5, 8)


def test_boundary_values(spl):
    rng = np.random.default_rng(4)
    ctrl = rng.normal(size=(spl.n_ctrl, 2))
    ends = np.array([0.0, T])
    q = spl.basis_matrix(ends) @ ctrl
    np.testing.assert_allclose(q[0], ctrl[0], atol=1e-14)
    np.testing.assert_allclose(q[1], ctrl[-1], atol=1e-13)
    np.testing.assert_allclose(spl.evaluate(ctrl, ends), q, atol=1e-13)
    # first three (last three) equal => zero velocity and acceleration at that end
    c = ctrl.copy()
    c[1:3] = c[0]
    c[-3:-1] = c[-1]
    q, v, a = (B @ c for B in spl.basis(ends))
    np.testing.assert_allclose(v, 0.0, atol=1e-12)
    np.testing.assert_allclose(a, 0.0, atol=1e-10)


def test_expand_rest_and_reduce(spl):
    n = spl.n_ctrl
    q0, q1 = np.array([0.1, -0.2]), np.array([1.0, 0.5])
    bc = dict(q0=q0, q1=q1, rest_start=True, rest_end=True)
    assert spl.n_free(**bc) == n - 6
    assert spl.fixed_indices(**bc) == (0, 1, 2, n - 3, n - 2, n - 1)
    free = np.random.default_rng(5).normal(size=(n - 6, 2))
    ctrl = spl.expand(free, **bc)
    np.testing.assert_allclose(ctrl[:3], np.broadcast_to(q0, (3, 2)))
    np.testing.assert_allclose(ctrl[-3:], np.broadcast_to(q1, (3, 2)))
    q, v, a = (B @ np.asarray(ctrl) for B in spl.basis(np.array([0.0, T])))
    np.testing.assert_allclose(q, np.stack([q0, q1]), atol=1e-13)
    np.testing.assert_allclose(v, 0.0, atol=1e-12)
    np.testing.assert_allclose(a, 0.0, atol=1e-10)
    np.testing.assert_allclose(spl.reduce(ctrl, **bc), free)
    # rest with a free boundary position: first three equal to a free parameter
    bc2 = dict(rest_start=True)
    assert spl.n_free(**bc2) == n - 2
    c2 = spl.expand(np.arange(n - 2.0), **bc2)
    np.testing.assert_allclose(c2[:3], 0.0)
    np.testing.assert_allclose(c2[3:], np.arange(1.0, n - 2.0))


@pytest.mark.parametrize("n", [6, 7, 10])
def test_expand_general_boundary_values(n):
    s = QuinticBSpline(n, T)
    rng = np.random.default_rng(n)
    vals = dict(q0=0.3, v0=-1.2, a0=4.0, q1=-0.7, v1=0.25, a1=-3.0)
    B = s.basis(np.array([0.0, T]))
    for mask in itertools.product([False, True], repeat=6):
        bc = {k: v for (k, v), on in zip(vals.items(), mask) if on}
        nf = s.n_free(**bc)
        assert nf == n - sum(mask)
        ctrl = np.asarray(s.expand(rng.normal(size=nf), **bc))
        res = [Bk @ ctrl for Bk in B]
        for k, v in bc.items():
            nu, end = "qva".index(k[0]), int(k[1])
            scale = 1.0 / s.h**nu
            assert abs(float(res[nu][end]) - v) < 1e-11 * scale, (mask, k)


def test_expand_rejects_conflicts(spl):
    with pytest.raises(InputError, match="v0"):
        spl.expand(np.zeros(spl.n_ctrl - 2), v0=1.0, rest_start=True)
    with pytest.raises(InputError, match="free must have shape"):
        spl.expand(np.zeros(3), q0=0.0)
    with pytest.raises(InputError, match="unknown"):
        spl.n_free(qstart=1.0)


def test_fit_with_boundary_conditions(spl):
    t = np.linspace(0.0, T, 200)
    y = np.stack([np.sin(t), np.cos(2 * t)], axis=1)
    bc = dict(q0=[0.0, 1.0], q1=[0.5, -0.5], rest_start=True, rest_end=True)
    ctrl = spl.fit(t, y, **bc)
    q, v, a = (B @ ctrl for B in spl.basis(np.array([0.0, T])))
    np.testing.assert_allclose(q, [[0.0, 1.0], [0.5, -0.5]], atol=1e-12)
    np.testing.assert_allclose(v, 0.0, atol=1e-10)
    np.testing.assert_allclose(a, 0.0, atol=1e-9)
    np.testing.assert_allclose(spl.expand(spl.reduce(ctrl, **bc), **bc), ctrl, atol=1e-12)


def test_fit_rank_deficient_raises(spl):
    with pytest.raises(InputError, match="undetermined"):
        spl.fit(np.linspace(0.0, 0.3, 50), np.zeros(50))


def test_input_validation():
    with pytest.raises(InputError, match="n_ctrl"):
        QuinticBSpline(5, 1.0)
    with pytest.raises(InputError, match="t_final"):
        QuinticBSpline(8, 0.0)
    with pytest.raises(InputError, match="t_final"):
        QuinticBSpline(8, float("nan"))
    s = QuinticBSpline(8, 1.0)
    with pytest.raises(InputError, match=r"\[0, t_final"):
        s.basis(np.array([0.0, 1.5]))
    with pytest.raises(InputError, match="ctrl"):
        s.evaluate(np.zeros(7), 0.5)
    assert s == QuinticBSpline(8, 1.0) and hash(s) == hash(QuinticBSpline(8, 1.0))
    with pytest.raises(AttributeError):
        s.t_final = 2.0


def test_jit_grad_vmap(spl):
    n = spl.n_ctrl
    t_grid = np.linspace(0.0, T, 101)
    B0, B1, B2 = (jnp.asarray(B) for B in spl.basis(t_grid))
    bc = dict(q0=jnp.array([0.0, 0.2]), q1=jnp.array([1.0, -1.0]), rest_start=True, rest_end=True)

    def cost(free, q1):
        ctrl = spl.expand(free, **{**bc, "q1": q1})
        q, a = B0 @ ctrl, B2 @ ctrl
        return jnp.sum(a**2) * 1e-3 + jnp.sum(jnp.sin(q))

    free = jnp.asarray(np.random.default_rng(6).normal(size=(n - 6, 2)))
    q1 = bc["q1"]
    g_free, g_q1 = jax.jit(jax.grad(cost, argnums=(0, 1)))(free, q1)
    cost = jax.jit(cost)
    assert np.all(np.isfinite(g_free)) and np.all(np.isfinite(g_q1))
    # central differences along random directions
    rng = np.random.default_rng(7)
    for _ in range(3):
        dfree, dq1 = rng.normal(size=free.shape), rng.normal(size=2)
        e = 1e-6
        fd = (cost(free + e * dfree, q1 + e * dq1) - cost(free - e * dfree, q1 - e * dq1)) / (2 * e)
        an = jnp.sum(g_free * dfree) + jnp.sum(g_q1 * dq1)
        assert abs(fd - an) < 1e-7 * (1 + abs(an))

    # d/dt of evaluate equals the next derivative, under jit and vmap
    ctrl = spl.expand(free, **bc)
    dq, dv = jax.jit(jax.vmap(lambda s: (jax.grad(lambda s: spl.evaluate(ctrl[:, 0], s))(s),
                                         jax.grad(lambda s: spl.evaluate(ctrl[:, 1], s, 1))(s))))(
        jnp.asarray(t_grid[1:-1]))
    np.testing.assert_allclose(dq, (B1 @ ctrl)[1:-1, 0], rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(dv, (B2 @ ctrl)[1:-1, 1], rtol=1e-9, atol=1e-9)
    # vmap over a batch of control-point sets
    batch = jnp.stack([ctrl, 2 * ctrl, -ctrl])
    out = jax.jit(jax.vmap(lambda c: spl.evaluate(c, jnp.asarray(t_grid))))(batch)
    np.testing.assert_allclose(out[1], 2 * (B0 @ ctrl), atol=1e-12)
