"""Describe a robot by hand (links, joints, inertias, shapes) and build a `Model`.

The builder is link-and-joint based, like URDF; the loaders use it too. Links joined by
fixed joints are merged into one body (inertias added; their frames and collision shapes
kept, re-expressed in the body frame, with the merged links available as named frames).

Example (a two-link pendulum hanging from the world)::

    b = cs.ModelBuilder("pendulum")
    b.add_body("upper", joint="revolute", axis=(0, 1, 0), mass=1.0, com=(0, 0, -0.25),
               inertia=(0.02, 0.02, 1e-4))
    b.add_body("lower", parent="upper", joint="revolute", axis=(0, 1, 0), xyz=(0, 0, -0.5),
               mass=1.0, com=(0, 0, -0.25), inertia=(0.02, 0.02, 1e-4))
    b.add_geom("lower", cs.Sphere(0.05), xyz=(0, 0, -0.5))
    model = b.build()

Units SI; angles in rad; ``rpy`` is URDF's fixed-axis roll-pitch-yaw, R = Rz(y) Ry(p) Rx(r).
"""

from __future__ import annotations

import dataclasses
import os
import warnings

import numpy as np
import jax.numpy as jnp

from ..errors import ModelError
from ..geometry.shapes import Shape
from .inertia import INERTIA_CHECKS, judge_bodies, link_inertia
from .joints import JOINT_TYPES, Ball, Free, Prismatic, Revolute
from .model import Model


def rpy_to_matrix(rpy) -> np.ndarray:
    r, p, y = (float(a) for a in rpy)
    cr, sr, cp, spi, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, spi], [0, 1, 0], [-spi, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def make_pose(pose=None, xyz=None, rpy=None, R=None, where="") -> np.ndarray:
    """(4, 4) pose from a 4x4 matrix, or from xyz and rpy / R."""
    if pose is not None:
        T = np.asarray(pose, dtype=float)
        if T.shape != (4, 4):
            raise ModelError(f"{where}: pose must be (4, 4), got {T.shape}")
        return T
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = np.asarray(R, dtype=float)
    elif rpy is not None:
        T[:3, :3] = rpy_to_matrix(rpy)
    if xyz is not None:
        p = np.asarray(xyz, dtype=float)
        if p.shape != (3,):
            raise ModelError(f"{where}: xyz must have 3 entries, got {p.shape}")
        T[:3, 3] = p
    if not np.all(np.isfinite(T)):
        raise ModelError(f"{where}: pose contains NaN or inf")
    return T


@dataclasses.dataclass
class _Link:
    name: str
    mass: float
    com: np.ndarray
    inertia: np.ndarray


@dataclasses.dataclass
class _JointSpec:
    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray
    axis: np.ndarray
    lower: float = -np.inf
    upper: float = np.inf
    velocity: float = np.inf
    effort: float = np.inf
    damping: float = 0.0
    armature: float = 0.0
    stiffness: float = 0.0
    spring_ref: float = 0.0


class ModelBuilder:
    """Collects links, joints, collision shapes and frames; `build()` makes a `Model`."""

    def __init__(self, name: str = "robot", gravity=(0.0, 0.0, -9.81), source: str = "<builder>",
                 inertia_check: str = "warn"):
        """``inertia_check``: ``"warn"`` (default; ``"lenient"`` is a synonym) loads an
        implausible but computable inertia (triangle inequality violated) with one
        `ModelWarning` per body; ``"strict"`` makes it a `ModelError`. What the dynamics
        cannot survive is an error either way. See `cstorm.model.inertia`."""
        if inertia_check not in INERTIA_CHECKS:
            raise ModelError(f"{source}: inertia_check must be one of {list(INERTIA_CHECKS)}, got {inertia_check!r}")
        self.inertia_check = inertia_check
        self.name = name
        self.gravity = np.asarray(gravity, dtype=float)
        self.source = source
        self.links: dict[str, _Link] = {}
        self.joints: dict[str, _JointSpec] = {}
        self.geoms: list[tuple[str, str, Shape, np.ndarray]] = []
        self.frames: list[tuple[str, str, np.ndarray]] = []
        self.limit_stiffness = 0.0
        self.limit_margin = 0.01

    def _where(self, kind, name):
        return f"{self.source}: {kind} {name!r}"

    # --- description ----------------------------------------------------------------
    def add_link(self, name: str, mass=0.0, com=(0.0, 0.0, 0.0), inertia=None):
        """A link with mass (kg), CoM (3,) and inertia about the CoM in the link frame:
        (3, 3), principal (3,) or URDF-ordered (ixx, ixy, ixz, iyy, iyz, izz)."""
        if name in self.links:
            raise ModelError(f"{self._where('link', name)} is defined twice")
        m, c, I = link_inertia(mass, com, inertia, self._where("link", name))
        self.links[name] = _Link(name, m, c, I)
        return self

    def add_joint(self, name: str, type: str, parent: str, child: str, *, pose=None, xyz=None, rpy=None,
                  R=None, axis=(0.0, 0.0, 1.0), lower=-np.inf, upper=np.inf, velocity=np.inf, effort=np.inf,
                  damping=0.0, armature=0.0, stiffness=0.0, spring_ref=0.0):
        """A joint from link ``parent`` to link ``child``. ``type``: revolute, continuous,
        prismatic, free, ball or fixed. Its frame in the parent link frame is ``pose`` or
        ``xyz``/``rpy``/``R``; ``axis`` in the joint frame."""
        where = self._where("joint", name)
        if name in self.joints:
            raise ModelError(f"{where} is defined twice")
        t = type.lower()
        if t != "fixed" and t not in JOINT_TYPES:
            raise ModelError(f"{where}: unknown joint type {type!r}; known: fixed, {', '.join(sorted(JOINT_TYPES))}")
        ax = np.asarray(axis, dtype=float)
        if t in ("revolute", "continuous", "hinge", "prismatic", "slide"):
            n = np.linalg.norm(ax) if ax.shape == (3,) else 0.0
            if not np.isfinite(n) or n < 1e-12:
                raise ModelError(f"{where}: axis must be a non-zero 3-vector, got {axis}")
            ax = ax / n
        else:
            ax = np.array([0.0, 0.0, 1.0])
        lo, hi = float(lower), float(upper)
        if t == "continuous":
            lo, hi = -np.inf, np.inf
        if not lo <= hi:
            raise ModelError(f"{where}: lower limit {lo} exceeds upper limit {hi}")
        for k, val in dict(velocity=velocity, effort=effort, damping=damping, armature=armature,
                           stiffness=stiffness).items():
            if not float(val) >= 0:
                raise ModelError(f"{where}: {k} must be >= 0, got {val}")
        self.joints[name] = _JointSpec(name, t, parent, child, make_pose(pose, xyz, rpy, R, where), ax, lo, hi,
                                       float(velocity), float(effort), float(damping), float(armature),
                                       float(stiffness), float(spring_ref))
        return self

    def add_body(self, name: str, parent: str | None = None, joint: str = "revolute", joint_name: str | None = None,
                 *, mass=0.0, com=(0.0, 0.0, 0.0), inertia=None, **joint_kwargs):
        """Shorthand: a link plus the joint that attaches it to ``parent`` (None: the world
        link ``"world"``, created on first use). The joint is named ``joint_name`` or the
        link's name."""
        if parent is None:
            parent = "world"
            if "world" not in self.links:
                self.add_link("world")
        self.add_link(name, mass, com, inertia)
        self.add_joint(joint_name or name, joint, parent, name, **joint_kwargs)
        return self

    def add_geom(self, link: str, shape: Shape, *, pose=None, xyz=None, rpy=None, R=None, name: str | None = None):
        """A collision shape attached to ``link`` at a pose (link from shape)."""
        if not isinstance(shape, Shape):
            raise ModelError(f"{self._where('link', link)}: geom must be a cstorm shape, got {type(shape).__name__}")
        name = name or f"{link}_geom{sum(1 for g in self.geoms if g[1] == link)}"
        self.geoms.append((name, link, shape, make_pose(pose, xyz, rpy, R, self._where("geom", name))))
        return self

    def add_frame(self, name: str, link: str, *, pose=None, xyz=None, rpy=None, R=None):
        """A named frame fixed to ``link`` (e.g. a foot sole, a tool tip)."""
        self.frames.append((name, link, make_pose(pose, xyz, rpy, R, self._where("frame", name))))
        return self

    # --- build ------------------------------------------------------------------------
    def build(self, floating_base: str | None = None) -> Model:
        """Resolve the tree, merge fixed joints, validate, and return the `Model`.

        ``floating_base``: None (the root link is fixed to the world), ``"free"`` (a free
        joint named ``root``) or ``"planar"`` (``root_x``, ``root_z`` prismatic along x, z
        and ``root_pitch`` revolute about y, in this order)."""
        src = self.source
        if not self.links:
            raise ModelError(f"{src}: the model has no links")
        children_of: dict[str, list[_JointSpec]] = {n: [] for n in self.links}
        parent_joint: dict[str, _JointSpec] = {}
        for j in self.joints.values():
            for role, ln in (("parent", j.parent), ("child", j.child)):
                if ln not in self.links:
                    raise ModelError(f"{self._where('joint', j.name)}: {role} link {ln!r} does not exist")
            if j.child in parent_joint:
                raise ModelError(
                    f"{self._where('joint', j.name)}: link {j.child!r} already has parent joint "
                    f"{parent_joint[j.child].name!r} (a link can have only one parent; kinematic loops are not supported)"
                )
            parent_joint[j.child] = j
            children_of[j.parent].append(j)
        roots = [n for n in self.links if n not in parent_joint]
        if not roots:
            raise ModelError(f"{src}: no root link: the joints form a cycle")
        if len(roots) > 1:
            raise ModelError(f"{src}: several root links {roots}: every link but one must be the child of a joint")
        root = roots[0]

        joints = dict(self.joints)
        links = dict(self.links)
        if floating_base not in (None, "free", "planar"):
            raise ModelError(f"{src}: floating_base must be None, 'free' or 'planar', got {floating_base!r}")
        world = "__world__"
        links[world] = _Link(world, 0.0, np.zeros(3), np.zeros((3, 3)))
        I4 = np.eye(4)
        if floating_base == "free":
            joints["root"] = _JointSpec("root", "free", world, root, I4, np.array([0.0, 0, 1]))
        elif floating_base == "planar":
            links["__root_x__"] = _Link("__root_x__", 0.0, np.zeros(3), np.zeros((3, 3)))
            links["__root_z__"] = _Link("__root_z__", 0.0, np.zeros(3), np.zeros((3, 3)))
            joints["root_x"] = _JointSpec("root_x", "prismatic", world, "__root_x__", I4, np.array([1.0, 0, 0]))
            joints["root_z"] = _JointSpec("root_z", "prismatic", "__root_x__", "__root_z__", I4, np.array([0.0, 0, 1]))
            joints["root_pitch"] = _JointSpec("root_pitch", "revolute", "__root_z__", root, I4, np.array([0.0, 1, 0]))
        else:
            joints["__fix_root__"] = _JointSpec("__fix_root__", "fixed", world, root, I4, np.array([0.0, 0, 1]))
        children: dict[str, list[_JointSpec]] = {n: [] for n in links}
        for j in joints.values():
            children[j.parent].append(j)

        # depth-first pre-order traversal, children in the order their joints were added
        # (URDF file order; MuJoCo's body order, so an MJCF model's q is MuJoCo's qpos):
        # bodies in an order with parent < child
        link_body: dict[str, int] = {world: -1}
        link_pose: dict[str, np.ndarray] = {world: I4}
        bodies: list[dict] = []
        stack: list[tuple[str, _JointSpec | None]] = [(world, None)]
        visited = set()
        while stack:
            ln, j = stack.pop()
            if ln in visited:
                raise ModelError(f"{src}: link {ln!r} is reached twice: the joints form a cycle")
            visited.add(ln)
            if j is not None:
                T = link_pose[j.parent] @ j.origin
                if j.type == "fixed":
                    link_body[ln] = link_body[j.parent]
                    link_pose[ln] = T
                else:
                    bodies.append(dict(name=ln, joint=j, parent=link_body[j.parent], T=T))
                    link_body[ln] = len(bodies) - 1
                    link_pose[ln] = I4
            for jc in reversed(children[ln]):
                stack.append((jc.child, jc))
        unreached = [n for n in self.links if n not in link_body]
        if unreached:
            raise ModelError(f"{src}: links {unreached} are not connected to the root {root!r} (a cycle?)")
        nb = len(bodies)
        if nb == 0:
            raise ModelError(f"{src}: the model has no moving joints (every joint is fixed): there are no dynamics to "
                             "compute; load it with floating_base='free' to move it as one rigid body")

        # accumulate inertias in body frames
        Isp = [np.zeros((6, 6)) for _ in range(nb)]
        for ln, L in links.items():
            b = link_body[ln]
            if b < 0 or L.mass == 0 and not np.any(L.inertia):
                continue
            T = link_pose[ln]
            I_link = _np_spatial_inertia(L.mass, L.com, L.inertia)
            Isp[b] += _np_transform_inertia(T[:3, :3], T[:3, 3], I_link)
        mass, com, inertia = [], [], []
        for b in range(nb):
            m = Isp[b][3, 3]
            if m > 0:
                m_, c_, Ic_ = _np_inertia_parts(Isp[b])
            else:
                m_, c_, Ic_ = 0.0, np.zeros(3), Isp[b][:3, :3]
            mass.append(float(m_)), com.append(c_), inertia.append(0.5 * (Ic_ + Ic_.T))
        body_links: dict[int, list[str]] = {b: [bd["name"]] for b, bd in enumerate(bodies)}
        body_links[-1] = []
        for ln in self.links:
            b = link_body[ln]
            if b < 0 or ln != bodies[b]["name"]:
                body_links[b].append(ln)
        inertia, notes = judge_bodies(src, [bd["name"] for bd in bodies], body_links, mass, inertia,
                                      {ln: (L.mass, L.inertia) for ln, L in links.items()},
                                      getattr(self, "inertia_check", "warn"))

        depth = [0] * nb
        for b, bd in enumerate(bodies):
            depth[b] = 1 + (depth[bd["parent"]] if bd["parent"] >= 0 else 0)
        check_size(src, nb, sum(JOINT_TYPES[bd["joint"].type].nv for bd in bodies), sum(depth))
        jtypes = []
        per_dof = {k: [] for k in ("armature", "damping", "stiffness", "spring_ref", "velocity", "effort")}
        q_lower, q_upper, q_starts, v_starts = [], [], [], []
        nq = nv = 0
        for bd in bodies:
            j = bd["joint"]
            jt = JOINT_TYPES[j.type]()
            jtypes.append(jt)
            q_starts.append(nq), v_starts.append(nv)
            nq += jt.nq
            nv += jt.nv
            for k in per_dof:
                per_dof[k] += [getattr(j, k)] * jt.nv
            if jt.nq == 1:
                q_lower.append(j.lower), q_upper.append(j.upper)
            else:
                q_lower += [-np.inf] * jt.nq
                q_upper += [np.inf] * jt.nq

        geom_names, geom_bodies, geom_shapes, geom_poses = [], [], [], []
        for name, ln, shape, T in self.geoms:
            if ln not in links:
                raise ModelError(f"{self._where('geom', name)}: link {ln!r} does not exist")
            geom_names.append(name), geom_bodies.append(link_body[ln])
            geom_shapes.append(shape), geom_poses.append(link_pose[ln] @ T)
        body_names = [bd["name"] for bd in bodies]
        frame_names, frame_bodies, frame_poses = [], [], []
        for ln in self.links:
            if ln not in body_names and ln != world:
                frame_names.append(ln), frame_bodies.append(link_body[ln]), frame_poses.append(link_pose[ln])
        for name, ln, T in self.frames:
            if ln not in links:
                raise ModelError(f"{self._where('frame', name)}: link {ln!r} does not exist")
            frame_names.append(name), frame_bodies.append(link_body[ln]), frame_poses.append(link_pose[ln] @ T)

        f = lambda x, shape=None: jnp.asarray(np.asarray(x, dtype=float).reshape(shape) if shape else np.asarray(x, dtype=float))
        model = Model(
            name=self.name, body_names=tuple(body_names), joint_names=tuple(bd["joint"].name for bd in bodies),
            parents=tuple(bd["parent"] for bd in bodies), joints=tuple(jtypes), q_starts=tuple(q_starts),
            v_starts=tuple(v_starts), geom_names=tuple(geom_names), geom_bodies=tuple(geom_bodies),
            frame_names=tuple(frame_names), frame_bodies=tuple(frame_bodies), source=src,
            joint_R=f([bd["T"][:3, :3] for bd in bodies], (nb, 3, 3)), joint_p=f([bd["T"][:3, 3] for bd in bodies], (nb, 3)),
            axis=f([bd["joint"].axis for bd in bodies], (nb, 3)), mass=f(mass, (nb,)), com=f(com, (nb, 3)),
            inertia=f(inertia, (nb, 3, 3)), armature=f(per_dof["armature"], (nv,)), damping=f(per_dof["damping"], (nv,)),
            stiffness=f(per_dof["stiffness"], (nv,)), spring_ref=f(per_dof["spring_ref"], (nv,)),
            q_lower=f(q_lower, (nq,)), q_upper=f(q_upper, (nq,)), velocity_limit=f(per_dof["velocity"], (nv,)),
            effort_limit=f(per_dof["effort"], (nv,)), limit_stiffness=f(self.limit_stiffness),
            limit_margin=f(self.limit_margin), gravity=f(self.gravity, (3,)), geoms=tuple(geom_shapes),
            geom_poses=f(geom_poses, (len(geom_poses), 4, 4)), frame_poses=f(frame_poses, (len(frame_poses), 4, 4)),
            notes=tuple(notes),
        )
        check_nonsingular(model)
        return model


def check_nonsingular(model: Model):
    """Raise `ModelError` if some joint moves a subtree with no mass or no inertia about
    its axis, or the mass matrix is otherwise not positive definite. Checked at the
    neutral configuration with armature included, in O(n_bodies) time and memory: the
    mass matrix's diagonal ``S_i^T Ic_i S_i`` (composite inertias) and the pivots
    ``D_i = S_i^T IA_i S_i`` of its tree factorization (articulated-body inertias,
    Featherstone RBDA 7.3), which are all positive iff M is positive definite (here: above
    1e-12 of the joint's diagonal entry, so that rounding does not hide a singular M)."""
    q = model.neutral()
    jR, jp, ax = np.asarray(model.joint_R), np.asarray(model.joint_p), np.asarray(model.axis)
    mass, com, inertia = np.asarray(model.mass), np.asarray(model.com), np.asarray(model.inertia)
    arm = np.asarray(model.armature)
    nb = model.n_bodies
    oR, op, Sw, Iw = [], [], [], []
    for i, (j, par) in enumerate(zip(model.joints, model.parents)):
        s = model.q_starts[i]
        RJ, pJ = _np_joint_transform(j, ax[i], q[s: s + j.nq])
        R, p = jR[i] @ RJ, jR[i] @ pJ + jp[i]
        if par >= 0:
            R, p = oR[par] @ R, oR[par] @ p + op[par]
        oR.append(R), op.append(p)
        Sw.append(_np_Ad(R, p) @ _np_motion_subspace(j, ax[i]))
        Iw.append(_np_transform_inertia(R, p, _np_spatial_inertia(mass[i], com[i], inertia[i])))
    Ic = [I.copy() for I in Iw]
    for i in reversed(range(nb)):
        if model.parents[i] >= 0:
            Ic[model.parents[i]] += Ic[i]
    arms = [arm[model.v_starts[i]: model.v_starts[i] + model.joints[i].nv] for i in range(nb)]
    diag = np.concatenate([np.einsum("ak,ab,bk->k", Sw[i], Ic[i], Sw[i]) + arms[i] for i in range(nb)])
    if not np.all(np.isfinite(diag)):
        raise ModelError(f"{model.source}: the mass matrix has NaN/inf entries; check inertias")
    scale = max(1.0, diag.max())  # |M_jk| <= sqrt(M_jj M_kk): the diagonal bounds M
    dof_joint = model.dof_joint()
    for k in range(model.nv):
        if diag[k] <= 1e-12 * scale:
            j = dof_joint[k]
            raise ModelError(
                f"{model.source}: joint {model.joint_names[j]!r} moves a subtree with no mass or no inertia about "
                f"its axis (body {model.body_names[j]!r}): the dynamics are singular. Give a link in that subtree "
                "an <inertial>, or add armature to the joint."
            )
    IA = Iw
    for i in reversed(range(nb)):
        U = IA[i] @ Sw[i]
        D = Sw[i].T @ U + np.diag(arms[i])
        if not np.linalg.eigvalsh(0.5 * (D + D.T)).min() > 1e-12 * diag[model.v_starts[i]: model.v_starts[i] + len(D)].max():
            raise ModelError(
                f"{model.source}: the mass matrix is not positive definite at the neutral configuration: joint "
                f"{model.joint_names[i]!r} (body {model.body_names[i]!r}) adds no inertia that the joints below it "
                "do not already move (its articulated-body pivot is not positive); give its subtree inertia about "
                "its axis, or add armature")
        if model.parents[i] >= 0:
            IA[model.parents[i]] = IA[model.parents[i]] + IA[i] - U @ np.linalg.solve(D, U.T)


# --- host-side (numpy) helpers: model construction stays fast for big trees (no per-op JAX
# dispatch); the same formulas as `cstorm.spatial` and `cstorm.dynamics.crba`.
def _np_skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _np_spatial_inertia(mass, com, inertia_com):
    C = _np_skew(np.asarray(com, dtype=float))
    return np.block([[inertia_com + mass * (C @ C.T), mass * C], [mass * C.T, mass * np.eye(3)]])


def _np_Ad(R, p):
    """(6, 6) motion transform [[R, 0], [[p]x R, R]] (A from B)."""
    X = np.zeros((6, 6))
    X[:3, :3] = X[3:, 3:] = R
    X[3:, :3] = _np_skew(p) @ R
    return X


def _np_transform_inertia(R, p, I):
    """Spatial inertia given in B -> expressed in A (T = A from B)."""
    Xi = _np_Ad(R.T, -R.T @ p)  # Ad(T^-1)
    return Xi.T @ I @ Xi


def _np_inertia_parts(I):
    """(mass, com (3,), inertia about the CoM (3, 3)) of a spatial inertia with mass > 0."""
    m = I[3, 3]
    C = I[:3, 3:] / m
    c = 0.5 * np.array([C[2, 1] - C[1, 2], C[0, 2] - C[2, 0], C[1, 0] - C[0, 1]])
    Cs = _np_skew(c)
    return float(m), c, I[:3, :3] - m * (Cs @ Cs.T)


def _np_joint_transform(joint, axis, qj):
    """(R, p) of a joint's displacement (joint frame from child frame), numpy."""
    def quat_R(w, x, y, z):
        n = np.sqrt(w * w + x * x + y * y + z * z)
        w, x, y, z = w / n, x / n, y / n, z / n
        return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                         [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                         [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])

    if isinstance(joint, Revolute):
        K = _np_skew(axis)
        t = qj[0]
        return np.eye(3) + np.sin(t) * K + (1 - np.cos(t)) * (K @ K), np.zeros(3)
    if isinstance(joint, Prismatic):
        return np.eye(3), axis * qj[0]
    if isinstance(joint, Free):
        return quat_R(*qj[3:7]), np.asarray(qj[:3], dtype=float)
    if isinstance(joint, Ball):
        return quat_R(*qj), np.zeros(3)
    raise TypeError(f"no host-side transform for joint type {type(joint).__name__}")


def _np_motion_subspace(joint, axis):
    """(6, joint.nv) motion subspace in the joint's child frame, numpy (`Joint.motion_subspace`)."""
    a = np.asarray(axis, dtype=float)
    if isinstance(joint, Revolute):
        return np.concatenate([a, np.zeros(3)])[:, None]
    if isinstance(joint, Prismatic):
        return np.concatenate([np.zeros(3), a])[:, None]
    if isinstance(joint, Free):
        return np.eye(6)
    if isinstance(joint, Ball):
        return np.concatenate([np.eye(3), np.zeros((3, 3))])
    return np.asarray(joint.motion_subspace(jnp.asarray(a)))


def _available_memory() -> int | None:
    """Bytes of memory available to this process (Linux MemAvailable), or None."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_size(source: str, n_bodies: int, nv: int, depth_sum: int):
    """Refuse, before allocating it, a model whose dense (nv, nv) mass matrix (the
    dynamics' and this builder's check, ~3 copies of 8 nv^2 bytes) and ancestor index
    lists (8 bytes per body and ancestor) need more memory than is available."""
    need = 3 * 8 * nv * nv + 8 * depth_sum
    avail = _available_memory()
    if avail is not None and need > avail:
        raise ModelError(
            f"{source}: the model has {n_bodies} bodies and nv = {nv}: its dense mass matrix and the tree's ancestor "
            f"lists need ~{need / 2**30:.1f} GiB, more than the {avail / 2**30:.1f} GiB of memory available; cstorm's "
            "dynamics work with the dense mass matrix, so a model this large cannot be used on this machine")
