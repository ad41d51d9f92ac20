"""Passive joint forces: viscous damping, linear springs and position-limit penalties.

``tau_passive(q, v) = -damping * v - stiffness * (q - spring_ref) + tau_limit`` per DoF;
springs and limits act on 1-DoF joints only. The limit force is a C1 penalty: with the
violation ``delta`` (metres or radians beyond the limit) and margin ``w``,
``limit_stiffness * (delta^2 / (2 w) if delta < w else delta - w / 2)``, pushing back
into the range. ``limit_stiffness = 0`` (the default) turns limits off here; rigid-body
algorithms never add these forces themselves: callers (rollouts) do.
"""

from __future__ import annotations

import numpy as np
import jax.numpy as jnp

from . import _checks


def one_dof_indices(model):
    """Static (q index, v index) arrays of the 1-DoF joints."""
    qi = np.array([s for j, s in zip(model.joints, model.q_starts) if j.nq == 1], dtype=int)
    vi = np.array([s for j, s in zip(model.joints, model.v_starts) if j.nv == 1], dtype=int)
    return qi, vi


def _onset(delta, w):
    d = jnp.clip(delta, 0.0, 1e6)
    return jnp.where(d < w, d * d / (2.0 * w), d - 0.5 * w)


def passive_forces(model, q, v):
    """(nv,) joint forces from damping, springs and limit penalties at q (nq,), v (nv,)."""
    q = _checks.config(model, q, "passive_forces")
    v = _checks.vec(model, v, model.nv, "v", "passive_forces")
    tau = -model.damping * v
    qi, vi = one_dof_indices(model)
    if len(qi):
        qj = q[qi]
        spring = -model.stiffness[vi] * (qj - model.spring_ref[vi])
        w = model.limit_margin
        lim = model.limit_stiffness * (_onset(model.q_lower[qi] - qj, w) - _onset(qj - model.q_upper[qi], w))
        tau = tau.at[vi].add(spring + lim)
    return tau
