"""Joint types: one final class per type, all with the same small interface.

A joint connects a parent body to a child body. Its placement in the parent body frame is
model data (`Model.joint_R`, `Model.joint_p`); the joint's own displacement
``transform(axis, q_j) -> (R, p)`` is "joint frame from child frame". Velocities are the
child's twist relative to the parent, expressed in the child frame, so the motion
subspace ``S`` (6, nv) is constant for every type here and the bias ``c = v x (S v_j)``.

| type      | nq | nv | q                                | v                        |
|-----------|----|----|----------------------------------|--------------------------|
| Revolute  | 1  | 1  | angle about `axis` (rad)         | angular rate             |
| Prismatic | 1  | 1  | displacement along `axis` (m)    | linear rate              |
| Free      | 7  | 6  | [x y z qw qx qy qz] in parent    | [omega_body; v_body]     |
| Ball      | 4  | 3  | [qw qx qy qz]                    | omega_body               |

`integrate` uses the group exponential (right multiplication: body-frame increments);
`difference(q0, q1)` is its inverse: ``integrate(q0, difference(q0, q1)) == q1``.
"""

from __future__ import annotations

import numpy as np
import jax.numpy as jnp

from .. import spatial as sp


class Joint:
    """Abstract joint type. Instances are stateless and hashable (static model data)."""

    name: str = "joint"
    nq: int = 0
    nv: int = 0

    def __eq__(self, other):
        return type(self) is type(other)

    def __hash__(self):
        return hash(type(self).__name__)

    def __repr__(self):
        return type(self).__name__ + "()"

    def neutral(self) -> np.ndarray:
        return np.zeros(self.nq)

    def integrate(self, qj, vj):
        return qj + vj

    def difference(self, q0, q1):
        return q1 - q0

    def random(self, rng: np.random.Generator, lower=None, upper=None) -> np.ndarray:
        lo = -np.pi if lower is None or not np.isfinite(lower) else lower
        hi = np.pi if upper is None or not np.isfinite(upper) else upper
        return rng.uniform(lo, hi, size=self.nq)


class Revolute(Joint):
    name, nq, nv = "revolute", 1, 1

    def transform(self, axis, qj):
        # Rodrigues with a unit axis: R = I + sin(q) K + (1 - cos(q)) K^2, K = [axis]x
        K = sp.skew(axis)
        c, s = sp.cos_sin(qj[0])
        R = jnp.eye(3, dtype=axis.dtype) + s * K + (1.0 - c) * sp.mm(K, K)
        return R, jnp.zeros(3, dtype=axis.dtype)

    def motion_subspace(self, axis):
        return jnp.concatenate([axis, jnp.zeros(3, dtype=axis.dtype)])[:, None]


class Prismatic(Joint):
    name, nq, nv = "prismatic", 1, 1

    def transform(self, axis, qj):
        return jnp.eye(3, dtype=axis.dtype), axis * qj[0]

    def motion_subspace(self, axis):
        return jnp.concatenate([jnp.zeros(3, dtype=axis.dtype), axis])[:, None]

    def random(self, rng, lower=None, upper=None):
        lo = -0.5 if lower is None or not np.isfinite(lower) else lower
        hi = 0.5 if upper is None or not np.isfinite(upper) else upper
        return rng.uniform(lo, hi, size=1)


class Free(Joint):
    name, nq, nv = "free", 7, 6

    def transform(self, axis, qj):
        return sp.quat_to_rot(qj[3:7]), qj[:3]

    def motion_subspace(self, axis):
        return jnp.eye(6, dtype=axis.dtype)

    def neutral(self):
        return np.array([0.0, 0, 0, 1, 0, 0, 0])

    def integrate(self, qj, vj):
        R = sp.quat_to_rot(qj[3:7])
        dR, dp = sp.se3_exp(vj)
        quat = sp.quat_mul(qj[3:7], sp.quat_exp(vj[:3]))
        return jnp.concatenate([qj[:3] + R @ dp, quat])

    def difference(self, q0, q1):
        R0, R1 = sp.quat_to_rot(q0[3:7]), sp.quat_to_rot(q1[3:7])
        Ri, pi = sp.inverse(R0, q0[:3])
        R, p = sp.compose(Ri, pi, R1, q1[:3])
        # rotation part through quaternions: exact and safe at identity
        dq = sp.quat_mul(sp.quat_conj(q0[3:7]), q1[3:7])
        twist = sp.se3_log(R, p)
        return jnp.concatenate([sp.quat_log(dq), twist[3:]])

    def random(self, rng, lower=None, upper=None):
        quat = rng.normal(size=4)
        return np.concatenate([rng.uniform(-1, 1, size=3), quat / np.linalg.norm(quat)])


class Ball(Joint):
    name, nq, nv = "ball", 4, 3

    def transform(self, axis, qj):
        return sp.quat_to_rot(qj), jnp.zeros(3, dtype=qj.dtype)

    def motion_subspace(self, axis):
        return jnp.concatenate([jnp.eye(3, dtype=axis.dtype), jnp.zeros((3, 3), dtype=axis.dtype)])

    def neutral(self):
        return np.array([1.0, 0, 0, 0])

    def integrate(self, qj, vj):
        return sp.quat_mul(qj, sp.quat_exp(vj))

    def difference(self, q0, q1):
        return sp.quat_log(sp.quat_mul(sp.quat_conj(q0), q1))

    def random(self, rng, lower=None, upper=None):
        quat = rng.normal(size=4)
        return quat / np.linalg.norm(quat)


JOINT_TYPES = {"revolute": Revolute, "continuous": Revolute, "hinge": Revolute, "prismatic": Prismatic,
               "slide": Prismatic, "free": Free, "floating": Free, "ball": Ball, "spherical": Ball}
