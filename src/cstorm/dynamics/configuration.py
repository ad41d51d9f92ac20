"""Operations on the configuration manifold: integrate, difference, normalize.

``integrate(model, q, v, dt)`` moves every joint along ``v * dt`` by its group
exponential (body-frame increments for free and ball joints); ``difference(model, q0,
q1)`` returns the (nv,) tangent ``v`` with ``integrate(model, q0, v) == q1``.
"""

from __future__ import annotations

import jax.numpy as jnp

from . import _checks
from ..model.joints import Ball, Free


def integrate(model, q, v, dt=1.0):
    """q (+) v dt: (nq,) configuration reached from q (nq,) along v (nv,) in time dt."""
    q = _checks.vec(model, q, model.nq, "q", "integrate")
    v = _checks.vec(model, v, model.nv, "v", "integrate")
    out = []
    for j, qs, vs in zip(model.joints, model.q_starts, model.v_starts):
        out.append(j.integrate(q[qs: qs + j.nq], dt * v[vs: vs + j.nv]))
    return jnp.concatenate(out)


def difference(model, q0, q1):
    """Tangent (nv,) from q0 to q1 (both (nq,))."""
    q0 = _checks.vec(model, q0, model.nq, "q0", "difference")
    q1 = _checks.vec(model, q1, model.nq, "q1", "difference")
    out = []
    for j, qs in zip(model.joints, model.q_starts):
        out.append(j.difference(q0[qs: qs + j.nq], q1[qs: qs + j.nq]))
    return jnp.concatenate(out)


def normalize(model, q):
    """q (nq,) with every quaternion scaled to unit norm."""
    q = jnp.asarray(q)
    for j, s in zip(model.joints, model.q_starts):
        if isinstance(j, (Free, Ball)):
            k = s + 3 if isinstance(j, Free) else s
            quat = q[k: k + 4]
            q = q.at[k: k + 4].set(quat / jnp.sqrt(jnp.sum(quat * quat)))
    return q
