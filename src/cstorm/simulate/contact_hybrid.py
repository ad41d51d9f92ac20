"""Contact forces and hybrid dynamics composed at the Jacobian level (`contact_hybrid`):
one JVP rule for ``f_ext = contact(q, v)`` followed by `cstorm.hybrid_dynamics`."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..dynamics.derivatives import hybrid_derivatives_unchecked
from ..dynamics.derivatives_fast import (ambient_to_tangent, any_nonzero, float0_zeros, instantiate_zero, is_inexact,
                                         is_symbolic_zero)
from ..dynamics.hybrid import hybrid_unchecked


def contact_hybrid(model, contact_fn, q, v, a_active, tau_passive, active):
    """``f_ext, cdata = contact_fn(q, v)`` then `cstorm.hybrid_dynamics` with that
    ``f_ext``, with one JVP rule for both: the contact Jacobian ``J_f`` w.r.t. ``(q, v)``
    (``jacfwd``, ``nq + nv`` directions; with `cstorm.contact_forces` its analytic rule
    for ground points) is composed with the hybrid algorithm's analytic ``dy/df_ext``
    once, ``(nv, nq + nv)``, and applied to every tangent: inside the step Jacobians of
    `_steps_jvp` the tangents are ``n_z + n_u`` wide, more than the ``nq + nv`` inputs
    of the contact model, and each costs an ``nv``-row product instead of a pass through
    the contact code and the ``n_bodies x 6`` wrenches. Tangents of closed-over values
    (environment, contact parameters) and of the model are pushed through by plain JVPs,
    and only when they are nonzero (on the hopper benchmark this is ~20 % faster than
    applying the contact model's forward-mode Jacobian to each tangent).

    Args:
      model: `Model`. contact_fn: ``(q, v) -> (f_ext (n_bodies, 6), cdata)`` (may close
        over traced values; they are hoisted and differentiated). q (nq,), v (nv,),
        a_active (n_active,), tau_passive (n_passive,), active: static tuple of nv bools.
    Returns:
      ``(tau_active, a_passive, f_ext, cdata)``.
    """
    fn_c, consts = jax.closure_convert(contact_fn, q, v)
    return _ch(fn_c, tuple(active), model, tuple(consts), q, v, a_active, tau_passive)


def _ch_primal(fn_c, active, model, consts, q, v, a_active, tau_passive):

    f_ext, cdata = fn_c(q, v, *consts)
    tau_a, a_p = hybrid_unchecked(model, q, v, a_active, tau_passive, active, f_ext)
    return tau_a, a_p, f_ext, cdata


_ch = jax.custom_jvp(_ch_primal, nondiff_argnums=(0, 1))


def _ch_jvp(fn_c, active, primals, tangents):

    model, consts, q, v, a_active, tau_passive = primals
    dmodel, dconsts, dq, dv, da, dt = tangents
    nb = model.n_bodies
    out, Js, extra, dcontact = _contact_tangents(fn_c, consts, dconsts, q, v, dq, dv)
    f_ext = out[0]
    dx = jnp.concatenate([instantiate_zero(dq), instantiate_zero(dv)])

    r = hybrid_derivatives_unchecked(model, q, v, a_active, tau_passive, active, f_ext)
    Df = r.df_ext.reshape(model.nv, nb * 6)
    Mx = Df @ Js[0].reshape(nb * 6, -1)  # dy/d(q, v) through f_ext, (nv, nq + nv) ambient
    dy = Mx @ dx
    if not is_symbolic_zero(dq):
        dy = dy + r.dq @ ambient_to_tangent(model, q, dq)
    if not is_symbolic_zero(dv):
        dy = dy + r.dv @ dv
    if not is_symbolic_zero(da) and da.shape[0]:
        dy = dy + r.da_active @ da
    if not is_symbolic_zero(dt) and dt.shape[0]:
        dy = dy + r.dtau_passive @ dt
    if extra is not None:
        dy = dy + Df @ extra[0].reshape(-1)
    act = np.array(active, dtype=bool)
    ia, ip = np.nonzero(act)[0], np.nonzero(~act)[0]
    if any_nonzero(dmodel):  # design derivatives of the dynamics (f_ext held fixed)
        dm = jax.tree_util.tree_map(instantiate_zero, dmodel, is_leaf=is_symbolic_zero)

        def y_of_model(m):
            ta, ap = hybrid_unchecked(m, q, v, a_active, tau_passive, active, f_ext)
            return jnp.zeros(model.nv, dtype=r.y.dtype).at[ia].set(ta).at[ip].set(ap)

        dy = dy + jax.jvp(y_of_model, (model,), (dm,))[1]
    primal = (r.y[ia], r.y[ip], f_ext, out[1])
    return primal, (dy[ia], dy[ip], dcontact[0], dcontact[1])


_ch.defjvp(_ch_jvp, symbolic_zeros=True)


def _contact_tangents(fn_c, consts, dconsts, q, v, dq, dv):
    """The contact model's value, its Jacobians w.r.t. ``x = (q, v)`` (``jacfwd``, one per
    float output leaf, shapes ``leaf.shape + (nq + nv,)``; XLA drops the unused ones),
    the JVP along nonzero tangents of its closed-over values (or None), and the tangent
    of the whole output for ``(dq, dv)``."""
    out = fn_c(q, v, *consts)
    leaves, tree = jax.tree_util.tree_flatten(out)
    fl = [i for i, y in enumerate(leaves) if is_inexact(y)]
    nq = q.shape[0]

    def fleaves(x, c):
        lv = jax.tree_util.tree_leaves(fn_c(x[:nq], x[nq:], *c))
        return [lv[i] for i in fl]

    x = jnp.concatenate([q, v])
    dx = jnp.concatenate([instantiate_zero(dq), instantiate_zero(dv)])
    Js = jax.jacfwd(fleaves)(x, consts)
    dys = [Jl @ dx for Jl in Js]
    extra = None
    if any_nonzero(dconsts):
        dc = tuple(instantiate_zero(t) for t in dconsts)
        extra = jax.jvp(lambda c: fleaves(x, c), (consts,), (dc,))[1]
        dys = [a + b for a, b in zip(dys, extra)]
    douts = [float0_zeros(y) for y in leaves]
    for i, dyi in zip(fl, dys):
        douts[i] = dyi
    return out, Js, extra, jax.tree_util.tree_unflatten(tree, douts)
