"""Result types of the dynamics derivatives (`HybridDerivatives`, `RNEADerivatives`,
`ABADerivatives`) and their input validation, shared by the analytic algorithm
(`derivatives`) and its autodiff reference (`derivatives_ad`)."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from . import _checks


class HybridDerivatives(NamedTuple):
    """Value and Jacobians of the hybrid dynamics ``y = g(q, v, a_active, tau_passive, f_ext)``.

    y (nv,): tau_active in the active rows, a_passive in the passive rows (v order).
    dq (nv, nv): w.r.t. a tangent perturbation ``q (+) dq``. dv (nv, nv).
    da_active (nv, n_active). dtau_passive (nv, n_passive).
    df_ext (nv, n_bodies, 6): w.r.t. the world wrenches ``[torque about world origin; force]``.
    """

    y: jnp.ndarray
    dq: jnp.ndarray
    dv: jnp.ndarray
    da_active: jnp.ndarray
    dtau_passive: jnp.ndarray
    df_ext: jnp.ndarray


class RNEADerivatives(NamedTuple):
    """``tau = rnea(q, v, a, f_ext)`` (nv,) and its Jacobians: dq (nv, nv) w.r.t. ``q (+) dq``,
    dv (nv, nv), da (nv, nv) (= the mass matrix M, armature included), df_ext (nv, n_bodies, 6)."""

    tau: jnp.ndarray
    dq: jnp.ndarray
    dv: jnp.ndarray
    da: jnp.ndarray
    df_ext: jnp.ndarray


class ABADerivatives(NamedTuple):
    """``a = aba(q, v, tau, f_ext)`` (nv,) and its Jacobians: dq (nv, nv) w.r.t. ``q (+) dq``,
    dv (nv, nv), dtau (nv, nv) (= M^-1), df_ext (nv, n_bodies, 6)."""

    a: jnp.ndarray
    dq: jnp.ndarray
    dv: jnp.ndarray
    dtau: jnp.ndarray
    df_ext: jnp.ndarray


#: checked ``(q, v, a_active, tau_passive, active, f_ext)`` for the derivative function ``fn``
validate_inputs = _checks.hybrid_inputs
