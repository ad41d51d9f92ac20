"""Side-view (x-z) animation of a solved motion: the robot's collision shapes, the
the kinematic skeleton (lines between joints; the only drawing of bodies without shapes),
obstacles, contact-force arrows, the centre-of-mass trace (red) and a time label; a sequence
plays as one continuous motion with its segment's name shown.

Rendering is fast by construction: body poses come from one vmapped forward-kinematics
call (`Motion.kinematics`); frames are subsampled to ``fps`` (default 25) in real time;
the static background (axes, obstacles) is drawn once and every frame only redraws the
moving artists on a copy of it (blitting, Agg); frames are quantized to one shared
palette and written as a GIF with Pillow (and piped to ffmpeg for an MP4 when ``ffmpeg`` is on PATH).

Force arrows start at each contact point and show the total contact force on the robot
(normal plus friction); the scale is printed in the corner (the robot's weight is drawn
as about a third of the robot's size, capped so that the 95th percentile of the peak
forces stays within about 0.6 robot sizes).
"""

from __future__ import annotations

import os
import shutil
import subprocess

import numpy as np

from ..io.files import atomic_write
from .planar import draw_obstacles, robot_extent, robot_outlines, skeleton
from ..progress import bar as progress_bar


def frame_indices(t, fps=25.0, max_frames=2000):
    """Grid indices of frames at ``fps`` frames per second of motion time (the first
    and last sample included; at most ``max_frames``)."""
    t = np.asarray(t, float)
    T = float(t[-1] - t[0])
    n = int(min(max_frames, max(2, round(T * fps) + 1)))
    want = np.linspace(t[0], t[-1], n)
    idx = np.clip(np.searchsorted(t, want), 0, len(t) - 1)
    return np.unique(idx)


def render_frames(motion, *, fps=25.0, size=(6.4, 4.0), dpi=100, max_frames=2000):
    """Render the animation frames: returns ``(frames, fps)`` with ``frames`` a list of
    (H, W, 3) uint8 RGB arrays."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.patches import Polygon

    from matplotlib.collections import LineCollection

    poses, com = motion.kinematics()
    idx = frame_indices(motion.t, fps, max_frames)
    fps_eff = (len(idx) - 1) / motion.duration if motion.duration > 0 and len(idx) > 1 else fps
    outlines = [robot_outlines(motion.model, poses[i]) for i in idx]
    skel = [skeleton(motion.model, poses[i]) for i in idx]
    allpts = np.concatenate([np.concatenate(o) for o in outlines if o] + [s[0].reshape(-1, 2) for s in skel] +
                            [com[:, [0, 2]]])
    lo, hi = allpts.min(0), allpts.max(0)
    extent = robot_extent(motion.model)
    pad = 0.15 * max(float(np.max(hi - lo)), 0.3 * extent)
    xlim, zlim = [lo[0] - pad, hi[0] + pad], [lo[1] - pad, hi[1] + pad]
    if motion.obstacles:
        zlim[0] = min(zlim[0], -0.08 * extent)
    # fit the axes' aspect: widen the narrow direction so the motion fills the frame
    box = (0.09, 0.11, 0.89, 0.83)
    aspect = (box[2] * size[0]) / (box[3] * size[1])
    w, h = xlim[1] - xlim[0], zlim[1] - zlim[0]
    if w / h < aspect:
        c, w = 0.5 * (xlim[0] + xlim[1]), h * aspect
        xlim = [c - w / 2, c + w / 2]
    else:
        h = w / aspect
        if motion.obstacles:  # keep the ground at the bottom, add room above
            zlim = [zlim[0], zlim[0] + h]
        else:
            c = 0.5 * (zlim[0] + zlim[1])
            zlim = [c - h / 2, c + h / 2]

    fig = plt.figure(figsize=size, dpi=dpi)
    ax = fig.add_axes(box)
    ax.set_xlim(*xlim)
    ax.set_ylim(*zlim)
    ax.set_aspect("equal", adjustable="datalim")
    ax.apply_aspect()
    ax.set_xlabel("x (m)", fontsize=8)
    ax.set_ylabel("z (m)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(alpha=0.25)
    ax.set_title(motion.name, fontsize=9)
    draw_obstacles(ax, motion.obstacles, ax.get_xlim(), ax.get_ylim())

    # force arrow scale
    c = motion.contact
    weight = float(np.sum(np.asarray(motion.model.mass))) * float(np.linalg.norm(np.asarray(motion.model.gravity)))
    arrows = None
    if c is not None and c["d"].shape[1]:
        F = c["force"][idx]  # (F, k, 3)
        peak = np.max(np.linalg.norm(F, axis=2), axis=1)
        ref = max(weight, 1e-9)
        scale = 0.33 * extent / ref  # m per N
        p95 = float(np.percentile(peak, 95)) if peak.size else 0.0
        if p95 * scale > 0.6 * extent:
            scale = 0.6 * extent / p95
        k = F.shape[1]
        arrows = ax.quiver(np.zeros(k), np.zeros(k), np.zeros(k), np.zeros(k), angles="xy", scale_units="xy",
                           scale=1.0, color="crimson", width=0.007, headwidth=3.0, headlength=3.5,
                           headaxislength=3.2, minlength=0.0, zorder=6, animated=True)
        ax.text(0.99, 0.98, f"contact force arrows: {ref:.3g} N (weight) = {ref * scale:.2g} m", transform=ax.transAxes,
                ha="right", va="top", fontsize=7, color="crimson",
                bbox=dict(facecolor="white", alpha=0.7, edgecolor="none", pad=1.5))
        shown = c["normal_magnitude"][idx] > 1e-3 * max(weight, 1e-9)

    ngeo = len(outlines[0])
    body_colors = ["C0", "C1", "C2", "C4", "C9", "C8", "C6", "C5"]  # no red (force arrows, CoM) or grey
    patches = [ax.add_patch(Polygon(outlines[0][g], closed=True, facecolor=body_colors[g % 8], edgecolor="k", lw=0.8,
                                    alpha=0.9, zorder=4, animated=True)) for g in range(ngeo)]
    bones = ax.add_collection(LineCollection(skel[0][0], colors="0.15", linewidths=1.6, zorder=5, animated=True))
    jdots, = ax.plot([], [], "o", color="0.15", ms=3.5, zorder=5, animated=True)
    anch, = ax.plot([], [], "^", color="k", ms=7, zorder=5, animated=True)
    trace, = ax.plot([], [], color="C3", lw=0.8, alpha=0.6, zorder=3, animated=True)
    dot, = ax.plot([], [], "o", color="C3", ms=3, zorder=5, animated=True)
    label = ax.text(0.01, 0.98, "", transform=ax.transAxes, ha="left", va="top", fontsize=8, animated=True)
    dyn = patches + [bones, jdots, anch, trace, dot] + ([arrows] if arrows is not None else []) + [label]

    fig.canvas.draw()
    bg = fig.canvas.copy_from_bbox(fig.bbox)
    frames = []
    nseg = len(motion.segment_names)
    with progress_bar(len(idx), "animation frames") as pbar:
        for f, i in enumerate(idx):
            fig.canvas.restore_region(bg)
            for g in range(ngeo):
                patches[g].set_xy(outlines[f][g])
            sg, jp, ap = skel[f]
            bones.set_segments(sg)
            jdots.set_data(jp[:, 0], jp[:, 1])
            anch.set_data(ap[:, 0], ap[:, 1])
            trace.set_data(com[:i + 1, 0], com[:i + 1, 2])
            dot.set_data([com[i, 0]], [com[i, 2]])
            if arrows is not None:
                P = c["p_robot"][i]
                V = F[f] * scale * shown[f][:, None]
                arrows.set_offsets(P[:, [0, 2]])
                arrows.set_UVC(V[:, 0], V[:, 2])
            txt = f"t = {motion.t[i]:6.2f} s"
            if nseg > 1:
                s = int(motion.segment_index[i])
                txt += f"   {s + 1}/{nseg} {motion.segment_names[s]}"
            label.set_text(txt)
            for a in dyn:
                ax.draw_artist(a)
            fig.canvas.blit(fig.bbox)
            frames.append(np.asarray(fig.canvas.buffer_rgba())[:, :, :3].copy())
            pbar.update()
    plt.close(fig)
    return frames, fps_eff


def write_gif(frames, path, fps, colors=64):
    """Write RGB frames as an animated GIF (atomically), looping forever. One palette
    for all frames (from 8 sample frames plus swatches of the drawing colours), so the
    encoder stores only what changes between frames."""
    from PIL import Image
    from matplotlib import colors as mcolors


    idx = np.unique(np.linspace(0, len(frames) - 1, min(8, len(frames))).astype(int))
    w = frames[0].shape[1]
    sw = [np.array(mcolors.to_rgb(c)) * 255 for c in ["crimson", "k", "0.15", "0.88", "white"] +
          [f"C{i}" for i in range(10)]]
    swatch = np.repeat(np.repeat(np.array(sw, np.uint8)[None], 4, axis=0), -(-w // len(sw)), axis=1)[:, :w]
    sample = np.concatenate([frames[i] for i in idx] + [swatch], axis=0)
    pal = Image.fromarray(sample).quantize(colors=colors, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
    ims = [Image.fromarray(f).quantize(palette=pal, dither=Image.Dither.NONE) for f in frames]
    dur = int(round(1000.0 / fps))
    atomic_write(path, lambda tmp: ims[0].save(tmp, format="GIF", save_all=True, append_images=ims[1:],
                                               duration=dur, loop=0, optimize=False), ".gif")
    return os.path.basename(path)


def write_mp4(frames, path, fps, ffmpeg=None):
    """Pipe RGB frames to ffmpeg (H.264, yuv420p) and write ``path`` atomically.
    Returns the file name, or None without ffmpeg or if it fails."""
    ffmpeg = ffmpeg or shutil.which("ffmpeg")
    if not ffmpeg or not frames:
        return None

    h, w = frames[0].shape[:2]
    h2, w2 = h - h % 2, w - w % 2

    def run(tmp):
        cmd = [ffmpeg, "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{w2}x{h2}",
               "-r", f"{fps:.6g}", "-i", "-", "-an", "-vcodec", "libx264", "-pix_fmt", "yuv420p", "-f", "mp4", tmp]
        proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stderr=subprocess.PIPE)
        for fr in frames:
            proc.stdin.write(np.ascontiguousarray(fr[:h2, :w2]).tobytes())
        _, err = proc.communicate()
        if proc.returncode != 0:
            raise RuntimeError(err.decode(errors="replace"))

    try:
        atomic_write(path, run, ".mp4")
    except (OSError, RuntimeError):
        return None
    return os.path.basename(path)


def write_animation(motion, out_dir, *, fps=25.0, mp4=True, name="animation") -> list:
    """Write ``out_dir/animation.gif`` (and ``animation.mp4`` when ffmpeg is on PATH);
    returns the file names written."""
    frames, fps_eff = render_frames(motion, fps=fps)
    files = [write_gif(frames, os.path.join(out_dir, f"{name}.gif"), fps_eff)]
    if mp4:
        f = write_mp4(frames, os.path.join(out_dir, f"{name}.mp4"), fps_eff)
        if f:
            files.append(f)
    return files
