"""Forward kinematics: joint placements, world poses and body velocities of a tree.

Frames: body ``i``'s frame is its joint's child frame. ``(R_i, p_i)`` returned by
`joint_placements` is "parent body from body i"; `world_placements` composes them to
"world from body i". Velocities are body twists ``[omega; v]`` of the body frame origin,
in body coordinates (Pinocchio's LOCAL).
"""

from __future__ import annotations

import jax.numpy as jnp

from .. import spatial as sp
from . import _checks


def joint_placements(model, q):
    """Per body: ``(R, p)`` parent-body-from-body and the motion subspace ``S`` (6, nv_j).

    q: (nq,). Returns three lists of length n_bodies."""
    Rs, ps, Ss = [], [], []
    for i, j in enumerate(model.joints):
        s = model.q_starts[i]
        RJ, pJ = j.transform(model.axis[i], q[s: s + j.nq])
        R, p = sp.compose(model.joint_R[i], model.joint_p[i], RJ, pJ)
        Rs.append(R), ps.append(p), Ss.append(j.motion_subspace(model.axis[i]))
    return Rs, ps, Ss


def world_placements(model, Rs, ps):
    """Compose parent-from-body placements into world-from-body (lists of R, p)."""
    oR, op = [], []
    for i, par in enumerate(model.parents):
        if par < 0:
            oR.append(Rs[i]), op.append(ps[i])
        else:
            R, p = sp.compose(oR[par], op[par], Rs[i], ps[i])
            oR.append(R), op.append(p)
    return oR, op


def forward_kinematics(model, q):
    """World poses of all bodies.

    Args: q (nq,). Returns: (n_bodies, 4, 4) homogeneous transforms, world from body."""
    q = _checks.config(model, q, "forward_kinematics")
    Rs, ps, _ = joint_placements(model, q)
    oR, op = world_placements(model, Rs, ps)
    return sp.homogeneous(jnp.stack(oR), jnp.stack(op))


def body_velocities(model, q, v):
    """Body twists (n_bodies, 6): ``[omega; v]`` of each body frame's origin relative to
    the world, in body coordinates."""
    q = _checks.config(model, q, "body_velocities")
    v = _checks.vec(model, v, model.nv, "v", "body_velocities")
    Rs, ps, Ss = joint_placements(model, q)
    vs = []
    for i, par in enumerate(model.parents):
        vj = Ss[i] @ v[model.v_starts[i]: model.v_starts[i] + model.joints[i].nv]
        vs.append(vj if par < 0 else sp.inv_act_motion(Rs[i], ps[i], vs[par]) + vj)
    return jnp.stack(vs)


def frame_pose(model, q, name):
    """(4, 4) world pose of a named frame or body."""
    b, T = model.frame_pose(name)
    if b < 0:  # a frame welded to the world (e.g. a fixed-base robot's root link)
        q = _checks.config(model, q, "frame_pose")
        return jnp.asarray(T, dtype=q.dtype)
    return forward_kinematics(model, q)[b] @ T


def world_twists(model, Rs, ps, Ss, oR, v):
    """World-aligned angular velocity and body-origin velocity, each (n_bodies, 3)."""
    vs = []
    for i, par in enumerate(model.parents):
        vj = Ss[i] @ v[model.v_starts[i]: model.v_starts[i] + model.joints[i].nv]
        vs.append(vj if par < 0 else sp.inv_act_motion(Rs[i], ps[i], vs[par]) + vj)
    tw = jnp.stack(vs)
    R = jnp.stack(oR)
    return jnp.einsum("bij,bj->bi", R, tw[:, :3]), jnp.einsum("bij,bj->bi", R, tw[:, 3:])
