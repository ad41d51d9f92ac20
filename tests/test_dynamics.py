"""Identities of the recursive dynamics on seeded random trees, finite-difference checks of
their derivatives on the manifold, and argument validation.

Each topology is compiled once (all checks in one jitted function) and evaluated for many
random parameter draws: parameters are pytree leaves of the model, so draws reuse the
compiled code.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import cstorm as cs
from helpers import manifold_fd, random_state, random_tree

TOPOLOGIES = [(11, 6), (12, 6), (13, 5), (14, 6)]  # (topology seed, n_bodies); depth <= 5
PARAM_DRAWS = 8  # 4 x 8 = 32 seeded random trees


def _masks(model, rng):
    """A random active mask with whole joints active or passive plus, if there is a
    multi-DoF joint, a mask that splits it."""
    act = []
    for j in model.joints:
        act += [bool(rng.integers(0, 2))] * j.nv
    return tuple(act)


def _identities(model, q, v, a, fext, active):
    tau = cs.rnea(model, q, v, a, fext)
    M = cs.mass_matrix(model, q)
    h = cs.bias_forces(model, q, v, fext)
    act = np.array(active)
    ia, ip = np.nonzero(act)[0], np.nonzero(~act)[0]
    ta, ap = cs.hybrid_dynamics(model, q, v, a[ia], tau[ip], active, fext)
    all_act = cs.hybrid_dynamics(model, q, v, a, jnp.zeros(0), (True,) * model.nv, fext)[0]
    aba = cs.aba(model, q, v, tau, fext)  # = hybrid dynamics with every DoF passive
    # d rnea / d a = M: rnea is affine in a, so its columns are rnea(e_k) - rnea(0)
    eye = jnp.eye(model.nv)
    drnea_da = jax.vmap(lambda e: cs.rnea(model, q, v, e, fext))(eye).T - h[:, None]
    # brute-force partitioned solve of M a + h = tau for the same split
    a_p_bf = jnp.linalg.solve(M[np.ix_(ip, ip)], tau[ip] - h[ip] - M[np.ix_(ip, ia)] @ a[ia])
    tau_a_bf = M[np.ix_(ia, ip)] @ a_p_bf + M[np.ix_(ia, ia)] @ a[ia] + h[ia]
    L = jnp.linalg.cholesky(M)
    return dict(
        aba_rnea=aba - a,
        M_from_rnea=drnea_da - M,
        M_asym=M - M.T,
        M_not_pd=jnp.where(jnp.all(jnp.isfinite(L)), 0.0, 1.0),
        rnea_vs_M=M @ a + h - tau,
        hybrid_tau=ta - tau[ia],
        hybrid_a=ap - a[ip],
        hybrid_bf_tau=ta - tau_a_bf,
        hybrid_bf_a=ap - a_p_bf,
        all_active=all_act - tau,
        scale=jnp.max(jnp.abs(tau)) + jnp.max(jnp.abs(M)) + 1.0,
    )


_identities_jit = jax.jit(_identities, static_argnums=(5,))


@pytest.mark.parametrize("topo,nb", TOPOLOGIES)
def test_identities_on_random_trees(topo, nb):
    rng = np.random.default_rng(topo)
    model0 = random_tree(topo, 0, n_bodies=nb)
    active = _masks(model0, rng)
    assert any(isinstance(j, cs.Free) for j in model0.joints)
    for draw in range(PARAM_DRAWS):
        model = random_tree(topo, draw, n_bodies=nb)
        assert model.parents == model0.parents and model.joints == model0.joints  # same topology
        q, v, a = random_state(model, rng)
        # external wrenches on even draws, none (zeros) on odd ones: one compiled function
        fext = jnp.asarray(rng.normal(size=(model.n_bodies, 6))) * (draw % 2 == 0)
        r = {k: np.asarray(x) for k, x in _identities_jit(model, q, v, a, fext, active).items()}
        s = float(r.pop("scale"))
        if True:
            for k, x in r.items():
                assert np.abs(x).max() <= 1e-10 * s, (k, draw, np.abs(x).max())


def _rk4_rollout(model, q0, v0, dt, n):
    """Torque-free RK4 on the manifold (stages in the tangent space at the step start)."""
    z = jnp.zeros(model.nv)

    def f(q, v):
        return v, cs.aba(model, q, v, z)

    def step(state, _):
        q, v = state
        k1q, k1v = f(q, v)
        k2q, k2v = f(cs.integrate(model, q, k1q, dt / 2), v + dt / 2 * k1v)
        k3q, k3v = f(cs.integrate(model, q, k2q, dt / 2), v + dt / 2 * k2v)
        k4q, k4v = f(cs.integrate(model, q, k3q, dt), v + dt * k3v)
        qn = cs.integrate(model, q, (k1q + 2 * k2q + 2 * k3q + k4q) / 6, dt)
        vn = v + dt / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
        return (cs.normalize(model, qn), vn), None

    (q, v), _ = jax.lax.scan(step, (q0, v0), None, length=n)
    return q, v


@jax.jit
def _energy_drift(model, q0, v0):
    E = lambda q, v: cs.kinetic_energy(model, q, v) + cs.potential_energy(model, q)
    q1, v1 = _rk4_rollout(model, q0, v0, 1e-3, 500)
    return E(q0, v0), E(q1, v1), cs.kinetic_energy(model, q0, v0)


def test_energy_conserved_by_torque_free_rollout():
    # fixed-base tree (revolute/prismatic/ball): frozen-frame RK4 is 4th order there
    rng = np.random.default_rng(5)
    for draw in range(3):
        model = random_tree(21, draw, n_bodies=4, floating=False, joint_types=("revolute", "prismatic", "revolute"))
        q, v, _ = random_state(model, rng)
        E0, E1, T0 = (float(x) for x in _energy_drift(model, q, 0.5 * v))
        assert abs(E1 - E0) <= 1e-8 * max(1.0, T0), (E0, E1)


def test_free_body_energy_and_momentum():
    """A single free rigid body tumbling without gravity: energy is conserved."""
    model = random_tree(31, 0, n_bodies=1)
    model = model.replace(gravity=jnp.zeros(3))
    rng = np.random.default_rng(0)
    q, v, _ = random_state(model, rng)
    E0, E1, T0 = (float(x) for x in _energy_drift(model, q, v))
    assert abs(E1 - E0) <= 1e-6 * T0


def _all_outputs(model, q, v, a, tau, fext, active, b, point):
    act = np.array(active)
    ta, ap = cs.hybrid_dynamics(model, q, v, a[act], tau[~act], active, fext)
    return jnp.concatenate([
        cs.rnea(model, q, v, a, fext), cs.aba(model, q, v, tau, fext), cs.mass_matrix(model, q).ravel(),
        cs.bias_forces(model, q, v, fext), ta, ap, cs.forward_kinematics(model, q).ravel(),
        cs.point_jacobian(model, q, b, point).ravel(), jnp.atleast_1d(cs.kinetic_energy(model, q, v)),
        jnp.atleast_1d(cs.potential_energy(model, q)), cs.center_of_mass(model, q), cs.body_velocities(model, q, v).ravel(),
    ])


@pytest.fixture(scope="module")
def fd_setup():
    model = random_tree(43, 0, n_bodies=4, joint_types=("ball", "prismatic", "revolute"))
    assert {type(j) for j in model.joints} == {cs.Free, cs.Ball, cs.Prismatic, cs.Revolute}
    rng = np.random.default_rng(1)
    active = _masks(model, rng)

    def f_tangent(dq, q, v, a, tau, fext):
        return _all_outputs(model, cs.integrate(model, q, dq), v, a, tau, fext, active, model.n_bodies - 1,
                            jnp.array([0.1, -0.2, 0.3]))

    jac = jax.jit(jax.jacfwd(f_tangent, argnums=(0, 2, 3, 4, 5)))
    val = jax.jit(f_tangent)
    return model, rng, jac, val


@pytest.mark.parametrize("where", ["random", "zero_angle"])
def test_derivatives_match_manifold_finite_differences(fd_setup, where):
    model, rng, jac, val = fd_setup
    q, v, a = random_state(model, rng)
    if where == "zero_angle":
        q = jnp.asarray(model.neutral())  # zero angles, identity quaternions
        v = jnp.zeros(model.nv)  # and zero velocity
    tau = jnp.asarray(rng.normal(size=model.nv))
    fext = jnp.asarray(rng.normal(size=(model.n_bodies, 6)))
    z = jnp.zeros(model.nv)
    Jq, Jv, Ja, Jtau, Jf = (np.asarray(x) for x in jac(z, q, v, a, tau, fext))
    assert all(np.all(np.isfinite(x)) for x in (Jq, Jv, Ja, Jtau, Jf))
    eps = 1e-6
    fd_q = manifold_fd(lambda qq: val(cs.difference(model, q, qq), q, v, a, tau, fext), model, q, eps)
    scale = np.abs(Jq).max() + 1.0
    assert np.abs(fd_q - Jq).max() <= 1e-6 * scale
    for J, arg_i in ((Jv, 1), (Ja, 2), (Jtau, 3)):
        args = [z, q, v, a, tau, fext]
        cols = []
        for k in range(model.nv):
            e = jnp.zeros(model.nv).at[k].set(eps)
            ap = list(args); ap[arg_i + 1] = args[arg_i + 1] + e
            am = list(args); am[arg_i + 1] = args[arg_i + 1] - e
            cols.append((np.asarray(val(*ap)) - np.asarray(val(*am))) / (2 * eps))
        assert np.abs(np.stack(cols, -1) - J).max() <= 1e-6 * (np.abs(J).max() + 1.0)


def test_manifold_integrate_difference_roundtrip():
    model = random_tree(41, 1, n_bodies=6, joint_types=("revolute", "prismatic", "ball", "free"))
    rng = np.random.default_rng(3)
    q, v, _ = random_state(model, rng)
    q1 = cs.integrate(model, q, v, 0.3)
    np.testing.assert_allclose(cs.difference(model, q, q1), 0.3 * v, atol=1e-12)
    np.testing.assert_allclose(cs.difference(model, q, q), 0.0, atol=1e-14)


# ----------------------------------------------------------------------------- bad input
@pytest.fixture(scope="module")
def small_model():
    return random_tree(51, 0, n_bodies=3, joint_types=("revolute",))


def test_wrong_shapes_are_named(small_model):
    m = small_model
    q, v = jnp.asarray(m.neutral()), jnp.zeros(m.nv)
    with pytest.raises(cs.InputError, match=rf"rnea: v must have shape \({m.nv},\)"):
        cs.rnea(m, q, jnp.zeros(3), v)
    with pytest.raises(cs.InputError, match="f_ext must have shape"):
        cs.aba(m, q, v, v, jnp.zeros((2, 6)))
    with pytest.raises(cs.InputError, match=f"active must be a tuple of nv={m.nv}"):
        cs.hybrid_dynamics(m, q, v, jnp.zeros(1), jnp.zeros(m.nv - 1), (True,))
    with pytest.raises(cs.InputError, match="a_active must have shape"):
        cs.hybrid_dynamics(m, q, v, jnp.zeros(2), jnp.zeros(m.nv - 1), (True,) + (False,) * (m.nv - 1))


def test_non_unit_quaternion_rejected(small_model):
    q = small_model.neutral()
    q[3:7] = [2.0, 0, 0, 0]
    with pytest.raises(cs.InputError, match="joint 'b0'.*norm 2"):
        cs.mass_matrix(small_model, jnp.asarray(q))


def test_model_index_maps(small_model):
    m = small_model
    assert m.joint_q("b0") == slice(0, 7) and m.joint_v("b0") == slice(0, 6)
    mask = m.active_mask(["b1"])
    assert len(mask) == m.nv and sum(mask) == 1 and mask[m.joint_v("b1").start]
    with pytest.raises(cs.ModelError, match="no joint named 'nope'"):
        m.joint_q("nope")


def test_small_spd_inverse_and_its_jvp():
    """The unrolled Cholesky inverse of a free joint's articulated inertia equals
    numpy's inverse, is symmetric, and its JVP rule (-X dD X) matches central differences."""
    import jax
    import jax.numpy as jnp
    from cstorm.dynamics.hybrid import small_spd_inverse
    rng = np.random.default_rng(3)
    for n in (2, 3, 6):
        A = rng.normal(size=(n, n))
        D = A @ A.T + 0.5 * np.eye(n)
        X = np.asarray(small_spd_inverse(jnp.asarray(D)))
        np.testing.assert_allclose(X, np.linalg.inv(D), rtol=1e-10, atol=1e-12)
        np.testing.assert_array_equal(X, X.T)
        dD = rng.normal(size=(n, n))
        dD = dD + dD.T
        _, t = jax.jvp(small_spd_inverse, (jnp.asarray(D),), (jnp.asarray(dD),))
        h = 1e-6
        fd = (np.linalg.inv(D + h * dD) - np.linalg.inv(D - h * dD)) / (2 * h)
        np.testing.assert_allclose(np.asarray(t), fd, rtol=1e-6, atol=1e-8)
