"""PNG plots of a solved motion (`cstorm.viz.motion.Motion`): joint positions, active
joint torques, contact normal forces and distances, and the x-z paths of the centre of
mass and the base with a strobe of the robot. Every file is written atomically.

Angles are plotted in degrees, positions in m, torques in N m (N for prismatic joints),
forces in N, distances in mm. Segment boundaries of a sequence are dotted vertical lines
labelled with the segment names.
"""

from __future__ import annotations

import os

import numpy as np

from ..io.files import atomic_write
from .planar import draw_obstacles, robot_outlines, skeleton

_DPI = 110


def _mpl():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path):

    atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=_DPI, format="png"), ".png")
    _mpl().close(fig)
    return os.path.basename(path)


def _segments(ax, motion, label=True):
    if len(motion.segment_names) < 2:
        return
    for k, (t0, name) in enumerate(zip(motion.segment_starts, motion.segment_names)):
        if k:
            ax.axvline(t0, color="0.5", ls=":", lw=0.9)
        if label:
            ax.text(t0 + 0.01 * motion.duration, 1.0, name, transform=ax.get_xaxis_transform(), va="bottom",
                    ha="left", fontsize=7, color="0.35")


def _joint_kind(model, i):
    return type(model.joints[i]).__name__


def _legend(ax, n):
    if n:
        ax.legend(loc="best", fontsize=7, ncol=1 if n <= 6 else 2, framealpha=0.8)


def plot_joints(motion, path):
    """``path``: 1-DoF joint positions over time, revolute in deg, prismatic in m (one
    panel each when both occur); active joints drawn solid, passive dashed."""
    plt = _mpl()
    m = motion.model
    rev = [i for i in range(len(m.joints)) if _joint_kind(m, i) == "Revolute"]
    pri = [i for i in range(len(m.joints)) if _joint_kind(m, i) == "Prismatic"]
    panels = [(rev, "angle (deg)", 180 / np.pi), (pri, "position (m)", 1.0)]
    panels = [p for p in panels if p[0]]
    other = [i for i in range(len(m.joints)) if _joint_kind(m, i) not in ("Revolute", "Prismatic")]
    fig, axs = plt.subplots(len(panels) or 1, 1, figsize=(7.5, 2.6 * max(1, len(panels)) + 0.6), sharex=True,
                            squeeze=False)
    for ax, (idx, ylabel, scale) in zip(axs[:, 0], panels):
        for c, i in enumerate(idx):
            name = m.joint_names[i]
            act = name in motion.active
            ax.plot(motion.t, motion.q[:, m.q_starts[i]] * scale, ls="-" if act else "--", lw=1.4,
                    color=f"C{c % 10}", label=f"{name} ({'active' if act else 'passive'})")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        _segments(ax, motion, label=ax is axs[0, 0])
        _legend(ax, len(idx))
    axs[-1, 0].set_xlabel("time (s)")
    title = f"{motion.name}: joint positions"
    if other:
        title += f" (not shown: {', '.join(m.joint_names[i] for i in other)})"
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def plot_torques(motion, path):
    """``path``: motor torques of the active joints (N m; N for prismatic), with their
    effort limits (dotted, same colour) where finite."""
    plt = _mpl()
    m = motion.model
    fig, ax = plt.subplots(figsize=(7.5, 3.4))
    lim = np.asarray(m.effort_limit)
    for c, name in enumerate(motion.active):
        i = m.joint_names.index(name)
        vs = m.v_starts[i]
        unit = "N" if _joint_kind(m, i) == "Prismatic" else "N m"
        ax.plot(motion.t, motion.tau[:, vs], color=f"C{c % 10}", lw=1.4, label=f"{name} ({unit})")
        if np.isfinite(lim[vs]):
            for s in (-1, 1):
                ax.axhline(s * lim[vs], color=f"C{c % 10}", ls=":", lw=1.0)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("torque (N m)")
    ax.grid(alpha=0.3)
    _segments(ax, motion)
    _legend(ax, len(motion.active))
    fig.suptitle(f"{motion.name}: active joint torques (dotted: effort limits)", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def plot_contacts(motion, path, d_max_mm=50.0):
    """``path``: normal force magnitude (N) and signed distance (mm, < 0 penetrating) of
    every contact point over time. The distance axis is clipped at ``d_max_mm`` so the
    contact region stays readable (flight heights are in the paths plot)."""
    plt = _mpl()
    c = motion.contact
    fig, axs = plt.subplots(2, 1, figsize=(7.5, 5.4), sharex=True)
    k = c["d"].shape[1]
    weight = float(np.sum(np.asarray(motion.model.mass))) * float(np.linalg.norm(np.asarray(motion.model.gravity)))
    for i in range(k):
        col = f"C{i % 10}"
        ls = "-" if i < 10 else "--"
        axs[0].plot(motion.t, c["normal_magnitude"][:, i], color=col, ls=ls, lw=1.2, label=motion.contact_names[i])
        axs[1].plot(motion.t, 1e3 * c["d"][:, i], color=col, ls=ls, lw=1.2)
    if weight > 0:
        axs[0].axhline(weight, color="k", ls=":", lw=0.9)
        axs[0].text(motion.t[0], weight, " body weight", va="bottom", fontsize=7)
    axs[0].set_ylabel("normal force (N)")
    axs[1].set_ylabel("distance (mm)")
    axs[1].axhline(0.0, color="k", lw=0.8)
    dmin = float(np.min(c["d"])) * 1e3 if c["d"].size else -1.0
    axs[1].set_ylim(min(-1.0, dmin * 1.1), d_max_mm)
    axs[1].set_xlabel("time (s)")
    for ax in axs:
        ax.grid(alpha=0.3)
        _segments(ax, motion, label=ax is axs[0])
    _legend(axs[0], k)
    fig.suptitle(f"{motion.name}: contact points (normal force and signed distance)", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def plot_paths(motion, path, n_strobe=6):
    """``path``: x-z paths of the centre of mass and (floating-base robots) the base
    body's origin, with the obstacles and a strobe of the robot (viridis colours:
    purple = start, yellow = end), equal aspect."""
    plt = _mpl()
    from matplotlib.collections import LineCollection
    from matplotlib.patches import Polygon

    poses, com = motion.kinematics()
    fig, ax = plt.subplots(figsize=(7.5, 4.6))  # resized to the data's aspect below
    N = len(motion.t)
    frames = np.unique(np.linspace(0, N - 1, n_strobe).round().astype(int))
    pts = [com[:, [0, 2]]]
    cmap = plt.get_cmap("viridis")
    for k, f in enumerate(frames):
        col = cmap(k / max(1, len(frames) - 1))
        for o in robot_outlines(motion.model, poses[f]):
            ax.add_patch(Polygon(o, closed=True, facecolor=col, edgecolor="k", lw=0.5, alpha=0.35, zorder=2))
            pts.append(o)
        sg, jp, ap = skeleton(motion.model, poses[f])
        ax.add_collection(LineCollection(sg, colors=[col], linewidths=2.0, alpha=0.9, zorder=2.5))
        ax.plot(jp[:, 0], jp[:, 1], "o", color=col, ms=3, zorder=2.5)
        pts.append(sg.reshape(-1, 2))
    ax.plot(com[:, 0], com[:, 2], color="C3", lw=1.6, label="centre of mass", zorder=3)
    b = motion.base_body()
    if b is not None:
        bp = poses[:, b, :3, 3]
        ax.plot(bp[:, 0], bp[:, 2], color="C0", lw=1.2, ls="--", label=f"base ({motion.model.body_names[b]})",
                zorder=3)
        pts.append(bp[:, [0, 2]])
    ax.plot(com[0, 0], com[0, 2], "o", color="C3", ms=5, zorder=4, label="start")
    ax.plot(com[-1, 0], com[-1, 2], "s", color="C3", ms=5, zorder=4, label="end")
    P = np.concatenate(pts)
    lo, hi = P.min(0), P.max(0)
    pad = 0.1 * max(float(np.max(hi - lo)), 0.2)
    xlim, zlim = (lo[0] - pad, hi[0] + pad), (lo[1] - pad, hi[1] + pad)
    if motion.obstacles:
        zlim = (min(zlim[0], -0.06), zlim[1])
    draw_obstacles(ax, motion.obstacles, xlim, zlim)
    r = (zlim[1] - zlim[0]) / (xlim[1] - xlim[0])
    fig.set_size_inches(7.5, float(np.clip(6.3 * r + 1.0, 3.0, 9.0)))
    ax.set_xlim(*xlim)
    ax.set_ylim(*zlim)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m)")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=7)
    ax.set_title(f"{motion.name}: paths in the x-z plane (strobe: purple = start, yellow = end)", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def write_plots(motion, out_dir) -> list:
    """Write ``joints.png``, ``torques.png``, ``contacts.png`` (with contact) and
    ``paths.png`` into ``out_dir``; returns the file names."""
    files = [plot_joints(motion, os.path.join(out_dir, "joints.png"))]
    if motion.active:
        files.append(plot_torques(motion, os.path.join(out_dir, "torques.png")))
    if motion.contact is not None and motion.contact["d"].shape[1]:
        files.append(plot_contacts(motion, os.path.join(out_dir, "contacts.png")))
    files.append(plot_paths(motion, os.path.join(out_dir, "paths.png")))
    return files
