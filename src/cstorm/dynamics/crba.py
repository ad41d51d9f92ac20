"""Composite rigid body algorithm: the joint-space mass matrix (Featherstone, RBDA 6.2).

``M(q)`` (nv, nv), symmetric positive definite, armature added to the diagonal.
"""

from __future__ import annotations

import jax.numpy as jnp

from .. import spatial as sp
from . import _checks
from .kinematics import joint_placements
from .rnea import body_spatial_inertias


def mass_matrix(model, q):
    """Joint-space inertia matrix M (nv, nv) at configuration q (nq,)."""
    q = _checks.config(model, q, "mass_matrix")
    Rs, ps, Ss = joint_placements(model, q)
    Ic = body_spatial_inertias(model)
    nb = model.n_bodies
    for i in reversed(range(nb)):
        par = model.parents[i]
        if par >= 0:
            Ic[par] = Ic[par] + sp.transform_inertia(Rs[i], ps[i], Ic[i])
    M = jnp.zeros((model.nv, model.nv), dtype=q.dtype)
    for i in range(nb):
        si = model.v_starts[i]
        ni = model.joints[i].nv
        F = Ic[i] @ Ss[i]  # (6, ni) in body i
        M = M.at[si: si + ni, si: si + ni].set(Ss[i].T @ F)
        j = i
        while model.parents[j] >= 0:
            F = sp.act_force(Rs[j], ps[j], F)
            j = model.parents[j]
            sj, nj = model.v_starts[j], model.joints[j].nv
            blk = Ss[j].T @ F  # (nj, ni)
            M = M.at[sj: sj + nj, si: si + ni].set(blk)
            M = M.at[si: si + ni, sj: sj + nj].set(blk.T)
    return M + jnp.diag(model.armature)
