"""Recursive Newton-Euler algorithm: inverse dynamics (Featherstone, RBDA table 5.1),
in body-local frames.

``tau = M(q) a + C(q, v) v + g(q) - sum_i J_i(q)^T f_ext_i`` (armature included in M).
"""

from __future__ import annotations

import jax.numpy as jnp

from .. import spatial as sp
from . import _checks
from .kinematics import joint_placements, world_placements


def body_spatial_inertias(model):
    """(6, 6) spatial inertias of the bodies about their frame origins (list)."""
    return [sp.spatial_inertia(model.mass[i], model.com[i], model.inertia[i]) for i in range(model.n_bodies)]


def external_wrenches_local(model, oR, op, f_ext):
    """World wrenches ``[torque about world origin; force]`` (n_bodies, 6) -> body frames."""
    if f_ext is None:
        return [None] * model.n_bodies
    return [sp.inv_act_force(oR[i], op[i], f_ext[i]) for i in range(model.n_bodies)]


def gravity_acceleration(model):
    """Spatial acceleration of the world frame that emulates gravity: ``[0; -g]``."""
    return jnp.concatenate([jnp.zeros(3, dtype=model.gravity.dtype), -model.gravity])


def rnea(model, q, v, a, f_ext=None):
    """Joint forces that produce acceleration ``a``.

    Args:
        q: (nq,) configuration. v: (nv,) velocity. a: (nv,) acceleration.
        f_ext: optional (n_bodies, 6) external wrenches on the bodies, world coordinates,
            ``[torque about the world origin; force]``.
    Returns: tau (nv,).
    """
    q = _checks.config(model, q, "rnea")
    v = _checks.vec(model, v, model.nv, "v", "rnea")
    a = _checks.vec(model, a, model.nv, "a", "rnea")
    f_ext = _checks.fext(model, f_ext, "rnea")
    return rnea_unchecked(model, q, v, a, f_ext)


def rnea_unchecked(model, q, v, a, f_ext):
    """`rnea` without input checks (arrays of the right shapes; ``f_ext`` may be None)."""
    Rs, ps, Ss = joint_placements(model, q)
    fl = external_wrenches_local(model, *world_placements(model, Rs, ps), f_ext) if f_ext is not None else [None] * model.n_bodies
    I = body_spatial_inertias(model)
    a0 = gravity_acceleration(model)
    vs, acc, fs = [], [], []
    for i, par in enumerate(model.parents):
        sl = slice(model.v_starts[i], model.v_starts[i] + model.joints[i].nv)
        vJ = sp.mv(Ss[i], v[sl])
        vp = jnp.zeros(6, dtype=v.dtype) if par < 0 else vs[par]
        ap = a0 if par < 0 else acc[par]
        vi = sp.inv_act_motion(Rs[i], ps[i], vp) + vJ
        ai = sp.inv_act_motion(Rs[i], ps[i], ap) + sp.mv(Ss[i], a[sl]) + sp.cross_motion(vi, vJ)
        fi = sp.mv(I[i], ai) + sp.cross_force(vi, sp.mv(I[i], vi))
        if fl[i] is not None:
            fi = fi - fl[i]
        vs.append(vi), acc.append(ai), fs.append(fi)
    tau = [None] * model.n_bodies
    for i in reversed(range(model.n_bodies)):
        sl = slice(model.v_starts[i], model.v_starts[i] + model.joints[i].nv)
        tau[i] = sp.mv(Ss[i].T, fs[i]) + model.armature[sl] * a[sl]
        par = model.parents[i]
        if par >= 0:
            fs[par] = fs[par] + sp.act_force(Rs[i], ps[i], fs[i])
    return jnp.concatenate(tau)


def bias_forces(model, q, v, f_ext=None):
    """``C(q, v) v + g(q) - J^T f_ext`` (nv,): `rnea` with zero acceleration."""
    q = _checks.config(model, q, "bias_forces")
    v = _checks.vec(model, v, model.nv, "v", "bias_forces")
    f_ext = _checks.fext(model, f_ext, "bias_forces")
    return rnea_unchecked(model, q, v, jnp.zeros(model.nv, dtype=v.dtype), f_ext)


def gravity_forces(model, q):
    """Generalized gravity ``g(q)`` (nv,)."""
    q = _checks.config(model, q, "gravity_forces")
    z = jnp.zeros(model.nv, dtype=q.dtype)
    return rnea_unchecked(model, q, z, z, None)
