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


@functools.lru_cache(maxsize=None)
def _tree(topology, params):
    return random_tree(topology, params)


def _active_mask(model, rng, kind):
    if kind == "all":
        return (True,) * model.nv
    if kind == "none":
        return (False,) * model.nv
    # mixed: floating root passive, the rest random per DoF
    m = [bool(x) for x in rng.integers(0, 2, model.nv)]
    for k in range(model.joints[0].nv):
        m[k] = False
    return tuple(m)


def _inputs(model, seed, kind="mixed", with_fext=True):
    rng = np.random.default_rng(seed)
    q, v, a = random_state(model, rng)
    active = _active_mask(model, rng, kind)
    act = np.array(active)
    tau = jnp.asarray(rng.normal(size=model.nv) * 3.0)
    f_ext = jnp.asarray(rng.normal(size=(model.n_bodies, 6))) if with_fext else None
    return q, v, a[act], tau[~act], active, f_ext


# jitted entry points (model and f_ext are traced; `active` is static)
_y = jax.jit(DAD._y, static_argnums=(5,))
_hyb_ad = jax.jit(DAD.hybrid_dynamics_derivatives_ad, static_argnames=("active",))
_rnea_ad = jax.jit(DAD.rnea_derivatives_ad)
_aba_ad = jax.jit(DAD.aba_derivatives_ad)


def _rel(a, b):
    a, b = np.asarray(a), np.asarray(b)
    if a.size == 0 and b.size == 0:
        return 0.0
    return np.abs(a - b).max() / max(1.0, np.abs(b).max())


def _fd_all(model, q, v, aa, tp, active, f_ext, eps=1e-6):
    """Central finite differences of the hybrid output w.r.t. every argument."""
    f0 = jnp.zeros((model.n_bodies, 6)) if f_ext is None else f_ext

    def col(fun, x, k):
        e = jnp.zeros_like(x).reshape(-1).at[k].set(eps).reshape(x.shape)
        return (np.asarray(fun(x + e)) - np.asarray(fun(x - e))) / (2 * eps)

    def jac(fun, x):
        if x.size == 0:
            return np.zeros((model.nv, 0))
        return np.stack([col(fun, x, k) for k in range(x.size)], axis=-1).reshape((model.nv,) + x.shape)

    dq = manifold_fd(lambda qq: _y(model, qq, v, aa, tp, active, f0), model, q, eps)
    dv = jac(lambda x: _y(model, q, x, aa, tp, active, f0), v)
    da = jac(lambda x: _y(model, q, v, x, tp, active, f0), aa)
    dt = jac(lambda x: _y(model, q, v, aa, x, active, f0), tp)
    df = jac(lambda x: _y(model, q, v, aa, tp, active, x), f0)
    return dq, dv, da, dt, df


# ------------------------------------------------------------------ autodiff vs finite differences
@pytest.mark.parametrize("topology", (0, 1, 3))
@pytest.mark.parametrize("kind", ("mixed", "all", "none"))
def test_autodiff_reference_matches_finite_differences(topology, kind):
    model = _tree(topology, 0)
    for seed, neutral in ((topology, False), (topology + 100, True)):
        q, v, aa, tp, active, f_ext = _inputs(model, seed, kind)
        if neutral:  # zero angles, identity rotations
            q = jnp.asarray(model.neutral())
        r = _hyb_ad(model, q, v, aa, tp, active=active, f_ext=f_ext)
        fd = _fd_all(model, q, v, aa, tp, active, f_ext)
        for name, got, want in zip(("dq", "dv", "da_active", "dtau_passive", "df_ext"), r[1:], fd):
            assert _rel(got, want) < 1e-6, (name, _rel(got, want))
        y = _y(model, q, v, aa, tp, active, f_ext)
        np.testing.assert_allclose(r.y, y, rtol=0, atol=1e-12)


def test_autodiff_rnea_and_aba_reference_identities():
    model = _tree(1, 0)
    q, v, a = random_state(model, np.random.default_rng(3))
    f_ext = jnp.asarray(np.random.default_rng(4).normal(size=(model.n_bodies, 6)))
    r = _rnea_ad(model, q, v, a, f_ext)
    np.testing.assert_allclose(r.da, cs.mass_matrix(model, q), atol=1e-12)
    np.testing.assert_allclose(r.tau, cs.rnea(model, q, v, a, f_ext), atol=1e-12)
    fd = manifold_fd(lambda qq: cs.rnea(model, qq, v, a, f_ext), model, q)
    assert _rel(r.dq, fd) < 1e-6
    s = _aba_ad(model, q, v, r.tau, f_ext)
    np.testing.assert_allclose(s.a, a, atol=1e-9)
    # aba = rnea^-1: da/dtau = M^-1 and da/dx = -M^-1 drnea/dx
    Minv = np.linalg.inv(np.asarray(r.da))
    assert _rel(s.dtau, Minv) < 1e-10
    assert _rel(s.dq, -Minv @ r.dq) < 1e-9
    assert _rel(s.dv, -Minv @ r.dv) < 1e-9
    assert _rel(s.df_ext, -np.einsum("ij,jbk->ibk", Minv, r.df_ext)) < 1e-9
