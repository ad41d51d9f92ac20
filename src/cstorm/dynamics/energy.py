"""Energies and centre of mass.

Kinetic energy includes the armature's rotor energy ``1/2 armature v^2`` (consistent with
the mass matrix, so it is conserved by torque-free rollouts). Potential energy is
``-sum_i m_i g . c_i`` (zero at the world origin's height).
"""

from __future__ import annotations

import jax.numpy as jnp

from .. import spatial as sp
from . import _checks
from .kinematics import body_velocities, joint_placements, world_placements


def kinetic_energy(model, q, v):
    """Scalar kinetic energy (J) at q (nq,), v (nv,)."""
    vb = body_velocities(model, q, v)
    T = 0.5 * jnp.sum(model.armature * v * v)
    for i in range(model.n_bodies):
        I = sp.spatial_inertia(model.mass[i], model.com[i], model.inertia[i])
        T = T + 0.5 * vb[i] @ I @ vb[i]
    return T


def _com_world(model, q):
    Rs, ps, _ = joint_placements(model, q)
    oR, op = world_placements(model, Rs, ps)
    return jnp.stack([oR[i] @ model.com[i] + op[i] for i in range(model.n_bodies)])


def potential_energy(model, q):
    """Scalar gravitational potential energy (J) at q (nq,)."""
    q = _checks.config(model, q, "potential_energy")
    return -jnp.sum(model.mass * (_com_world(model, q) @ model.gravity))


def center_of_mass(model, q):
    """(3,) world position of the robot's centre of mass."""
    q = _checks.config(model, q, "center_of_mass")
    return jnp.sum(model.mass[:, None] * _com_world(model, q), axis=0) / jnp.sum(model.mass)
