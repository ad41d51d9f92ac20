"""The robot model: a kinematic tree of rigid bodies, one joint with DoFs per body.

Static topology, dynamic numbers: names, parents, joint types and index maps are Python
tuples (they key JAX's compile cache); inertias, joint placements and axes, limits and
collision-shape sizes are JAX array leaves (differentiable). Build models with
`cstorm.ModelBuilder`, `cstorm.load_urdf` or `cstorm.load_mjcf`.

Body ``i`` is the child of joint ``i``; ``parents[i]`` is its parent body index, -1 for
the world. Bodies are ordered so that ``parents[i] < i``. The joint's placement in the
parent body frame is ``(joint_R[i], joint_p[i])`` (parent from joint frame). Body
inertia: ``mass[i]``, ``com[i]`` (3,) and ``inertia[i]`` (3, 3) about the CoM, in the
body frame. Per-DoF data (length nv): ``armature`` (rotor inertia, added to the mass
matrix diagonal), ``damping`` (N m s/rad or N s/m), ``stiffness`` with ``spring_ref``
(spring rest position, 1-DoF joints), ``velocity_limit``, ``effort_limit``. Position
limits ``q_lower``/``q_upper`` have length nq (+-inf where unlimited). Collision
geometry: ``geoms`` (shapes) attached to ``geom_bodies`` (-1: the world) at
``geom_poses`` (ng, 4, 4) (body from shape). Named frames (links merged by fixed joints,
MJCF sites) live in ``frame_bodies``/``frame_poses``. ``notes`` lists what the loader
repaired or ignored (rounding noise clipped, placeholder links), one sentence each.
"""

from __future__ import annotations

import numpy as np
import jax.numpy as jnp

from .._pytree import pytree_dataclass, replace
from ..errors import ModelError
from .joints import Joint, Free, Ball


@pytree_dataclass(
    meta=("body_names", "joint_names", "parents", "joints", "q_starts", "v_starts", "geom_names", "geom_bodies",
          "frame_names", "frame_bodies"),
    labels=("name", "source", "notes"),
)
class Model:
    # --- static -----------------------------------------------------------------
    name: str
    body_names: tuple
    joint_names: tuple
    parents: tuple
    joints: tuple
    q_starts: tuple
    v_starts: tuple
    geom_names: tuple
    geom_bodies: tuple
    frame_names: tuple
    frame_bodies: tuple
    source: str
    # --- dynamic (array leaves) ----------------------------------------------------
    joint_R: jnp.ndarray  # (nb, 3, 3)
    joint_p: jnp.ndarray  # (nb, 3)
    axis: jnp.ndarray  # (nb, 3), unit (unused by free/ball joints)
    mass: jnp.ndarray  # (nb,)
    com: jnp.ndarray  # (nb, 3)
    inertia: jnp.ndarray  # (nb, 3, 3) about the CoM
    armature: jnp.ndarray  # (nv,)
    damping: jnp.ndarray  # (nv,)
    stiffness: jnp.ndarray  # (nv,)
    spring_ref: jnp.ndarray  # (nv,)
    q_lower: jnp.ndarray  # (nq,)
    q_upper: jnp.ndarray  # (nq,)
    velocity_limit: jnp.ndarray  # (nv,)
    effort_limit: jnp.ndarray  # (nv,)
    limit_stiffness: jnp.ndarray  # () penalty stiffness of position limits in passive_forces
    limit_margin: jnp.ndarray  # () width of the quadratic onset of the limit penalty
    gravity: jnp.ndarray  # (3,)
    geoms: tuple  # shapes (pytrees)
    geom_poses: jnp.ndarray  # (ng, 4, 4) body from shape
    frame_poses: jnp.ndarray  # (nf, 4, 4) body from frame
    # --- informational (does not key compilation) ------------------------------------
    notes: tuple = ()  # what the loader repaired or ignored (strings; `cstorm info` prints them)

    # --- sizes ---------------------------------------------------------------------
    @property
    def n_bodies(self) -> int:
        return len(self.parents)

    @property
    def nq(self) -> int:
        return sum(j.nq for j in self.joints)

    @property
    def nv(self) -> int:
        return sum(j.nv for j in self.joints)

    @property
    def n_geoms(self) -> int:
        return len(self.geoms)

    def __repr__(self):
        return (f"Model({self.name!r}, n_bodies={self.n_bodies}, nq={self.nq}, nv={self.nv}, "
                f"n_geoms={self.n_geoms})")

    # --- index maps -------------------------------------------------------------------
    def _joint_index(self, name: str) -> int:
        try:
            return self.joint_names.index(name)
        except ValueError:
            raise ModelError(
                f"model {self.name!r}: no joint named {name!r}; joints with DoFs are {list(self.joint_names)}"
            ) from None

    def joint_q(self, name: str) -> slice:
        """Slice of ``q`` holding joint ``name``'s configuration."""
        i = self._joint_index(name)
        return slice(self.q_starts[i], self.q_starts[i] + self.joints[i].nq)

    def joint_v(self, name: str) -> slice:
        """Slice of ``v`` (and of ``a``, ``tau``) holding joint ``name``'s velocity."""
        i = self._joint_index(name)
        return slice(self.v_starts[i], self.v_starts[i] + self.joints[i].nv)

    def active_mask(self, names) -> tuple:
        """Tuple of nv bools, True for the DoFs of the named joints."""
        if isinstance(names, str):
            names = [names]
        mask = [False] * self.nv
        for n in names:
            s = self.joint_v(n)
            for k in range(s.start, s.stop):
                mask[k] = True
        return tuple(mask)

    def body_index(self, body) -> int:
        """Body index from a name or an index (validated)."""
        if isinstance(body, (int, np.integer)):
            if not -self.n_bodies <= int(body) < self.n_bodies:
                raise ModelError(f"model {self.name!r}: body index {body} out of range [0, {self.n_bodies})")
            return int(body) % self.n_bodies
        try:
            return self.body_names.index(body)
        except ValueError:
            pass
        if body in self.frame_names:
            return self.frame_bodies[self.frame_names.index(body)]
        raise ModelError(f"model {self.name!r}: no body named {body!r}; bodies are {list(self.body_names)}")

    def frame_pose(self, name: str):
        """(body index, (4, 4) body-from-frame pose) of a named frame or body."""
        if name in self.body_names:
            return self.body_names.index(name), jnp.eye(4)
        if name in self.frame_names:
            k = self.frame_names.index(name)
            return self.frame_bodies[k], self.frame_poses[k]
        raise ModelError(f"model {self.name!r}: no frame or body named {name!r}")

    def children(self, i: int) -> tuple:
        return tuple(k for k, p in enumerate(self.parents) if p == i)

    def subtree(self, i: int) -> tuple:
        """Body i and all its descendants (ordered)."""
        out = [i]
        for k in range(i + 1, self.n_bodies):
            if self.parents[k] in out:
                out.append(k)
        return tuple(out)

    def dof_joint(self) -> tuple:
        """For each velocity DoF, the index of its joint/body."""
        return tuple(i for i, j in enumerate(self.joints) for _ in range(j.nv))

    # --- configurations ---------------------------------------------------------------
    def neutral(self) -> np.ndarray:
        """Neutral configuration (nq,): zeros, identity quaternions, clipped into limits."""
        q = np.concatenate([j.neutral() for j in self.joints]) if self.joints else np.zeros(0)
        lo, hi = np.asarray(self.q_lower), np.asarray(self.q_upper)
        one_dof = np.array([j.nq == 1 for j in self.joints for _ in range(j.nq)], dtype=bool)
        q[one_dof] = np.clip(q[one_dof], lo[one_dof], hi[one_dof])
        return q

    def random_q(self, rng: np.random.Generator) -> np.ndarray:
        """A random configuration within limits (unlimited angles in [-pi, pi])."""
        lo, hi = np.asarray(self.q_lower), np.asarray(self.q_upper)
        parts = []
        for j, s in zip(self.joints, self.q_starts):
            parts.append(j.random(rng, lo[s], hi[s]) if j.nq == 1 else j.random(rng))
        return np.concatenate(parts)

    def has_quaternions(self) -> bool:
        return any(isinstance(j, (Free, Ball)) for j in self.joints)

    def replace(self, **changes) -> "Model":
        """Copy with some array fields changed (e.g. ``mass=...`` for design studies)."""
        return replace(self, **changes)
