import jax

jax.config.update("jax_enable_x64", True)

import numpy as np
import jax.numpy as jnp
import pytest

from cstorm.contact import (
    ContactParams,
    beta,
    friction_force,
    gamma,
    gamma_over_s,
    normal_force,
    point_contact_force,
    smooth_nonneg,
)
from cstorm.errors import ContactParamError, ShapeError

PARAMS = ContactParams(stiffness=5e3, damping=100.0, d_on=0.01, d_off=0.0, friction=0.3, v_max=0.1, eps=0.01)
PULL = PARAMS.replace(pulling=True)
SHIFTED = ContactParams(stiffness=2e4, damping=30.0, d_on=0.0, d_off=-0.002, friction=0.8, v_max=0.05, eps=0.1)


_pcf = jax.jit(point_contact_force)
_jac_d_v = jax.jit(jax.vmap(jax.jacfwd(lambda d, n, v, p: point_contact_force(d, n, v, p)[0], argnums=(0, 2)),
                            in_axes=(0, 0, 0, None)))
_VG = {}


def _vg(f):
    """jit(vmap(f)) and jit(vmap(grad f)) over x for f(x, args), built once per f so that
    every check of the same f (with any args of the same structure) reuses one compile."""
    if f not in _VG:
        _VG[f] = (jax.jit(jax.vmap(f, in_axes=(0, None))), jax.jit(jax.vmap(jax.grad(f), in_axes=(0, None))))
    return _VG[f]


def c1_report(f, x0, width, args=()):
    """Numbers that show whether the scalar function ``x -> f(x, args)`` is C1 at ``x0``.

    Returns (value_gap, slope_gap, fd_error, G): with ``delta = 1e-7 width``,
    value_gap = |f(x0+delta) - f(x0-delta) - 2 delta f'(x0)| (0 up to O(delta^2) for C1,
    O(1) at a jump), slope_gap = |f'(x0+delta) - f'(x0-delta)| (O(delta) for C1, O(G) at a
    kink), fd_error = max over 41 points in [x0 - width, x0 + width] (x0 included) of
    |jax.grad - central difference|, G = max |f'| there (the scale).
    """
    fv, gv = _vg(f)
    delta = 1e-7 * width
    h = 1e-6 * width
    xs = x0 + width * np.linspace(-1.0, 1.0, 41)
    pts = np.concatenate([[x0 - delta, x0, x0 + delta], xs - h, xs + h])
    F = np.asarray(fv(pts, args))
    g = np.asarray(gv(np.concatenate([[x0 - delta, x0, x0 + delta], xs]), args))
    assert np.all(np.isfinite(F)) and np.all(np.isfinite(g))
    value_gap = abs(F[2] - F[0] - 2 * delta * g[1])
    slope_gap = abs(g[2] - g[0])
    fd = (F[3 + 41:] - F[3:3 + 41]) / (2 * h)
    fd_error = np.abs(fd - g[3:]).max()
    G = np.abs(g).max() + 1e-300
    return value_gap, slope_gap, fd_error, G


def assert_c1(f, x0, width, args=()):
    value_gap, slope_gap, fd_error, G = c1_report(f, x0, width, args)
    assert value_gap <= 1e-9 * G * width + 1e-13, (value_gap, G)
    assert slope_gap <= 1e-5 * G, (slope_gap, G)
    assert fd_error <= 1e-5 * G, (fd_error, G)


# scalar functions of one variable x, the rest in args (module level: compiled once each)
def f_nonneg(x, a):
    return smooth_nonneg(x, a)


def f_beta(x, a):
    return beta(x, a[0], a[1])


def f_gamma(x, v_max):
    return gamma(x, v_max)


def f_gamma_over_s(x, v_max):
    return gamma_over_s(x, v_max)


def f_normal_of_d(x, a):
    params, v_n = a
    return normal_force(x, v_n, params)


def f_normal_of_vn(x, a):
    params, d = a
    return normal_force(d, x, params)


def f_abs_normal_of_vn(x, a):
    params, d = a
    return jnp.abs(normal_force(d, x, params))


def f_force_along_slip(x, a):
    """w . f for v = base + x e (contact force component as a function of slip)."""
    params, d, n, e, base, w = a
    return jnp.dot(point_contact_force(d, n, base + x * e, params)[0], w)


# --------------------------------------------------------------------------- smoothing functions


def test_smooth_nonneg_values_and_stability():
    eps = 0.01
    x = jnp.array([-1e12, -1e3, -1.0, -1e-3, 0.0, 1e-3, 1.0, 1e3, 1e12])
    P = _vg(f_nonneg)[0](x, eps)
    assert np.all(np.isfinite(P)) and np.all(P > 0)
    assert float(smooth_nonneg(0.0, eps)) == pytest.approx(eps / 2, rel=1e-15)
    np.testing.assert_allclose(P, (x + np.sqrt(np.asarray(x) ** 2 + eps**2)) / 2 * (x > -1) + (x <= -1) * P, rtol=1e-12)
    assert np.all(P >= np.maximum(x, 0)) and np.all(P - np.maximum(x, 0) <= eps / 2 + 1e-15 * np.abs(x))
    # far negative: eps^2 / (4 |x|), not 0 from cancellation
    np.testing.assert_allclose(P[0], eps**2 / 4e12, rtol=1e-12)
    g = _vg(f_nonneg)[1](x, eps)
    assert np.all(np.isfinite(g)) and np.all((g >= 0) & (g <= 1))
    assert float(jax.grad(smooth_nonneg)(0.0, eps)) == pytest.approx(0.5)
    np.testing.assert_allclose(smooth_nonneg(x, eps, pulling=True), x)


def test_smooth_nonneg_is_c1():
    assert_c1(f_nonneg, 0.0, 0.05, 0.01)


def test_beta_values_and_c1():
    d_on, d_off = 0.01, -0.004
    d = jnp.array([1.0, 0.02, 0.01, 0.003, -0.004, -0.1])
    b = beta(d, d_on, d_off)
    np.testing.assert_array_equal(b[:3], 0.0)
    np.testing.assert_array_equal(b[4:], 1.0)
    s = (0.003 - d_on) / (d_off - d_on)
    assert float(b[3]) == pytest.approx(3 * s**2 - 2 * s**3, rel=1e-14)
    for x0 in (d_on, d_off):
        assert_c1(f_beta, x0, 0.002, (d_on, d_off))
    g = _vg(f_beta)[1](jnp.array([d_on, d_off]), (d_on, d_off))
    np.testing.assert_array_equal(g, 0.0)


def test_gamma_c1_and_corrected_slope_at_zero():
    v_max = 0.1
    # the draft's gamma'(0) = 1 is wrong: it is 1.5 / v_max
    assert float(jax.grad(gamma)(0.0, v_max)) == pytest.approx(1.5 / v_max, rel=1e-14)
    assert float(gamma_over_s(0.0, v_max)) == pytest.approx(1.5 / v_max, rel=1e-14)
    assert float(gamma(v_max, v_max)) == pytest.approx(1.0, rel=1e-15)
    s = jnp.array([0.0, 0.03, 0.1, 0.5, 10.0])
    np.testing.assert_allclose(gamma(s, v_max), [0.0, 1.5 * 0.3 - 0.5 * 0.027, 1.0, 1.0, 1.0], rtol=1e-14)
    assert_c1(f_gamma, v_max, 0.02, v_max)
    assert_c1(f_gamma_over_s, v_max, 0.02, v_max)
    # across zero (as a function of a signed slip s e): gamma(|s|)/|s| is even and smooth
    assert_c1(f_gamma_over_s, 0.0, 0.02, v_max)
    g0 = jax.grad(gamma_over_s)(0.0, v_max)
    assert np.isfinite(g0) and g0 == 0.0


# --------------------------------------------------------------------------- normal force


@pytest.mark.parametrize("params", [PARAMS, SHIFTED, PULL], ids=["default", "shifted", "pulling"])
def test_normal_force_c1_across_d_on_d_off(params):
    d_on, d_off = float(params.d_on), float(params.d_off)
    w = 0.2 * (d_on - d_off)
    for v_n in (-0.3, 0.0, 0.05):
        assert_c1(f_normal_of_d, d_on, w, (params, v_n))
        assert_c1(f_normal_of_d, d_off, w, (params, v_n))


@pytest.mark.parametrize("params", [PARAMS, SHIFTED], ids=["default", "shifted"])
def test_normal_force_c1_across_sign_change(params):
    """Where the spring-damper argument k (d_on - d) - c v_n crosses 0 (the separating
    robot would be pulled by the damper): N stays >= 0 and C1, and so does |N|."""
    k, c, d_on, d_off = (float(getattr(params, a)) for a in ("stiffness", "damping", "d_on", "d_off"))
    for d in (d_off - 0.001, 0.5 * (d_on + d_off)):
        v0 = k * (d_on - d) / c
        w = 5 * float(params.eps) / c
        assert_c1(f_normal_of_vn, v0, w, (params, d))
        assert_c1(f_abs_normal_of_vn, v0, w, (params, d))
        N = _vg(f_normal_of_vn)[0](v0 + w * jnp.linspace(-10, 10, 101), (params, d))
        assert np.all(N >= 0)


def test_pulling_option_has_the_kink_the_check_detects():
    """Sanity check of the C1 check: with P(x) = x, |N| has a kink where N changes sign."""
    k, c, d_on = 5e3, 100.0, 0.01
    d = -0.001
    v0 = k * (d_on - d) / c
    _, slope_gap, _, G = c1_report(f_abs_normal_of_vn, v0, 0.01, (PULL, d))
    assert slope_gap > 0.5 * G
    assert float(normal_force(d, v0 + 0.1, PULL)) < 0  # the draft's damper pulls


def test_force_exactly_zero_beyond_d_on():
    rng = np.random.default_rng(0)
    for params in (PARAMS, SHIFTED, PULL):
        d_on = float(params.d_on)
        d = jnp.asarray(np.concatenate([[d_on, d_on + 1e-15], d_on + rng.uniform(0, 1, 20)]))
        n = rng.normal(size=(d.shape[0], 3))
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        v = rng.normal(size=(d.shape[0], 3)) * 5
        f, N, f_t = _pcf(d, jnp.asarray(n), jnp.asarray(v), params)
        np.testing.assert_array_equal(f, 0.0)
        np.testing.assert_array_equal(N, 0.0)
        np.testing.assert_array_equal(f_t, 0.0)
        J = _jac_d_v(d, jnp.asarray(n), jnp.asarray(v), params)
        for Jk in J:
            np.testing.assert_array_equal(Jk, 0.0)


# --------------------------------------------------------------------------- friction


def _random_contact(rng, m):
    n = rng.normal(size=(m, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    v = rng.normal(size=(m, 3)) * rng.uniform(0.001, 1.0, size=(m, 1))
    d = rng.uniform(-0.002, 0.009, size=m)
    return jnp.asarray(d), jnp.asarray(n), jnp.asarray(v)


def test_friction_opposes_slip_and_saturates():
    rng = np.random.default_rng(1)
    d, n, v = _random_contact(rng, 400)
    for params in (PARAMS, SHIFTED, PULL):
        f, N, f_t = _pcf(d, n, v, params)
        v_t = v - jnp.sum(v * n, axis=1, keepdims=True) * n
        s = np.linalg.norm(v_t, axis=1)
        mu, v_max = float(params.friction), float(params.v_max)
        np.testing.assert_allclose(jnp.sum(f_t * n, axis=1), 0.0, atol=1e-10 * (1 + np.abs(N).max()))
        np.testing.assert_allclose(f, N[:, None] * n + f_t, rtol=1e-14, atol=1e-12)
        assert np.all(jnp.sum(f_t * v_t, axis=1) <= 0)
        # antiparallel to the slip
        np.testing.assert_allclose(jnp.cross(f_t, v_t), 0.0, atol=1e-9 * (1 + np.abs(N).max()))
        mag = np.linalg.norm(f_t, axis=1)
        above = s >= v_max
        assert above.sum() > 20 and (~above).sum() > 20
        np.testing.assert_allclose(mag[above], mu * np.abs(N[above]), rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(mag[~above], mu * np.abs(N[~above]) * (1.5 * s[~above] / v_max - 0.5 * (s[~above] / v_max) ** 3),
                                   rtol=1e-10, atol=1e-14)
        assert np.all(mag <= mu * np.abs(N) * (1 + 1e-12) + 1e-14)
        if not params.pulling:
            assert np.all(N >= 0)


def test_friction_c1_across_v_max_and_zero_slip():
    n = jnp.array([0.0, 0.0, 1.0])
    e = jnp.array([0.6, 0.8, 0.0])
    for params in (PARAMS, SHIFTED):
        v_max = float(params.v_max)
        d = 0.5 * float(params.d_on + params.d_off)
        for w in (jnp.array([1.0, 0.0, 0.0]), jnp.array([0.0, 1.0, 0.0])):  # two force components
            args = (params, d, n, e, jnp.array([0.0, 0.0, -0.05]), w)
            for x0 in (v_max, -v_max, 0.0):
                assert_c1(f_force_along_slip, x0, 0.2 * v_max, args)


def test_gradients_finite_at_zero_slip_and_zero_velocity():
    params = PARAMS
    n = jnp.array([0.0, 0.6, 0.8])
    d = 0.004
    fun = lambda dd, nn, vv: point_contact_force(dd, nn, vv, params)[0]
    jacs = [jax.jit(jac(fun, argnums=(0, 1, 2))) for jac in (jax.jacfwd, jax.jacrev)]
    for v in (jnp.zeros(3), 0.2 * n, -0.3 * n):  # zero velocity; zero slip, moving normally
        for jac in jacs:
            Jd, Jn, Jv = jac(d, n, v)
            assert all(np.all(np.isfinite(J)) for J in (Jd, Jn, Jv))
        # exact Jacobian w.r.t. v at zero slip: normal damper plus viscous friction
        v_n = float(v @ n)
        x = float(params.stiffness) * (float(params.d_on) - d) - float(params.damping) * v_n
        b = float(beta(d, params.d_on, params.d_off))
        N = b * float(smooth_nonneg(x, params.eps))
        dN_dvn = -b * float(params.damping) * 0.5 * (1 + x / np.sqrt(x * x + float(params.eps) ** 2))
        nn = np.outer(n, n)
        expected = dN_dvn * nn - float(params.friction) * N * 1.5 / float(params.v_max) * (np.eye(3) - nn)
        np.testing.assert_allclose(Jv, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())
    # second derivatives too (friction depends on |v_t|^2 below v_max, no norm taken)
    H = jax.jit(jax.hessian(lambda vv: fun(d, n, vv)[0]))(jnp.zeros(3))
    assert np.all(np.isfinite(H))
    jv = jax.jit(jax.jacfwd(lambda vv: fun(d, n, vv)[0]))
    h = 1e-6
    H_fd = np.stack([(jv(h * ei) - jv(-h * ei)) / (2 * h) for ei in np.eye(3)], axis=1)
    np.testing.assert_allclose(H, H_fd, atol=1e-6 * (1 + np.abs(H).max()))


def test_point_force_jacobian_matches_central_differences():
    rng = np.random.default_rng(2)
    d, n, v = _random_contact(rng, 6)
    fun = jax.jit(lambda x, nn: point_contact_force(x[0], nn, x[1:], SHIFTED.replace(d_on=0.01, d_off=-0.002))[0])
    jf = jax.jit(jax.jacfwd(fun))
    for i in range(d.shape[0]):
        x = jnp.concatenate([d[i:i + 1], v[i]])
        J = jf(x, n[i])
        scale = 1e-6 * np.array([0.01, 1.0, 1.0, 1.0])
        J_fd = np.stack([(fun(x + s * e, n[i]) - fun(x - s * e, n[i])) / (2 * s) for s, e in zip(scale, np.eye(4))], axis=1)
        np.testing.assert_allclose(J, J_fd, rtol=1e-6, atol=1e-6 * np.abs(J).max())


def test_friction_force_direct_call_shapes_and_abs():
    v_t = jnp.array([[0.3, 0.0, 0.0], [0.0, 0.01, 0.0], [0.0, 0.0, 0.0]])
    N = jnp.array([10.0, -10.0, 5.0])
    f_t = friction_force(N, v_t, PARAMS)
    assert f_t.shape == (3, 3)
    np.testing.assert_allclose(f_t[0], [-3.0, 0.0, 0.0], rtol=1e-14)
    np.testing.assert_allclose(f_t[1], [0.0, -0.3 * 10 * (1.5 * 0.1 - 0.5 * 0.001), 0.0], rtol=1e-12)
    np.testing.assert_array_equal(f_t[2], 0.0)


# --------------------------------------------------------------------------- parameters


def test_contact_params_is_a_pytree_with_static_flag():
    leaves, tree = jax.tree_util.tree_flatten(PARAMS)
    assert len(leaves) == 7 and all(l.dtype == jnp.float64 for l in leaves)
    assert jax.tree_util.tree_structure(PULL) != tree
    assert PARAMS.pulling is False and PULL.pulling is True
    assert float(ContactParams(1.0, 0.0, 0.0, -1.0).friction) == 0.3

    d, n, v = 0.003, jnp.array([0.0, 0.0, 1.0]), jnp.array([0.2, 0.0, -0.1])

    @jax.jit
    def fz(p):
        return point_contact_force(d, n, v, p)[0][0]

    g = jax.grad(fz)(PARAMS)
    assert isinstance(g, ContactParams)
    for name in ("stiffness", "damping", "d_on", "friction", "v_max", "eps"):
        e = 1e-6 * abs(float(getattr(PARAMS, name)))
        fd = (fz(PARAMS.replace(**{name: getattr(PARAMS, name) + e})) - fz(PARAMS.replace(**{name: getattr(PARAMS, name) - e}))) / (2 * e)
        assert abs(float(getattr(g, name)) - fd) <= 1e-6 * (1 + abs(fd)), name


def test_contact_params_per_pair_arrays_broadcast():
    p = ContactParams(stiffness=jnp.array([5e3, 1e4]), damping=100.0, d_on=0.01, d_off=jnp.array([0.0, -0.001]),
                      friction=jnp.array([0.3, 0.8]))
    d = jnp.array([0.002, 0.002])
    n = jnp.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    v = jnp.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    f, N, f_t = _pcf(d, n, v, p)
    for i in range(2):
        pi = ContactParams(stiffness=p.stiffness[i], damping=100.0, d_on=0.01, d_off=p.d_off[i], friction=p.friction[i])
        fi, Ni, _ = _pcf(d[i], n[i], v[i], pi)
        np.testing.assert_allclose(f[i], fi, rtol=1e-14)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(stiffness=-1.0), "stiffness"),
        (dict(damping=-0.1), "damping"),
        (dict(d_on=0.0, d_off=0.0), "d_off"),
        (dict(d_on=0.0, d_off=0.01), "d_off"),
        (dict(v_max=0.0), "v_max"),
        (dict(v_max=-1.0), "v_max"),
        (dict(friction=-0.2), "friction"),
        (dict(eps=0.0), "eps"),
        (dict(eps=-1e-3), "eps"),
        (dict(stiffness=float("nan")), "stiffness"),
        (dict(damping=jnp.array([1.0, -1.0])), "damping"),
        (dict(pulling="no"), "pulling"),
    ],
)
def test_contact_params_validation(kwargs, name):
    base = dict(stiffness=5e3, damping=100.0, d_on=0.01, d_off=0.0)
    base.update(kwargs)
    with pytest.raises(ContactParamError, match=name) as exc:
        ContactParams(**base)
    assert isinstance(exc.value, ShapeError)


def test_contact_params_not_validated_under_tracing():
    @jax.jit
    def build(k):
        return normal_force(0.0, 0.0, ContactParams(k, 100.0, 0.01, 0.0))

    assert float(build(5e3)) == pytest.approx(float(normal_force(0.0, 0.0, PARAMS)))
