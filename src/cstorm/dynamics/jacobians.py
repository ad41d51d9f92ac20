"""Point Jacobians: the map from ``v`` to the velocity of a point fixed in a body.

``J (6, nv)`` maps v to ``[omega; pdot]`` of the point, both in world-aligned axes
(Pinocchio's LOCAL_WORLD_ALIGNED); the point is given in body coordinates.
"""

from __future__ import annotations

import jax.numpy as jnp

from .. import spatial as sp
from . import _checks
from .kinematics import joint_placements, world_placements


def ancestors(model, b):
    """Body b and its ancestors, root last (static tuple)."""
    out = []
    while b >= 0:
        out.append(b)
        b = model.parents[b]
    return tuple(out)


def point_jacobian(model, q, body, point=(0.0, 0.0, 0.0)):
    """(6, nv) Jacobian of ``[omega; pdot]`` (world-aligned) of a point fixed in ``body``.

    Args: q (nq,); body: name or index; point: (3,) in body coordinates."""
    q = _checks.config(model, q, "point_jacobian")
    b = model.body_index(body)
    Rs, ps, Ss = joint_placements(model, q)
    oR, op = world_placements(model, Rs, ps)
    return _point_jacobian(model, oR, op, Ss, b, jnp.asarray(point, dtype=q.dtype))


def _point_jacobian(model, oR, op, Ss, b, point):
    x = oR[b] @ point + op[b]
    J = jnp.zeros((6, model.nv), dtype=x.dtype)
    for j in ancestors(model, b):
        Sw = sp.act_motion(oR[j], op[j], Ss[j])  # (6, nv_j) twists about the world origin
        w, vo = Sw[:3], Sw[3:]
        lin = vo + jnp.cross(w.T, x).T
        s = model.v_starts[j]
        J = J.at[:, s: s + model.joints[j].nv].set(jnp.concatenate([w, lin]))
    return J
