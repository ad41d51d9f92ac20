"""Hybrid dynamics with its analytic derivatives registered as a `jax.custom_jvp` rule:
the hybrid algorithm for rollouts whose gradients should use the recursive Jacobians
of `cstorm.dynamics.derivatives` instead of differentiating through the algorithm.

``hybrid_dynamics_fast(model, q, v, a_active, tau_passive, active, f_ext=None)`` has the
signature and value of `cstorm.hybrid_dynamics`. Its JVP (and, by JAX's transposition,
its VJP) is ``dy = Dq dq_t + Dv dv + Da da_active + Dt dtau_passive + Df df_ext`` with
the analytic Jacobians, plus, only when the model's array leaves carry nonzero tangents
(masses, inertias, placements, axes...: design derivatives), the forward-mode
derivative of the plain algorithm w.r.t. those leaves. Tangents w.r.t. model
parameters are therefore never dropped; when they are zero (the usual case) the
fallback is not traced at all (symbolic zeros).

Tangent space. JAX hands the rule an ambient tangent ``dq`` (nq,) of the configuration;
it is mapped to the body-frame tangent ``dq_t`` (nv,) of ``integrate(model, q, .)``:
revolute/prismatic ``dq_t = dq``; ball ``omega = 2 vec(conj(quat) (x) dquat)``; free
``[2 vec(conj(quat) (x) dquat); R^T dp]``. The quaternion tangent's radial component
(``quat . dquat``) is dropped: the rule is the derivative of the dynamics with unit
quaternions. Rollouts built from `integrate` only produce tangent (norm-preserving)
perturbations, where this equals plain autodiff; for a radial perturbation, plain
autodiff differentiates ``quat_to_rot`` off the unit sphere, which is not a rotation.

Cost: one JVP evaluates the full analytic Jacobians (O(n d) recursions plus a Cholesky
of M_pp) once per primal point; many tangent directions (``jacfwd``, ``vmap`` of
``jvp``) share them. For a single reverse-mode gradient plain autodiff of the O(n)
algorithm can be cheaper; see `benchmarks/derivatives.py`.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero

from .. import spatial as sp
from .derivative_types import validate_inputs
from .derivatives import hybrid_derivatives_unchecked
from .hybrid import hybrid_unchecked
from ..model.joints import Ball, Free


def hybrid_dynamics_fast(model, q, v, a_active, tau_passive, active, f_ext=None):
    """`cstorm.hybrid_dynamics` with analytic derivatives (custom JVP).

    Args:
        q: (nq,). v: (nv,). a_active: (n_active,). tau_passive: (n_passive,).
        active: static tuple of nv bools. f_ext: optional (n_bodies, 6) world wrenches
            ``[torque about world origin; force]``.
    Returns: (tau_active (n_active,), a_passive (n_passive,)).
    """
    q, v, a_active, tau_passive, active, f_ext = validate_inputs(
        model, q, v, a_active, tau_passive, active, f_ext, "hybrid_dynamics_fast")
    return hybrid_fast(model, q, v, a_active, tau_passive, active, f_ext)


@functools.partial(jax.custom_jvp, nondiff_argnums=(5,))
def hybrid_fast(model, q, v, a_active, tau_passive, active, f_ext):
    return hybrid_unchecked(model, q, v, a_active, tau_passive, active, f_ext)


def is_symbolic_zero(t):
    return t is None or isinstance(t, SymbolicZero)


def instantiate_zero(t):
    if isinstance(t, SymbolicZero):
        if jnp.issubdtype(t.aval.dtype, jnp.inexact):
            return jnp.zeros(t.aval.shape, t.aval.dtype)
        return np.zeros(t.aval.shape, dtype=jax.dtypes.float0)
    return t


def float0_zeros(x):
    """The zero tangent of an integer or boolean value ``x`` (dtype float0)."""
    return np.zeros(np.shape(x), dtype=jax.dtypes.float0)


def is_inexact(x):
    """Whether ``x`` has a floating (differentiable) dtype."""
    return jnp.issubdtype(jnp.result_type(x), jnp.inexact)


def any_nonzero(tree):
    """Whether any tangent leaf of ``tree`` is not a symbolic zero."""
    return not all(is_symbolic_zero(t) for t in jax.tree_util.tree_leaves(tree, is_leaf=is_symbolic_zero))


def ambient_to_tangent(model, q, dq):
    """Map an ambient configuration tangent ``dq`` (nq,) at ``q`` to the body-frame tangent
    (nv,) of ``integrate(model, q, .)`` (radial quaternion components dropped)."""
    out = []
    for j, qs in zip(model.joints, model.q_starts):
        if isinstance(j, Free):
            quat, dquat = q[qs + 3: qs + 7], dq[qs + 3: qs + 7]
            w = 2.0 * sp.quat_mul(sp.quat_conj(quat), dquat)[1:]
            out += [w, sp.mv(sp.quat_to_rot(quat).T, dq[qs: qs + 3])]
        elif isinstance(j, Ball):
            out.append(2.0 * sp.quat_mul(sp.quat_conj(q[qs: qs + 4]), dq[qs: qs + 4])[1:])
        else:
            out.append(dq[qs: qs + j.nq])
    return jnp.concatenate(out)


def _jvp(active, primals, tangents):
    model, q, v, a_active, tau_passive, f_ext = primals
    dmodel, dq, dv, da, dt, df = tangents
    act = np.array(active, dtype=bool)
    ia, ip = np.nonzero(act)[0], np.nonzero(~act)[0]
    r = hybrid_derivatives_unchecked(model, q, v, a_active, tau_passive, active, f_ext)
    dy = jnp.zeros_like(r.y)
    if not is_symbolic_zero(dq):
        dy = dy + r.dq @ ambient_to_tangent(model, q, dq)
    if not is_symbolic_zero(dv):
        dy = dy + r.dv @ dv
    if not is_symbolic_zero(da) and da.shape[0]:
        dy = dy + r.da_active @ da
    if not is_symbolic_zero(dt) and dt.shape[0]:
        dy = dy + r.dtau_passive @ dt
    if f_ext is not None and not is_symbolic_zero(df):
        dy = dy + jnp.einsum("ibk,bk->i", r.df_ext, df)
    if any_nonzero(dmodel):
        # design derivatives: forward mode through the plain algorithm, model leaves only
        dm = jax.tree_util.tree_map(instantiate_zero, dmodel, is_leaf=is_symbolic_zero)

        def y_of_model(m):
            ta, ap = hybrid_unchecked(m, q, v, a_active, tau_passive, active, f_ext)
            return jnp.zeros(model.nv, dtype=r.y.dtype).at[ia].set(ta).at[ip].set(ap)

        dy = dy + jax.jvp(y_of_model, (model,), (dm,))[1]
    return (r.y[ia], r.y[ip]), (dy[ia], dy[ip])


hybrid_fast.defjvp(_jvp, symbolic_zeros=True)
