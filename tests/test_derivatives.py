"""Derivatives of RNEA, ABA and the hybrid dynamics.

Oracles: the autodiff reference (`derivatives_ad`) against central finite differences on
the manifold (tier c), and the analytic recursive algorithms against the autodiff
reference on seeded random trees with free, ball, revolute and prismatic joints (several
topologies x several parameter draws; one compiled function per topology).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import cstorm as cs
from cstorm.dynamics import derivatives as D
from cstorm.dynamics import derivatives_ad as DAD
from helpers import manifold_fd, random_state, random_tree

TOPOLOGIES = (0, 1, 2, 3, 5)
PARAMS = (0, 1, 2)
SLOW = pytest.mark.slow  # compile-heavy variants (run with -m slow or without -m filtering)

# Compile-time budget: the jacfwd references on these trees take ~5-40 s each to compile
# with XLA's full CPU optimization on 2 cores; the tests only need correct numbers, so they compile with
# the backend optimizations off (~2-3x faster), and every jitted function is reused
# across parameter draws of one topology (same pytree structure: one compilation).
jit = functools.partial(jax.jit, compiler_options={"xla_backend_optimization_level": 0,
                                                   "xla_llvm_disable_expensive_passes": True})


@functools.lru_cache(maxsize=None)
def _tree(topology, params):
    return random_tree(topology, params)


def _active_mask(model, topology, kind):
    """Deterministic per (topology, kind), so compiled functions are shared by tests."""
    if kind == "all":
        return (True,) * model.nv
    if kind == "none":
        return (False,) * model.nv
    # mixed: floating root passive, the other DoFs active or passive at random
    m = [bool(x) for x in np.random.default_rng(1000 + topology).integers(0, 2, model.nv)]
    for k in range(model.joints[0].nv):
        m[k] = False
    return tuple(m)


def _inputs(model, topology, seed, kind="mixed", with_fext=True, neutral=False):
    rng = np.random.default_rng(seed)
    q, v, a = random_state(model, rng)
    if neutral:  # zero angles, identity rotations
        q = jnp.asarray(model.neutral())
    active = _active_mask(model, topology, kind)
    act = np.array(active)
    tau = jnp.asarray(rng.normal(size=model.nv) * 3.0)
    f_ext = jnp.asarray(rng.normal(size=(model.n_bodies, 6))) if with_fext else None
    return q, v, a[act], tau[~act], active, f_ext


def _hybrid_output(model, q, v, a_active, tau_passive, active, f_ext):
    """(nv,) hybrid output through the public `cs.hybrid_dynamics`: tau_active in the
    active rows, a_passive in the passive rows (the layout of the derivatives' ``y``)."""
    act = np.array(active, dtype=bool)
    ta, ap = cs.hybrid_dynamics(model, q, v, a_active, tau_passive, active, f_ext)
    y = jnp.zeros(model.nv, dtype=jnp.result_type(ta, ap, v))
    return y.at[np.nonzero(act)[0]].set(ta).at[np.nonzero(~act)[0]].set(ap)


_y = jit(_hybrid_output, static_argnums=(5,))
_hyb_ad = jit(DAD.hybrid_dynamics_derivatives_ad, static_argnames=("active",))
_hyb = jit(D.hybrid_dynamics_derivatives, static_argnames=("active",))
_rnea = jit(D.rnea_derivatives)
_aba = jit(D.aba_derivatives)
# References that only one or two calls use are not compiled: the `DAD` functions run op
# by op, ~2 s a call on these trees after a first call of ~10 s, against 20-40 s to
# compile each new (tree, mask, f_ext/None) combination of the jacfwd reference.


def _rel(a, b):
    """max |a - b| / max(1, max |b|)."""
    a, b = np.asarray(a), np.asarray(b)
    if a.size == 0 and b.size == 0:
        return 0.0
    return np.abs(a - b).max() / max(1.0, np.abs(b).max())


def _fd_all(model, q, v, aa, tp, active, f_ext, eps=1e-6):
    """Central finite differences of the hybrid output w.r.t. every argument (the
    q-columns on the manifold, `helpers.manifold_fd`)."""
    f0 = jnp.zeros((model.n_bodies, 6)) if f_ext is None else f_ext

    def col(fun, x, k):
        e = jnp.zeros_like(x).reshape(-1).at[k].set(eps).reshape(x.shape)
        return (np.asarray(fun(x + e)) - np.asarray(fun(x - e))) / (2 * eps)

    def jac(fun, x):
        if x.size == 0:
            return np.zeros((model.nv,) + x.shape)
        return np.stack([col(fun, x, k) for k in range(x.size)], axis=-1).reshape((model.nv,) + x.shape)

    dq = manifold_fd(lambda qq: _y(model, qq, v, aa, tp, active, f0), model, q, eps)
    dv = jac(lambda x: _y(model, q, x, aa, tp, active, f0), v)
    da = jac(lambda x: _y(model, q, v, x, tp, active, f0), aa)
    dt = jac(lambda x: _y(model, q, v, aa, x, active, f0), tp)
    df = jac(lambda x: _y(model, q, v, aa, tp, active, x), f0)
    return dq, dv, da, dt, df


NAMES = ("y", "dq", "dv", "da_active", "dtau_passive", "df_ext")


# ------------------------------------------------------------------ autodiff vs finite differences
@pytest.mark.parametrize("topology,kind", [(0, "mixed"), (1, "mixed"), pytest.param(3, "mixed", marks=SLOW),
                                           pytest.param(1, "all", marks=SLOW), pytest.param(1, "none", marks=SLOW)])
def test_autodiff_reference_matches_finite_differences(topology, kind):
    """Tier (c): the oracle itself against central differences on the manifold, at a
    random point and at zero angles / identity rotations."""
    model = _tree(topology, 0)
    for seed, neutral in ((topology, False), (topology + 100, True)):
        q, v, aa, tp, active, f_ext = _inputs(model, topology, seed, kind, neutral=neutral)
        r = _hyb_ad(model, q, v, aa, tp, active=active, f_ext=f_ext)
        fd = _fd_all(model, q, v, aa, tp, active, f_ext)
        for name, got, want in zip(NAMES[1:], r[1:], fd):
            assert _rel(got, want) < 1e-6, (name, neutral, _rel(got, want))
        np.testing.assert_allclose(r.y, _y(model, q, v, aa, tp, active, f_ext), rtol=0, atol=1e-12)


# ------------------------------------------------------------------ analytic vs autodiff
def _compare(got, want, tol=1e-10):
    errs = {n: _rel(g, w) for n, g, w in zip(got._fields, got, want)}
    assert max(errs.values()) < tol, errs
    return errs


@pytest.mark.parametrize("topology", [t if t in (0, 1, 3) else pytest.param(t, marks=SLOW) for t in TOPOLOGIES])
def test_analytic_hybrid_matches_autodiff(topology):
    """Several parameter draws of one topology (one compilation each way), random
    states and the neutral configuration, external wrenches on every body."""
    for p in PARAMS:
        model = _tree(topology, p)
        assert any(isinstance(j, (cs.Free, cs.Ball)) for j in model.joints)
        for seed, neutral in ((10 * p, False), (10 * p + 1, True)):
            q, v, aa, tp, active, f_ext = _inputs(model, topology, seed, neutral=neutral)
            _compare(_hyb(model, q, v, aa, tp, active=active, f_ext=f_ext),
                     _hyb_ad(model, q, v, aa, tp, active=active, f_ext=f_ext))


@pytest.mark.parametrize("topology", (1, pytest.param(2, marks=SLOW)))
def test_analytic_hybrid_without_fext(topology):
    """f_ext=None: df_ext is still returned (derivative at a zero wrench)."""
    for p in PARAMS[:2]:
        model = _tree(topology, p)
        q, v, aa, tp, active, _ = _inputs(model, topology, p, with_fext=False)
        got = _hyb(model, q, v, aa, tp, active=active)
        assert got.df_ext.shape == (model.nv, model.n_bodies, 6)
        _compare(got, DAD.hybrid_dynamics_derivatives_ad(model, q, v, aa, tp, active=active))


def test_hybrid_layer_product_forms_agree(monkeypatch):
    """The hybrid layer multiplies S into [dq | dv | M[:, a]] concatenated (up to
    `_CONCAT_MAX_NV` DoFs, as the small trees here) or block by block (larger models,
    e.g. TALOS); both forms give the same numbers."""
    model = _tree(1, 0)
    assert model.nv <= D._CONCAT_MAX_NV
    q, v, aa, tp, active, f_ext = _inputs(model, 1, 0)
    assert any(active) and not all(active)
    ref = jit(D.hybrid_derivatives_unchecked, static_argnums=(5,))(model, q, v, aa, tp, active, f_ext)
    monkeypatch.setattr(D, "_CONCAT_MAX_NV", 0)  # read at trace time: a new function, a new trace
    got = jit(lambda *args: D.hybrid_derivatives_unchecked(*args), static_argnums=(5,))(model, q, v, aa, tp, active, f_ext)
    _compare(got, ref, tol=1e-13)


@pytest.mark.parametrize("topology,with_fext", [(1, True), pytest.param(3, True, marks=SLOW),
                                                pytest.param(1, False, marks=SLOW)])
def test_analytic_rnea_and_aba_match_autodiff(topology, with_fext):
    """Reference: jacfwd through the hybrid algorithm with every DoF active (= RNEA) or
    passive (= ABA), run eagerly."""
    for p in PARAMS[:2]:
        model = _tree(topology, p)
        rng = np.random.default_rng(p)
        q, v, a = random_state(model, rng)
        f_ext = jnp.asarray(rng.normal(size=(model.n_bodies, 6))) if with_fext else None
        z = jnp.zeros(0)
        ref = DAD.hybrid_dynamics_derivatives_ad(model, q, v, a, z, _active_mask(model, topology, "all"), f_ext)
        _compare(_rnea(model, q, v, a, f_ext), D.RNEADerivatives(ref.y, ref.dq, ref.dv, ref.da_active, ref.df_ext))
        tau = jnp.asarray(rng.normal(size=model.nv))
        ref = DAD.hybrid_dynamics_derivatives_ad(model, q, v, z, tau, _active_mask(model, topology, "none"), f_ext)
        _compare(_aba(model, q, v, tau, f_ext), D.ABADerivatives(ref.y, ref.dq, ref.dv, ref.dtau_passive, ref.df_ext))


@SLOW
def test_autodiff_rnea_and_aba_references():
    """The public autodiff references rnea_derivatives_ad / aba_derivatives_ad (jacfwd
    through `rnea_unchecked`, and through `hybrid_unchecked` with all DoFs passive)."""
    model = _tree(1, 0)
    rng = np.random.default_rng(5)
    q, v, a = random_state(model, rng)
    f_ext = jnp.asarray(rng.normal(size=(model.n_bodies, 6)))
    _compare(_rnea(model, q, v, a, f_ext), DAD.rnea_derivatives_ad(model, q, v, a, f_ext))
    _compare(_aba(model, q, v, a, f_ext), DAD.aba_derivatives_ad(model, q, v, a, f_ext))


@pytest.mark.parametrize("n", (1, 2, 7, 22, 38))
def test_spd_inverse_against_numpy(n):
    """`spd_inverse` (LAPACK Cholesky, recursive blocked triangular inverse) on random
    SPD matrices with condition numbers 1e2 and 1e8, against numpy's LU inverse: the
    error stays at cond * eps."""
    rng = np.random.default_rng(n)
    for cond in (1e2, 1e8):
        Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
        A = Q @ np.diag(np.logspace(0, np.log10(cond), n)) @ Q.T
        A = (A + A.T) / 2
        got = np.asarray(jit(D.spd_inverse)(jnp.asarray(A)))
        want = np.linalg.inv(A)
        assert np.abs(got - want).max() / np.abs(want).max() < 100 * cond * np.finfo(float).eps
        L = np.linalg.cholesky(A)
        assert np.allclose(np.asarray(jit(D.tril_inverse)(jnp.asarray(L))) @ L, np.eye(n), atol=1e-10 * cond ** 0.5)


def test_identities():
    """rnea: tau, da = M; aba: a = aba, dtau = M^-1, d a = -M^-1 d rnea; hybrid with all
    DoFs active / passive equals rnea / aba derivatives; the autodiff method switch."""
    topology = 1
    model = _tree(topology, 0)
    rng = np.random.default_rng(3)
    q, v, a = random_state(model, rng)
    f_ext = jnp.asarray(rng.normal(size=(model.n_bodies, 6)))
    r = _rnea(model, q, v, a, f_ext)
    M = np.asarray(cs.mass_matrix(model, q))
    np.testing.assert_allclose(r.da, M, atol=1e-12)
    np.testing.assert_allclose(r.tau, cs.rnea(model, q, v, a, f_ext), atol=1e-11)
    s = _aba(model, q, v, r.tau, f_ext)
    np.testing.assert_allclose(s.a, a, atol=1e-9)
    np.testing.assert_allclose(s.a, cs.aba(model, q, v, r.tau, f_ext), atol=1e-9)
    Minv = np.linalg.inv(M)
    assert _rel(s.dtau, Minv) < 1e-10
    assert _rel(s.dq, -Minv @ r.dq) < 1e-9
    assert _rel(s.dv, -Minv @ r.dv) < 1e-9
    assert _rel(s.df_ext, -np.einsum("ij,jbk->ibk", Minv, r.df_ext)) < 1e-9
    # df_ext = -J^T of the body's point Jacobian at the world origin, re-expressed
    for b in range(model.n_bodies):
        Jp = np.asarray(cs.point_jacobian(model, q, b))  # [omega; pdot of body origin], world axes
        x = np.asarray(cs.forward_kinematics(model, q)[b, :3, 3])
        Jo = np.vstack([Jp[:3], Jp[3:] + np.cross(x[:, None], Jp[:3], axis=0)])  # twist about the origin
        np.testing.assert_allclose(r.df_ext[:, b, :], -Jo.T, atol=1e-12)
    h = _hyb(model, q, v, a, jnp.zeros(0), active=(True,) * model.nv, f_ext=f_ext)
    for x, y in zip(h, (r.tau, r.dq, r.dv, r.da, None, r.df_ext)):
        if y is not None:
            assert _rel(x, y) < 1e-12
    with pytest.raises(cs.InputError):
        D.rnea_derivatives(model, q, v, a, method="symbolic")
    with pytest.raises(cs.InputError):
        D.hybrid_dynamics_derivatives(model, q, v, a[:3], a[3:], (True,) * model.nv)


# ------------------------------------------------------------------ real models vs Pinocchio
def _pin_case(rel, floating):
    """(model, pinocchio model, P) with v_pin = P v_cs for a URDF of example-robot-data."""
    pin = pytest.importorskip("pinocchio")
    import importlib.metadata
    import os
    import warnings

    try:
        robots = importlib.metadata.distribution("example-robot-data").locate_file(
            "cmeel.prefix/share/example-robot-data/robots")
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("example-robot-data is not installed")
    path = os.path.join(str(robots), rel)
    if not os.path.isfile(path):
        pytest.skip(f"{rel} not found")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = cs.load_urdf(path, floating_base=floating, load_meshes=False, inertia_check="lenient")
    pm = pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer()) if floating else pin.buildModelFromUrdf(path)
    P = np.zeros((pm.nv, model.nv))
    for i, (name, j) in enumerate(zip(model.joint_names, model.joints)):
        pj = pm.joints[pm.getJointId("root_joint" if name == "root" else name)]
        vs = model.v_starts[i]
        if j.nv == 6:  # cstorm [omega; v] -> Pinocchio [v; omega]
            P[pj.idx_v: pj.idx_v + 3, vs + 3: vs + 6] = np.eye(3)
            P[pj.idx_v + 3: pj.idx_v + 6, vs: vs + 3] = np.eye(3)
        else:
            assert j.nv == pj.nv == 1 and pj.nq == 1, name
            P[pj.idx_v, vs] = 1.0
    return model, pm, P


def _q_to_pin(model, pm, q):
    import pinocchio as pin

    qp = pin.neutral(pm)
    for i, (name, j) in enumerate(zip(model.joint_names, model.joints)):
        pj = pm.joints[pm.getJointId("root_joint" if name == "root" else name)]
        s, t = model.q_starts[i], pj.idx_q
        if j.nq == 7:  # [x y z qw qx qy qz] -> [x y z qx qy qz qw]
            qp[t: t + 3], qp[t + 3: t + 6], qp[t + 6] = q[s: s + 3], q[s + 4: s + 7], q[s + 3]
        else:
            qp[t] = q[s]
    return qp


@pytest.mark.parametrize("rel,floating", [("ur_description/urdf/ur5_robot.urdf", None),
                                          ("solo_description/robots/solo12.urdf", "free")],
                         ids=["ur5", "solo12"])
def test_against_pinocchio(rel, floating):
    """Tier (a): Pinocchio's computeRNEADerivatives / computeABADerivatives (no external
    forces: Pinocchio's are body-fixed, ours world-fixed, so their q-derivatives differ)."""
    import pinocchio as pin

    model, pm, P = _pin_case(rel, floating)
    pd = pm.createData()
    rng = np.random.default_rng(7)
    arm = rng.uniform(0.0, 0.05, model.nv) * np.array([j.nv == 1 for j in model.joints for _ in range(j.nv)])
    model = model.replace(armature=jnp.asarray(arm))
    pm.armature = P @ arm
    sym = lambda X: np.triu(X) + np.triu(X, 1).T  # Pinocchio fills the upper triangle of M, M^-1
    for k in range(2):
        q = jnp.asarray(model.random_q(rng) if k else model.neutral())
        v, a, tau = (rng.normal(size=model.nv) for _ in range(3))
        qp = _q_to_pin(model, pm, np.asarray(q))
        dq, dv, da = pin.computeRNEADerivatives(pm, pd, qp, P @ v, P @ a)
        r = _rnea(model, q, jnp.asarray(v), jnp.asarray(a), None)
        assert _rel(r.tau, P.T @ pin.rnea(pm, pd, qp, P @ v, P @ a)) < 1e-9
        assert _rel(r.dq, P.T @ dq @ P) < 1e-9
        assert _rel(r.dv, P.T @ dv @ P) < 1e-9
        assert _rel(r.da, P.T @ sym(da) @ P) < 1e-9
        dq, dv, dt = pin.computeABADerivatives(pm, pd, qp, P @ v, P @ tau)
        s = _aba(model, q, jnp.asarray(v), jnp.asarray(tau), None)
        assert _rel(s.a, P.T @ pin.aba(pm, pd, qp, P @ v, P @ tau)) < 1e-9
        assert _rel(s.dq, P.T @ dq @ P) < 1e-9
        assert _rel(s.dv, P.T @ dv @ P) < 1e-9
        assert _rel(s.dtau, P.T @ sym(dt) @ P) < 1e-9


# ------------------------------------------------------------------ custom JVP rule in a rollout
@SLOW  # ~4 min of compiles on 2 cores; test_simulate_rollout_uses_fast_rule... covers the same in CI
def test_fast_rule_rollout_gradients_match_autodiff():
    """A few explicit-Euler steps (lax.scan) of hybrid dynamics on a tree with free, ball,
    revolute and prismatic joints: gradients (reverse mode) and a JVP (forward mode) of a
    scalar loss w.r.t. link masses and joint placements (model leaves: the autodiff
    fallback of the rule), the initial configuration (tangent), initial velocity,
    controls and external wrenches agree between `hybrid_dynamics_fast` and plain
    autodiff of `hybrid_dynamics`."""
    from cstorm.dynamics.derivatives_fast import hybrid_dynamics_fast

    base = random_tree(14, 0, n_bodies=4, joint_types=("ball", "revolute", "prismatic", "free"))
    assert {type(j) for j in base.joints} == {cs.Free, cs.Ball, cs.Revolute, cs.Prismatic}
    rng = np.random.default_rng(0)
    q0, v0, _ = random_state(base, rng)
    active = tuple(isinstance(j, (cs.Revolute, cs.Prismatic)) for j in base.joints for _ in range(j.nv))
    act = np.array(active)
    ia, ip = np.nonzero(act)[0], np.nonzero(~act)[0]
    T, dt = 4, 0.01
    U = jnp.asarray(rng.normal(size=(T, len(ia))))
    F = jnp.asarray(rng.normal(size=(base.n_bodies, 6)))

    def loss(hyb, mass, joint_p, dq0, v0, U, F):
        model = base.replace(mass=mass, joint_p=joint_p)

        def step(c, u):
            q, v = c
            ta, ap = hyb(model, q, v, u, -0.1 * v[ip], active, F)
            a = jnp.zeros(model.nv).at[ia].set(u).at[ip].set(ap)
            return (cs.integrate(model, q, v, dt), v + dt * a), jnp.sum(ta ** 2)

        (q, v), e = jax.lax.scan(step, (cs.integrate(model, q0, dq0), v0), U)
        return jnp.sum(jnp.sin(q)) + jnp.sum(v * jnp.arange(model.nv)) + 0.1 * jnp.sum(e)

    args = (base.mass, base.joint_p, jnp.zeros(base.nv), v0, U, F)
    tangents = tuple(jnp.asarray(rng.normal(size=np.shape(x))) for x in args)
    out = {}
    for name, hyb in (("plain", cs.hybrid_dynamics), ("fast", hybrid_dynamics_fast)):
        f = functools.partial(loss, hyb)
        grads = jit(jax.grad(f, argnums=tuple(range(len(args)))))(*args)
        val, jvp = jit(lambda a, t: jax.jvp(f, a, t))(args, tangents)
        out[name] = (grads, val, jvp)
    (g0, v0_, j0), (g1, v1_, j1) = out["plain"], out["fast"]
    for k, (x, y) in enumerate(zip(g1, g0)):
        assert _rel(x, y) < 1e-9, (k, _rel(x, y))
    assert abs(v1_ - v0_) < 1e-10 and abs(j1 - j0) < 1e-9 * max(1.0, abs(j0))


# ------------------------------------------------------------------ real models: analytic vs autodiff
REAL = {"ur5": ("ur_description/urdf/ur5_robot.urdf", None),
        "solo12": ("solo_description/robots/solo12.urdf", "free"),
        "talos": ("talos_data/robots/talos_reduced.urdf", "free")}


@functools.lru_cache(maxsize=None)
def _erd_model(key):
    """A cstorm model of an example-robot-data URDF (skips when the package is absent)."""
    import importlib.metadata
    import os
    import warnings

    rel, floating = REAL[key]
    try:
        robots = importlib.metadata.distribution("example-robot-data").locate_file(
            "cmeel.prefix/share/example-robot-data/robots")
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("example-robot-data is not installed")
    path = os.path.join(str(robots), rel)
    if not os.path.isfile(path):
        pytest.skip(f"{rel} not found")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return cs.load_urdf(path, floating_base=floating, load_meshes=False, inertia_check="lenient")


@pytest.mark.parametrize("key,algorithms", [
    ("ur5", ("hybrid",)),
    ("ur5", ("rnea", "aba")),
    pytest.param("solo12", ("hybrid", "rnea", "aba"), marks=SLOW),
    pytest.param("talos", ("hybrid", "rnea", "aba"), marks=SLOW)], ids=["ur5", "ur5-rnea-aba", "solo12", "talos"])
def test_analytic_matches_autodiff_on_real_models(key, algorithms):
    """The acceptance check on example-robot-data robots (free base on Solo12 and TALOS):
    analytic == jacfwd reference to 1e-10 relative, with external wrenches on every body
    and without (f_ext=None), at a random configuration and at the neutral one. Hybrid:
    floating base passive, every other joint active (as in the benchmark).

    Both sides run eagerly (op by op, no `jax.jit`): the same jnp operations as the
    compiled functions, without compiling a whole unrolled 38-DoF tree and its jacfwd.
    On TALOS each jitted analytic function takes ~80 s to compile even with the backend
    optimizations off, and the jitted jacfwd oracle exhausted LLVM's memory mappings
    (`vm.max_map_count` 65530); eagerly a TALOS call takes ~20 s. The compiled analytic
    code is checked on the seeded trees above and against Pinocchio (UR5, Solo12)."""
    model = _erd_model(key)
    rng = np.random.default_rng(11)
    nfb = 6 if REAL[key][1] else 0
    active = tuple(bool(i % 2) if i >= nfb else False for i in range(model.nv))
    act = np.array(active)
    for k, with_fext in enumerate((True, False)):
        q, v, a = random_state(model, rng)
        if k:
            q = jnp.asarray(model.neutral())
        tau = jnp.asarray(rng.normal(size=model.nv) * 3.0)
        f_ext = jnp.asarray(rng.normal(size=(model.n_bodies, 6)) * 5.0) if with_fext else None
        if "hybrid" in algorithms:
            _compare(D.hybrid_dynamics_derivatives(model, q, v, a[act], tau[~act], active=active, f_ext=f_ext),
                     DAD.hybrid_dynamics_derivatives_ad(model, q, v, a[act], tau[~act], active=active, f_ext=f_ext))
        if "rnea" in algorithms:
            _compare(D.rnea_derivatives(model, q, v, a, f_ext), DAD.rnea_derivatives_ad(model, q, v, a, f_ext))
        if "aba" in algorithms:
            _compare(D.aba_derivatives(model, q, v, tau, f_ext), DAD.aba_derivatives_ad(model, q, v, tau, f_ext))


# ------------------------------------------------------------------ the rule inside cstorm's rollouts
def test_simulate_rollout_uses_fast_rule_and_keeps_mass_tangents():
    """`cstorm.simulate.rollout` (RK4 with RKMK4 on the free base, checkpointed scan,
    state-dependent external wrenches from a ``contact_fn``): its value equals the
    ``derivatives="autodiff"`` rollout's, and its reverse-mode gradient (through the
    custom JVP rule, the default) w.r.t. the link masses (each), joint placements, initial
    velocity and active accelerations (random directions) matches central finite
    differences, so no model-parameter tangent is dropped (a dropped one would be off by
    O(1)). The 1e-9 comparison with plain autodiff is `test_fast_rule_rollout_...`
    (slow: its compilations take minutes)."""
    from cstorm.simulate import RolloutLayout, rollout

    base = random_tree(14, 0, n_bodies=4, joint_types=("ball", "revolute", "prismatic", "free"))
    assert {type(j) for j in base.joints} == {cs.Free, cs.Ball, cs.Revolute, cs.Prismatic}
    active_names = [n for n, j in zip(base.joint_names, base.joints) if isinstance(j, (cs.Revolute, cs.Prismatic))]
    lay = RolloutLayout.make(base, active_names)
    rng = np.random.default_rng(4)
    q0, v0, _ = random_state(base, rng)
    N, na = 4, lay.n_active
    qa = jnp.asarray(rng.normal(size=(N + 1, na)) * 0.1)
    va = jnp.asarray(rng.normal(size=(N + 1, na)))
    aa = jnp.asarray(rng.normal(size=(N + 1, na)))
    F0 = jnp.asarray(rng.normal(size=(base.n_bodies, 6)))
    contact_fn = lambda q, v: (F0 * (1.0 + 0.3 * jnp.sum(jnp.sin(q)) + 0.1 * jnp.sum(v)), None)
    cost = lambda t, q, v, a, tau, c, p: 0.5 * jnp.sum(tau ** 2)

    def loss(derivatives, mass, joint_p, v0, aa):
        paths = dict(qa=qa, va=va, aa=aa, qm=qa[:-1], vm=va[:-1], am=aa[:-1])
        r = rollout(base.replace(mass=mass, joint_p=joint_p), lay, q0, v0, paths, 0.01, N, contact_fn=contact_fn,
                    cost_fn=cost, record=False, derivatives=derivatives)
        return jnp.sum(jnp.sin(r["qT"])) + jnp.sum(r["vT"] * jnp.arange(base.nv)) + 1e-3 * r["J"]

    args = (base.mass, base.joint_p, v0, aa)
    value = jit(functools.partial(loss, "analytic"))
    grads = jit(jax.grad(functools.partial(loss, "analytic"), argnums=(0, 1, 2, 3)))(*args)
    assert float(value(*args)) == pytest.approx(float(jit(functools.partial(loss, "autodiff"))(*args)), rel=1e-12)
    eps = 1e-6

    def fd(k, direction):
        plus = [x + eps * direction if i == k else x for i, x in enumerate(args)]
        minus = [x - eps * direction if i == k else x for i, x in enumerate(args)]
        return (float(value(*plus)) - float(value(*minus))) / (2 * eps)

    for b in range(base.n_bodies):  # each link mass
        e = jnp.zeros(base.n_bodies).at[b].set(1.0)
        assert float(grads[0][b]) == pytest.approx(fd(0, e), rel=1e-6, abs=1e-7), b
    for k in (1, 2, 3):
        d = jnp.asarray(rng.normal(size=np.shape(args[k])))
        assert float(jnp.sum(grads[k] * d)) == pytest.approx(fd(k, d), rel=1e-6, abs=1e-7), k
    with pytest.raises(cs.InputError):
        loss("symbolic", *args)
