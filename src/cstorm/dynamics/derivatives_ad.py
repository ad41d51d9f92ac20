"""Derivatives of the hybrid dynamics, RNEA and ABA by forward-mode automatic
differentiation (``jax.jacfwd`` through `hybrid_unchecked` / `rnea_unchecked`): the test oracle and the
fallback of the analytic algorithms in `cstorm.dynamics.derivatives`.

Same signatures and named tuples as the analytic functions. The q-derivative is taken
on the tangent space: columns are ``d/d dq  f(integrate(model, q, dq))`` at ``dq = 0``
(body-frame increments for free and ball joints, see `cstorm.dynamics.configuration`).
Cost: O(nv) forward-mode passes through an O(n) algorithm, i.e. O(n^2) with a large
constant; the analytic versions are the fast path.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .configuration import integrate
from .derivative_types import ABADerivatives, HybridDerivatives, RNEADerivatives, validate_inputs
from .hybrid import hybrid_unchecked
from .rnea import rnea_unchecked


def _y(model, q, v, a_active, tau_passive, active, f_ext):
    """(nv,) hybrid output: tau_active in active rows, a_passive in passive rows."""
    act = np.array(active, dtype=bool)
    ta, ap = hybrid_unchecked(model, q, v, a_active, tau_passive, active, f_ext)
    y = jnp.zeros(model.nv, dtype=jnp.result_type(ta, ap, v))
    return y.at[np.nonzero(act)[0]].set(ta).at[np.nonzero(~act)[0]].set(ap)


def hybrid_derivatives_ad(model, q, v, a_active, tau_passive, active, f_ext):
    f0 = jnp.zeros((model.n_bodies, 6), dtype=v.dtype) if f_ext is None else f_ext
    dq0 = jnp.zeros(model.nv, dtype=v.dtype)

    def g(dq, v_, aa, tp, f):
        return _y(model, integrate(model, q, dq), v_, aa, tp, active, f)

    y = g(dq0, v, a_active, tau_passive, f0)
    dq, dv, da, dtau, df = jax.jacfwd(g, argnums=(0, 1, 2, 3, 4))(dq0, v, a_active, tau_passive, f0)
    return HybridDerivatives(y, dq, dv, da, dtau, df)


def hybrid_dynamics_derivatives_ad(model, q, v, a_active, tau_passive, active, f_ext=None):
    """Autodiff reference of `cstorm.hybrid_dynamics_derivatives` (same arguments and
    named tuple ``(y, dq, dv, da_active, dtau_passive, df_ext)``)."""
    q, v, a_active, tau_passive, active, f_ext = validate_inputs(
        model, q, v, a_active, tau_passive, active, f_ext, "hybrid_dynamics_derivatives_ad")
    return hybrid_derivatives_ad(model, q, v, a_active, tau_passive, active, f_ext)


def rnea_derivatives_ad(model, q, v, a, f_ext=None):
    """Autodiff reference of `cstorm.rnea_derivatives`: ``(tau, dq, dv, da, df_ext)``."""
    active = (True,) * model.nv
    q, v, a, _, _, f_ext = validate_inputs(model, q, v, a, jnp.zeros(0), active, f_ext, "rnea_derivatives_ad")
    f0 = jnp.zeros((model.n_bodies, 6), dtype=v.dtype) if f_ext is None else f_ext
    dq0 = jnp.zeros(model.nv, dtype=v.dtype)

    def g(dq, v_, a_, f):
        return rnea_unchecked(model, integrate(model, q, dq), v_, a_, f)

    tau = g(dq0, v, a, f0)
    dq, dv, da, df = jax.jacfwd(g, argnums=(0, 1, 2, 3))(dq0, v, a, f0)
    return RNEADerivatives(tau, dq, dv, da, df)


def aba_derivatives_ad(model, q, v, tau, f_ext=None):
    """Autodiff reference of `cstorm.aba_derivatives`: ``(a, dq, dv, dtau, df_ext)``."""
    active = (False,) * model.nv
    q, v, _, tau, _, f_ext = validate_inputs(model, q, v, jnp.zeros(0), tau, active, f_ext, "aba_derivatives_ad")
    r = hybrid_derivatives_ad(model, q, v, jnp.zeros(0, dtype=v.dtype), tau, active, f_ext)
    return ABADerivatives(r.y, r.dq, r.dv, r.dtau_passive, r.df_ext)
