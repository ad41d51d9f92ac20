"""Human-readable description of a `Model` (used by ``cstorm info MODEL``)."""

from __future__ import annotations

import numpy as np

from ..geometry.shapes import describe as describe_shape
from .model import Model

__all__ = ["describe"]

MAX_INDENT = 24


def _vec(x, prec=4):
    return np.array2string(np.asarray(x, dtype=float), precision=prec, suppress_small=True, separator=", ")


def _range(lo, hi):
    if not np.isfinite(lo) and not np.isfinite(hi):
        return None
    return f"[{lo:.4g}, {hi:.4g}]"


def _pose(T):
    T = np.asarray(T, dtype=float)
    s = f"xyz={_vec(T[:3, 3])}"
    if not np.allclose(T[:3, :3], np.eye(3), atol=1e-12):
        s += " R=" + _vec(T[:3, :3].ravel(), 3)
    return s


def describe(model: Model) -> str:
    """A multi-line text: header (sizes, gravity, total mass), then the body tree, each
    body with its joint (name, type, q and v slices, axis, limits, armature, damping,
    spring), mass, CoM, principal inertias, collision shapes and named frames; world
    geoms and frames, then the loader's notes (``model.notes``) at the end. Units SI,
    angles in rad."""
    nb = model.n_bodies
    mass = np.asarray(model.mass)
    com = np.asarray(model.com)
    inertia = np.asarray(model.inertia)
    axis = np.asarray(model.axis)
    lo, hi = np.asarray(model.q_lower), np.asarray(model.q_upper)
    arm, damp = np.asarray(model.armature), np.asarray(model.damping)
    stiff, sref = np.asarray(model.stiffness), np.asarray(model.spring_ref)
    vel, eff = np.asarray(model.velocity_limit), np.asarray(model.effort_limit)
    geom_poses = np.asarray(model.geom_poses)
    frame_poses = np.asarray(model.frame_poses)
    joint_R, joint_p = np.asarray(model.joint_R), np.asarray(model.joint_p)

    lines = [
        f"model {model.name!r}  (source: {model.source})",
        f"  bodies {nb}, nq {model.nq}, nv {model.nv}, geoms {model.n_geoms}, frames {len(model.frame_names)}",
        f"  gravity {_vec(model.gravity)} m/s^2, moving mass {mass.sum():.6g} kg (links welded to the world excluded)",
        "",
    ]

    def geoms_and_frames(b, indent):
        out = []
        for k, gb in enumerate(model.geom_bodies):
            if gb == b:
                out.append(f"{indent}geom {model.geom_names[k]!r}: {describe_shape(model.geoms[k])} at {_pose(geom_poses[k])}")
        for k, fb in enumerate(model.frame_bodies):
            if fb == b:
                out.append(f"{indent}frame {model.frame_names[k]!r} at {_pose(frame_poses[k])}")
        return out

    def body(i, depth):
        # indentation shows the tree up to depth 24; deeper bodies (long chains) say their depth
        ind = "  " * min(depth, MAX_INDENT) + (f"[depth {depth}] " if depth > MAX_INDENT else "")
        j = model.joints[i]
        qs, vs = model.q_starts[i], model.v_starts[i]
        parent = "world" if model.parents[i] < 0 else model.body_names[model.parents[i]]
        out = [f"{ind}body {model.body_names[i]!r} (#{i}, parent {parent})"]
        jl = (f"{ind}  joint {model.joint_names[i]!r}: {j.name}, q[{qs}:{qs + j.nq}], v[{vs}:{vs + j.nv}]")
        if j.nv == 1:
            jl += f", axis {_vec(axis[i])}"
            r = _range(lo[qs], hi[qs])
            if r:
                jl += f", range {r}"
        out.append(jl)
        extras = []
        sl = slice(vs, vs + j.nv)
        if np.any(arm[sl]):
            extras.append(f"armature {_vec(arm[sl])}" if j.nv > 1 else f"armature {arm[vs]:.4g}")
        if np.any(damp[sl]):
            extras.append(f"damping {damp[vs]:.4g}")
        if j.nv == 1 and stiff[vs]:
            extras.append(f"spring {stiff[vs]:.4g} about {sref[vs]:.4g}")
        if j.nv == 1 and np.isfinite(vel[vs]):
            extras.append(f"velocity limit {vel[vs]:.4g}")
        if j.nv == 1 and np.isfinite(eff[vs]):
            extras.append(f"effort limit {eff[vs]:.4g}")
        if extras:
            out.append(f"{ind}    " + ", ".join(extras))
        out.append(f"{ind}  placement in parent: {_pose(_homog(joint_R[i], joint_p[i]))}")
        ev = np.linalg.eigvalsh(0.5 * (inertia[i] + inertia[i].T))
        out.append(f"{ind}  mass {mass[i]:.6g} kg, CoM {_vec(com[i])}, principal inertias {_vec(ev, 6)} kg m^2")
        out += geoms_and_frames(i, ind + "  ")
        return out

    # depth-first pre-order with an explicit stack (no recursion limit on deep chains)
    children = [[] for _ in range(nb)]
    for i, p in enumerate(model.parents):
        if p >= 0:
            children[p].append(i)
    stack = [(i, 0) for i in reversed(range(nb)) if model.parents[i] < 0]
    while stack:
        i, depth = stack.pop()
        lines += body(i, depth)
        stack += [(c, depth + 1) for c in reversed(children[i])]
    world = geoms_and_frames(-1, "  ")
    if world:
        lines += ["", "world (fixed):"] + world
    if model.notes:
        lines += ["", "loader notes (repaired or ignored):"] + [f"  note: {n}" for n in model.notes]
    return "\n".join(lines)


def _homog(R, p):
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p
    return T


def dof_names(model, kind):
    """Names of the DoFs of ``model``'s joints in q order (``kind="q"``) or v order (``"v"``):
    the joint's name for a 1-DoF joint, ``<joint>_<i>`` for the components of others."""
    out = []
    for j, n in zip(model.joints, model.joint_names):
        k = j.nq if kind == "q" else j.nv
        out += [n] if k == 1 else [f"{n}_{i}" for i in range(k)]
    return out
