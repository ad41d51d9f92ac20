"""A solved motion gathered for pictures and files: the model, its obstacles and the
trajectory on one time grid (a sequence's segments joined into one continuous motion)."""

from __future__ import annotations

import dataclasses

import numpy as np
import jax

from ..analysis.segments import problem_segments, segment_solutions
from ..contact import contact_labels
from ..dynamics.energy import center_of_mass
from ..dynamics.kinematics import forward_kinematics


@dataclasses.dataclass
class Motion:
    """One continuous motion (host numpy arrays, SI units).

    Attributes:
      name: the problem's name. model: the robot `Model`.
      obstacles: tuple of `cstorm.Obstacle` (the union, by name, of the segments'
        environments; empty without contact).
      t (N,): time, s, from 0. q (N, nq), v (N, nv), tau (N, nv): state and joint forces
        (see `cstorm.simulate`). active: names of the joints that are active in any
        segment.
      segment_index (N,): the segment each sample belongs to (a segment's first sample
        is the previous segment's last; it is counted in the earlier segment).
      segment_names, segment_starts: per segment, its name and start time (s).
      contact: None or dict of per-point arrays on the grid: ``d`` (N, k) m,
        ``normal_magnitude`` (N, k) N, ``p_robot`` (N, k, 3) m, ``force`` (N, k, 3) N
        (normal plus friction, on the robot), world frame.
      contact_names: (k,) labels ``geom_obstacle[_feature]``.
    """

    name: str
    model: object
    obstacles: tuple
    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    tau: np.ndarray
    active: tuple
    segment_index: np.ndarray
    segment_names: tuple
    segment_starts: tuple
    contact: dict | None
    contact_names: tuple

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    @staticmethod
    def from_solution(problem, solution) -> "Motion":
        """Join the segments of ``solution`` (of ``problem``, a `MotionProblem` or
        `MotionSequence`) into one motion."""

        segs, sols = problem_segments(problem), segment_solutions(solution)
        segs = segs[:len(sols)]
        model = segs[0].model
        ts, qs, vs, taus, idx, starts = [], [], [], [], [], []
        off = 0.0
        for k, s in enumerate(sols):
            tr = s.trajectory
            sl = slice(0 if k == 0 else 1, None)
            t = np.asarray(tr["t"], float)
            starts.append(off + float(t[0]))
            ts.append(t[sl] + off), qs.append(np.asarray(tr["q"])[sl]), vs.append(np.asarray(tr["v"])[sl])
            taus.append(np.asarray(tr["tau"])[sl]), idx.append(np.full(len(t[sl]), k))
            off += float(t[-1])
        # obstacles: union by name; contact: joined when every segment has the same points
        obstacles, seen = [], set()
        labels = None
        same = True
        for p in segs:
            if p.env is not None:
                for o in p.env.obstacles:
                    if o.name not in seen:
                        seen.add(o.name), obstacles.append(o)
                lab = contact_labels(p.model, p.env)
            else:
                lab = None
            if labels is None:
                labels = lab
            elif lab != labels:
                same = False
        contact = None
        names = ()
        cds = [s.trajectory.get("contact") for s in sols]
        if same and all(isinstance(c, dict) and "normal_magnitude" in c for c in cds):
            parts = {k: [] for k in ("d", "normal_magnitude", "p_robot", "force")}
            for k, c in enumerate(cds):
                sl = slice(0 if k == 0 else 1, None)
                parts["d"].append(np.asarray(c["d"])[sl])
                parts["normal_magnitude"].append(np.asarray(c["normal_magnitude"])[sl])
                parts["p_robot"].append(np.asarray(c["p_robot"])[sl])
                f = np.asarray(c["normal_force"])
                if "friction_force" in c:
                    f = f + np.asarray(c["friction_force"])
                parts["force"].append(f[sl])
            contact = {k: np.concatenate(v) for k, v in parts.items()}
            kk = contact["d"].shape[1]
            if labels is not None and len(labels) == kk:
                names = tuple(f"{g}_{o}" + (f"_{i}" if i >= 0 else "") for g, o, i in labels)
            else:
                names = tuple(f"point{i}" for i in range(kk))
        active = []
        for p in segs:
            active += [a for a in p.active if a not in active]
        return Motion(name=solution.problem or problem.name, model=model, obstacles=tuple(obstacles),
                      t=np.concatenate(ts), q=np.concatenate(qs), v=np.concatenate(vs), tau=np.concatenate(taus),
                      active=tuple(active), segment_index=np.concatenate(idx),
                      segment_names=tuple(p.name for p in segs), segment_starts=tuple(starts), contact=contact,
                      contact_names=names)

    # ------------------------------------------------------------------ kinematics
    def kinematics(self):
        """``(poses (N, n_bodies, 4, 4), com (N, 3))`` on the whole grid (world frame;
        computed once by one compiled, vmapped forward-kinematics call, then cached)."""
        if getattr(self, "_kin", None) is None:

            fn = jax.jit(jax.vmap(lambda m, q: (forward_kinematics(m, q), center_of_mass(m, q)), in_axes=(None, 0)))
            poses, com = fn(self.model, np.asarray(self.q))
            self._kin = (np.asarray(poses), np.asarray(com))
        return self._kin

    def base_body(self):
        """Index of the floating base's body (the child of a free joint named ``root``
        or of the planar base's ``root_pitch``; else the first body moved by a free
        joint), or None for a fixed-base robot."""
        m = self.model
        for name in ("root", "root_pitch"):
            if name in m.joint_names:
                return m.joint_names.index(name)
        for i, j in enumerate(m.joints):
            if type(j).__name__ == "Free":
                return i
        return None
