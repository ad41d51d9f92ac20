"""MJCF loader: ``load_mjcf(path_or_xml) -> Model``, through MuJoCo's own compiler.

The file (or XML string) is compiled by ``mujoco.MjModel`` (so defaults, ``<include>``,
joint ``ref``, inertias inferred from geoms, ``fromto`` are MuJoCo's), and the compiled
model is converted. Needs the optional ``mujoco`` package (``pip install 'cstorm[mjcf]'``).

Conversion
----------
- The world body is the root link (fixed); its geoms (ground planes, walls) become world
  geoms (``model.geom_bodies == -1``).
- A body with one joint becomes one cstorm body named like the MJCF body. A body with
  several joints becomes a chain: joints ``j1 .. jk`` in MuJoCo's order, the first
  ``k - 1`` ending in massless intermediate bodies named ``"<body>/<joint>"``. A body
  without joints is welded to its parent (merged, kept as a frame).
- Joint types: hinge -> revolute, slide -> prismatic, ball -> ball, free -> free.
- **q equals MuJoCo's qpos** (same order, same units, quaternions (w, x, y, z)). A
  hinge or slide with ``ref`` r (``qpos0``) moves by ``q - r`` from the body's
  reference pose; the offset is folded into the joint placement.
- **Body frames.** cstorm's revolute and ball joints turn about their frame's origin and
  a body's frame is its joint's child frame, so a cstorm body frame sits at the MJCF
  joint anchor (``<joint pos>``) of the body's last joint, with the MJCF body's
  orientation. It equals the MJCF body frame when that anchor is 0. The MJCF body frame
  itself is always available as the named frame ``"<body>/origin"``
  (``cs.frame_pose(model, q, "thigh/origin")`` equals MuJoCo's ``xpos``/``xquat``).
  Sites become named frames too (their MJCF names).
- Inertia: ``body_mass``, ``body_ipos``, ``body_iquat``, ``body_inertia`` (principal
  moments in the inertial frame) re-expressed in the cstorm body frame.
- Per DoF: ``dof_armature`` (part of M, as in MuJoCo), ``dof_damping``; per joint:
  ``jnt_stiffness`` with ``qpos_spring`` as the spring reference, ``jnt_range`` when
  ``jnt_limited``. An actuator on a hinge/slide gives the joint's effort limit
  (``|forcerange|`` if force-limited, else ``|ctrlrange| * |gear|`` if ctrl-limited).
  Gravity is ``opt.gravity`` (zero when the model disables gravity).
- Geoms with ``contype`` or ``conaffinity`` non-zero (collision geoms): sphere, capsule
  (``size[1]`` is MuJoCo's half-length; cstorm's ``length`` = ``2 * size[1]``), box
  (half sizes), cylinder (likewise), plane (the half-space below the geom's z = 0),
  mesh (`ConvexMesh` of the compiled vertices). Ellipsoids, height fields and SDFs are
  skipped with a warning.
- Not modelled, reported by one `cstorm.ModelWarning` (an error with ``strict=True``):
  ``<tendon>``, ``<equality>``, actuators acting through tendons/sites/bodies or with bias
  or activation dynamics, joint ``frictionloss``, ``gravcomp``, fluid forces
  (``density``, ``viscosity``, ``wind``), ``<flex>``, explicit contact ``<pair>`` /
  ``<exclude>`` (see `unsupported`). Sensors, keyframes, cameras, lights and visual-only
  geoms do not change the dynamics and are ignored silently.

Velocity conventions (the one trap): cstorm's free joint has ``v = [omega_body;
v_body]`` (body-frame twist), MuJoCo's ``qvel = [v_world; omega_body]`` (linear
velocity of the body origin in world axes, then body-frame angular velocity).
`qvel_from_v`, `v_from_qvel`, `qacc_from_a` and `tau_from_qfrc` convert; hinge, slide
and ball velocities are identical.
"""

from __future__ import annotations

import os
import warnings

import numpy as np

from ..errors import ModelError, ModelWarning
from ..geometry.shapes import Box, Capsule, ConvexMesh, Cylinder, Plane, Sphere
from .builder import ModelBuilder
from .joints import Free
from .model import Model
from .urdf import parse_xml

__all__ = ["load_mjcf", "unsupported", "qvel_from_v", "v_from_qvel", "qacc_from_a", "tau_from_qfrc"]


def _import_mujoco():
    try:
        import mujoco
    except ImportError as e:
        raise ImportError("cstorm.load_mjcf needs MuJoCo: pip install 'cstorm[mjcf]' (or pip install mujoco)") from e
    return mujoco


def _quat_to_R(q):
    w, x, y, z = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _pose(pos=None, quat=None, R=None):
    T = np.eye(4)
    if quat is not None:
        T[:3, :3] = _quat_to_R(quat)
    if R is not None:
        T[:3, :3] = R
    if pos is not None:
        T[:3, 3] = pos
    return T


def _axis_angle(axis, angle):
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * (K @ K)


def _name(m, mujoco, objtype, i, fallback):
    n = mujoco.mj_id2name(m, objtype, i)
    return n if n else fallback


_FILE_ELEMENTS = {"mesh": "meshdir", "hfield": "meshdir", "skin": "meshdir", "texture": "texturedir",
                  "include": None, "model": None}


def _within(path, root):
    path, root = os.path.realpath(path), os.path.realpath(root)
    return path == root or path.startswith(root.rstrip(os.sep) + os.sep)


def check_asset_paths(text, source: str, base_dir: str, asset_dirs=(), assets=None, _seen=None):
    """Refuse an MJCF whose asset files (``<mesh file>``, ``<hfield>``, ``<skin>``,
    ``<texture>``, ``<include>``, ``<model>``; with ``<compiler meshdir texturedir
    assetdir>``, as MuJoCo resolves them) resolve, symlinks followed, outside
    ``base_dir`` (the model file's directory) and ``asset_dirs``. Included files are
    checked too. The XML is parsed with DTDs refused (`cstorm.model.urdf.parse_xml`).
    Files given in ``assets`` (in memory) are not looked up on disk. Raises `ModelError`
    naming the file, line and element."""
    seen = set() if _seen is None else _seen
    root, lines = parse_xml(text, source)
    roots = [base_dir] + [os.fspath(d) for d in asset_dirs]
    dirs = {"meshdir": base_dir, "texturedir": base_dir}
    for comp in root.iter("compiler"):
        a = comp.get("assetdir")
        if a is not None:
            dirs = {k: os.path.join(base_dir, a) for k in dirs}
        for k in ("meshdir", "texturedir"):
            if comp.get(k) is not None:
                dirs[k] = os.path.join(base_dir, comp.get(k))
    for el in root.iter():
        if el.tag not in _FILE_ELEMENTS:
            continue
        names = [el.get("file")] + ([el.get(f"file{s}") for s in ("right", "left", "up", "down", "front", "back")]
                                    if el.tag == "texture" else [])
        for f in names:
            if not f or (assets and f in assets):
                continue
            d = dirs[_FILE_ELEMENTS[el.tag]] if _FILE_ELEMENTS[el.tag] else base_dir
            path = f if os.path.isabs(f) else os.path.join(d, f)
            if not any(_within(path, r) for r in roots):
                raise ModelError(f"{source}:{lines.get(el, '?')}: <{el.tag} file={f!r}> resolves to "
                                 f"{os.path.realpath(path)!r}, outside the model's directory "
                                 f"{os.path.realpath(base_dir)!r} (pass its directory in asset_dirs)")
            if el.tag in ("include", "model") and os.path.isfile(path) and os.path.realpath(path) not in seen:
                seen.add(os.path.realpath(path))
                with open(path, "rb") as fh:
                    check_asset_paths(fh.read(), path, base_dir, asset_dirs, assets, seen)


def _compile(path_or_xml, assets, mujoco, asset_dirs=()):
    """(mjModel, source string for messages). Asset paths are confined first
    (`check_asset_paths`)."""
    if isinstance(path_or_xml, mujoco.MjModel):
        return path_or_xml, "<mjModel>"
    if isinstance(path_or_xml, (str, os.PathLike)) and not (isinstance(path_or_xml, str)
                                                              and path_or_xml.lstrip().startswith("<")):
        source = os.fspath(path_or_xml)
        if not os.path.isfile(source):
            raise ModelError(f"{source}: MJCF file not found")
        try:
            with open(source, "rb") as fh:
                text = fh.read()
        except OSError as e:
            raise ModelError(f"{source}: cannot read MJCF file: {e.strerror or e}") from None
        check_asset_paths(text, source, os.path.dirname(os.path.abspath(source)), asset_dirs, assets)
        try:
            return mujoco.MjModel.from_xml_path(source, assets) if assets else mujoco.MjModel.from_xml_path(source), source
        except ValueError as e:
            raise ModelError(f"{source}: MuJoCo could not compile the MJCF model: {str(e).strip()}") from None
    if isinstance(path_or_xml, str):
        source = "<MJCF string>"
        check_asset_paths(path_or_xml, source, os.getcwd(), asset_dirs, assets)
        try:
            return (mujoco.MjModel.from_xml_string(path_or_xml, assets) if assets
                    else mujoco.MjModel.from_xml_string(path_or_xml)), source
        except ValueError as e:
            raise ModelError(f"{source}: MuJoCo could not compile the MJCF model: {str(e).strip()}") from None
    raise ModelError(f"load_mjcf: expected a file path, an XML string or a mujoco.MjModel, got {type(path_or_xml).__name__}")


def _names(m, mujoco, objtype, ids, prefix):
    return [mujoco.mj_id2name(m, objtype, int(i)) or f"{prefix}{int(i)}" for i in ids]


def unsupported(m, mujoco) -> list[str]:
    """What the compiled model ``m`` holds that cstorm does not model, one sentence each
    (the elements, by name, and what ignoring them changes); empty when nothing."""
    O, out = mujoco.mjtObj, []
    if m.ntendon:
        out.append(f"<tendon> {_names(m, mujoco, O.mjOBJ_TENDON, range(m.ntendon), 'tendon')}: tendon stiffness, "
                   "damping, limits and lengths are not modelled (the joints they couple move independently)")
    if m.neq:
        kinds = [mujoco.mjtEq(int(t)).name.replace("mjEQ_", "").lower() for t in m.eq_type]
        names = _names(m, mujoco, O.mjOBJ_EQUALITY, range(m.neq), "equality")
        out.append(f"<equality> {[f'{n} ({k})' for n, k in zip(names, kinds)]}: constraints are not enforced "
                   "(welded or coupled parts move freely)")
    JOINT = int(mujoco.mjtTrn.mjTRN_JOINT)
    other_trn = [a for a in range(m.nu) if int(m.actuator_trntype[a]) != JOINT]
    if other_trn:
        out.append(f"actuators {_names(m, mujoco, O.mjOBJ_ACTUATOR, other_trn, 'actuator')} act through tendons, "
                   "sites or bodies: not modelled (no effort limit, no actuation from them)")
    biased = [a for a in range(m.nu) if int(m.actuator_biastype[a]) != int(mujoco.mjtBias.mjBIAS_NONE)
              or int(m.actuator_dyntype[a]) != int(mujoco.mjtDyn.mjDYN_NONE)]
    if biased:
        out.append(f"actuators {_names(m, mujoco, O.mjOBJ_ACTUATOR, biased, 'actuator')} have bias terms or "
                   "activation dynamics (position/velocity servos, filters): cstorm's controls are joint torques; "
                   "their servo forces are not modelled")
    fric = [j for j in range(m.njnt) if np.any(m.dof_frictionloss[m.jnt_dofadr[j]: m.jnt_dofadr[j] + 1] > 0)]
    if fric:
        out.append(f"joint frictionloss on {_names(m, mujoco, O.mjOBJ_JOINT, fric, 'joint')}: dry joint friction "
                   "is not modelled")
    grav = [b for b in range(1, m.nbody) if m.body_gravcomp[b] != 0]
    if grav:
        out.append(f"gravcomp on bodies {_names(m, mujoco, O.mjOBJ_BODY, grav, 'body')}: gravity compensation is "
                   "not modelled")
    if m.opt.density > 0 or m.opt.viscosity > 0 or np.any(m.opt.wind != 0):
        out.append(f"<option density={m.opt.density:g} viscosity={m.opt.viscosity:g} "
                   f"wind={[float(x) for x in m.opt.wind]}>: "
                   "fluid forces are not modelled")
    if getattr(m, "nflex", 0):
        out.append(f"{m.nflex} <flex> elements (deformable bodies) are not modelled")
    if m.npair or m.nexclude:
        out.append(f"<contact> pairs ({m.npair}) and excludes ({m.nexclude}): cstorm's contact pairs come from its "
                   "Environment, not from these")
    return out


def load_mjcf(path_or_xml, *, assets: dict | None = None, inertia_check: str = "warn",
              collision_only: bool = True, strict: bool = False, asset_dirs=()) -> Model:
    """Load an MJCF model into a `Model` through MuJoCo's compiler.

    Args:
        path_or_xml: a file path, an XML string (starting with ``<``) or a compiled
            ``mujoco.MjModel``.
        assets: optional ``{filename: bytes}`` for ``MjModel.from_xml_*`` (meshes,
            included files of an XML string).
        inertia_check: ``"warn"`` or ``"strict"`` (see `cstorm.model.inertia`).
        collision_only: True keeps only geoms with ``contype`` or ``conaffinity`` set.
        strict: True makes what cstorm does not model (`unsupported`: tendons, equality
            constraints, actuators other than joint motors, frictionloss, gravcomp, fluid
            forces, flex, explicit contact pairs) and unsupported geom types an error, and
            implies ``inertia_check="strict"``; False (default) loads the rest with one
            `cstorm.ModelWarning` listing what was ignored and what that changes.
        asset_dirs: further directories that asset files (meshes, textures, includes)
            may lie in, besides the model file's (the working directory for an XML
            string); a path resolving outside them is a `cstorm.ModelError`.
    Returns: the `Model` (q order and values = MuJoCo's qpos; see the module docstring
        for frames and the free-joint velocity convention).
    Raises: `cstorm.ModelError` (compile errors wrapped, naming the file);
        ImportError when MuJoCo is not installed.
    """
    mujoco = _import_mujoco()
    m, source = _compile(path_or_xml, assets, mujoco, asset_dirs)
    if strict:
        inertia_check = "strict"
    ignored = unsupported(m, mujoco)
    if ignored and strict:
        raise ModelError(f"{source}: elements cstorm does not model (strict=True): " + "; ".join(ignored))
    O = mujoco.mjtObj
    JT = mujoco.mjtJoint
    GT = mujoco.mjtGeom
    model_name = m.names[: m.names.index(b"\0")].decode() or "mjcf"
    b = ModelBuilder(model_name, gravity=np.array(m.opt.gravity, dtype=float), source=source,
                     inertia_check=inertia_check)
    if m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_GRAVITY:
        b.gravity = np.zeros(3)

    body_names = [_name(m, mujoco, O.mjOBJ_BODY, i, f"body{i}") for i in range(m.nbody)]
    body_names[0] = body_names[0] or "world"
    if len(set(body_names)) != len(body_names):
        raise ModelError(f"{source}: body names must be unique for cstorm (got duplicates)")
    joint_names = [_name(m, mujoco, O.mjOBJ_JOINT, j, f"{body_names[m.jnt_bodyid[j]]}_joint{j}") for j in range(m.njnt)]

    # effort limits from actuators on hinge/slide joints
    effort = {}
    for a in range(m.nu):
        if int(m.actuator_trntype[a]) != int(mujoco.mjtTrn.mjTRN_JOINT):
            continue
        j = int(m.actuator_trnid[a, 0])
        if int(m.jnt_type[j]) not in (int(JT.mjJNT_HINGE), int(JT.mjJNT_SLIDE)):
            continue
        if m.actuator_forcelimited[a]:
            e = float(np.abs(m.actuator_forcerange[a]).max())
        elif m.actuator_ctrllimited[a]:
            e = float(np.abs(m.actuator_ctrlrange[a]).max() * abs(m.actuator_gear[a, 0]))
        else:
            continue
        effort[j] = effort.get(j, 0.0) + e

    # O_b: pose of MJCF body b's frame in its cstorm link frame (the link named after it)
    origin = {0: np.eye(4)}
    b.add_link(body_names[0])
    for i in range(1, m.nbody):
        name, par = body_names[i], int(m.body_parentid[i])
        A = origin[par] @ _pose(m.body_pos[i], m.body_quat[i])  # parent link from MJCF ref frame of body i
        prev = body_names[par]
        nj, adr = int(m.body_jntnum[i]), int(m.body_jntadr[i])
        if nj == 0:
            b.add_joint(f"{name}/weld", "fixed", prev, name, pose=A)
            A = np.eye(4)
        for k in range(nj):
            j = adr + k
            jn, jt = joint_names[j], int(m.jnt_type[j])
            child = name if k == nj - 1 else f"{name}/{jn}"
            if child != name:
                b.add_link(child)  # massless intermediate link
            dof = int(m.jnt_dofadr[j])
            kw = dict(damping=float(m.dof_damping[dof]), armature=float(m.dof_armature[dof]))
            c, ax = np.array(m.jnt_pos[j], dtype=float), np.array(m.jnt_axis[j], dtype=float)
            if jt in (JT.mjJNT_HINGE, JT.mjJNT_SLIDE):
                r = float(m.qpos0[m.jnt_qposadr[j]])
                kw.update(axis=ax, stiffness=float(m.jnt_stiffness[j]), spring_ref=float(m.qpos_spring[m.jnt_qposadr[j]]))
                if m.jnt_limited[j]:
                    kw.update(lower=float(m.jnt_range[j, 0]), upper=float(m.jnt_range[j, 1]))
                if j in effort:
                    kw["effort"] = effort[j]
            if jt == JT.mjJNT_HINGE:
                placement = A @ _pose(pos=c, R=_axis_angle(ax, -r))
                A = _pose(pos=-c)
                jtype = "revolute"
            elif jt == JT.mjJNT_SLIDE:
                placement = A @ _pose(pos=-r * ax / np.linalg.norm(ax))
                A = np.eye(4)
                jtype = "prismatic"
            elif jt == JT.mjJNT_BALL:
                placement = A @ _pose(pos=c)
                A = _pose(pos=-c)
                jtype = "ball"
            elif jt == JT.mjJNT_FREE:
                if par != 0:
                    raise ModelError(f"{source}: free joint {jn!r} of body {name!r} is not on a child of the world")
                placement, A, jtype = np.eye(4), np.eye(4), "free"
            else:
                raise ModelError(f"{source}: joint {jn!r}: unsupported MuJoCo joint type {jt}")
            b.add_joint(jn, jtype, prev, child, pose=placement, **kw)
            prev = child
        origin[i] = A
        # inertia, re-expressed in the link frame
        Ri = A[:3, :3] @ _quat_to_R(m.body_iquat[i])
        b.add_link(name, float(m.body_mass[i]), A[:3, :3] @ m.body_ipos[i] + A[:3, 3],
                   Ri @ np.diag(m.body_inertia[i]) @ Ri.T)
        b.add_frame(f"{name}/origin", name, pose=A)

    # geoms
    skipped = []
    for g in range(m.ngeom):
        bi = int(m.geom_bodyid[g])
        if collision_only and m.geom_contype[g] == 0 and m.geom_conaffinity[g] == 0:
            continue
        gname = _name(m, mujoco, O.mjOBJ_GEOM, g, f"{body_names[bi]}_geom{g}")
        t, size = int(m.geom_type[g]), np.array(m.geom_size[g], dtype=float)
        try:
            if t == GT.mjGEOM_SPHERE:
                shape = Sphere(size[0])
            elif t == GT.mjGEOM_CAPSULE:
                shape = Capsule(size[0], 2.0 * size[1])
            elif t == GT.mjGEOM_CYLINDER:
                shape = Cylinder(size[0], 2.0 * size[1])
            elif t == GT.mjGEOM_BOX:
                shape = Box(size[:3])
            elif t == GT.mjGEOM_PLANE:
                shape = Plane(np.array([0.0, 0.0, 1.0]), 0.0)
            elif t == GT.mjGEOM_MESH:
                mid = int(m.geom_dataid[g])
                va, vn = int(m.mesh_vertadr[mid]), int(m.mesh_vertnum[mid])
                shape = ConvexMesh(np.array(m.mesh_vert[va: va + vn], dtype=float))
            else:
                skipped.append(f"{gname} ({mujoco.mjtGeom(t).name})")
                continue
        except Exception as e:
            raise ModelError(f"{source}: geom {gname!r} of body {body_names[bi]!r}: {e}") from None
        b.add_geom(body_names[bi], shape, pose=origin[bi] @ _pose(m.geom_pos[g], m.geom_quat[g]), name=gname)
    if skipped:
        msg = f"geoms of unsupported types skipped (no contact through them): {skipped}"
        if strict:
            raise ModelError(f"{source}: {msg} (strict=True)")
        ignored.append(msg)
    if ignored:
        warnings.warn(f"{source}: loaded without what cstorm does not model (strict=True refuses it): "
                      + "; ".join(ignored), ModelWarning, stacklevel=2)
    for s in range(m.nsite):
        bi = int(m.site_bodyid[s])
        b.add_frame(_name(m, mujoco, O.mjOBJ_SITE, s, f"{body_names[bi]}_site{s}"), body_names[bi],
                    pose=origin[bi] @ _pose(m.site_pos[s], m.site_quat[s]))

    model = b.build()
    if model.nq != m.nq or model.nv != m.nv or model.joint_names != tuple(joint_names):
        raise ModelError(f"{source}: internal error: converted joints {model.joint_names} (nq={model.nq}) do not "
                         f"match MuJoCo's {joint_names} (nq={m.nq})")
    return model


# ------------------------------------------------------------------ velocity conventions
def _free_blocks(model):
    return [(s, vs) for j, s, vs in zip(model.joints, model.q_starts, model.v_starts) if isinstance(j, Free)]


def qvel_from_v(model: Model, q, v) -> np.ndarray:
    """MuJoCo qvel (nv,) from cstorm v (nv,) at q (nq,): free joints
    ``[omega_b; v_b] -> [R v_b; omega_b]``; other joints unchanged."""
    q, out = np.asarray(q, dtype=float), np.array(v, dtype=float)
    for s, vs in _free_blocks(model):
        R = _quat_to_R(q[s + 3: s + 7])
        w, vb = out[vs: vs + 3].copy(), out[vs + 3: vs + 6].copy()
        out[vs: vs + 3], out[vs + 3: vs + 6] = R @ vb, w
    return out


def v_from_qvel(model: Model, q, qvel) -> np.ndarray:
    """cstorm v (nv,) from MuJoCo qvel (nv,) at q (nq,) (inverse of `qvel_from_v`)."""
    q, out = np.asarray(q, dtype=float), np.array(qvel, dtype=float)
    for s, vs in _free_blocks(model):
        R = _quat_to_R(q[s + 3: s + 7])
        vw, w = out[vs: vs + 3].copy(), out[vs + 3: vs + 6].copy()
        out[vs: vs + 3], out[vs + 3: vs + 6] = w, R.T @ vw
    return out


def qacc_from_a(model: Model, q, v, a) -> np.ndarray:
    """MuJoCo qacc (nv,) from cstorm a (nv,) at (q, v): the time derivative of
    `qvel_from_v`; for a free joint ``d/dt (R v_b) = R (a_lin + omega x v_b)``."""
    q, v = np.asarray(q, dtype=float), np.asarray(v, dtype=float)
    out = qvel_from_v(model, q, a)
    for s, vs in _free_blocks(model):
        R = _quat_to_R(q[s + 3: s + 7])
        out[vs: vs + 3] += R @ np.cross(v[vs: vs + 3], v[vs + 3: vs + 6])
    return out


def tau_from_qfrc(model: Model, q, qfrc) -> np.ndarray:
    """cstorm generalized force (nv,) from a MuJoCo qfrc_* vector (nv,): a free joint's
    ``[f_world; torque_body] -> [torque_body; R^T f_world]`` (same power)."""
    return v_from_qvel(model, q, qfrc)
