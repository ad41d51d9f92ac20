"""A sequence of motion segments solved in order, each starting where the previous one
ended (the draft's tumbler: standing -> handstand -> roll -> standing).

Segment ``k > 0`` starts from the final configuration and velocity of segment ``k - 1``'s
solution (its own ``q0``/``v0`` are ignored; its active joints' splines start there by
construction). Segments are separate problems with their own costs, constraints, time
step and solve options (continuation, staging).
"""

from __future__ import annotations

import os
import threading

import numpy as np
import jax
import jax.numpy as jnp

from ..errors import ProblemError
from .problem import MotionProblem
from .solution import Solution, Status

__all__ = ["MotionSequence"]


class MotionSequence:
    """``MotionSequence(segments)``: a list of `MotionProblem` on the same model (the same
    joints, ``nq``, ``nv``). ``name`` labels displays and files. ``success_criteria``
    (optional, as for `MotionProblem`) are checked on the whole sequence's solution; each
    segment's own criteria are checked on its segment solution. While the first segment
    solves, the later ones are compiled in a background thread (same results; on a
    2-core machine the other core would idle); ``solve_options["precompile"] = False``
    turns that off."""

    def __init__(self, segments, name="sequence", success_criteria=None):
        segments = list(segments)
        if not segments:
            raise ProblemError("MotionSequence: give at least one segment")
        for k, s in enumerate(segments):
            if not isinstance(s, MotionProblem):
                raise ProblemError(f"MotionSequence: segment {k} is a {type(s).__name__}, not a MotionProblem")
            if s.model.joint_names != segments[0].model.joint_names:
                raise ProblemError(f"MotionSequence: segment {k} uses a different model (joints "
                                   f"{list(s.model.joint_names)} vs {list(segments[0].model.joint_names)})")
            if k > 0 and getattr(s, "free_initial", None):
                raise ProblemError(f"MotionSequence: segment {k} has free_initial, but segments after the first "
                                   "start where the previous one ended")
        self.segments = segments
        self.name = str(name)
        self.success_criteria = success_criteria
        self.solve_options = {}

    def __len__(self):
        return len(self.segments)

    def __repr__(self):
        return f"MotionSequence({self.name!r}, {len(self.segments)} segments)"

    def solve_segments(self, solve_one, *, method, continuation, schedule, max_iter, tol, constraint_tol, verbose,
                       callback, checkpoint, options, out, objective_scale="auto", resume=None):
        """Solve the segments in order with ``solve_one(segment, q0=..., v0=..., **options)``
        (`cstorm.solve`'s single-problem solver), each from the previous one's final
        state, and return the sequence's `Solution` (its ``segments`` hold the segments'
        solutions, its trajectory their concatenation). Stops after an interrupted
        segment. With ``checkpoint=path`` segment ``k`` writes its iterates to
        ``path.seg<k>.npz`` and, once solved (not interrupted), its solution to
        ``path.seg<k>.done.npz``; ``resume=path`` takes every segment whose
        ``.done.npz`` belongs to it (same problem hash) as solved and continues the
        first other one from its ``.seg<k>.npz`` when there is one. A KeyboardInterrupt
        stops the sequence and returns the segments solved so far (one raised before the
        first segment has an iterate propagates)."""
        from .solution import load_solution
        sols = []
        q0 = v0 = None
        stopped_between = False
        resuming = resume is not None
        # (the background compile builds the SQP transcription's functions; DDP compiles its own)
        warm = None
        for k, seg in enumerate(self.segments):
            ck = None if checkpoint is None else f"{checkpoint}.seg{k}.npz"
            rk = None
            if resuming:
                prev = _load_done(f"{resume}.seg{k}.done.npz", seg, load_solution)
                if prev is not None:
                    sols.append(prev)
                    q0, v0 = prev.trajectory["q"][-1], prev.trajectory["v"][-1]
                    if verbose:
                        print(f"{seg.name}: solved in an earlier run ({resume}.seg{k}.done.npz)", file=out)
                    continue
                resuming = False
                rk = f"{resume}.seg{k}.npz" if os.path.exists(f"{resume}.seg{k}.npz") else None
            if warm is None and self.solve_options.get("precompile", True) and method != "ddp" and \
                    k + 1 < len(self.segments):
                warm = (k, _Precompiler(self.segments[k + 1:], first=seg))
            try:
                if warm is not None and k > warm[0]:
                    warm[1].wait(k - warm[0] - 1)  # its compile, started in the background, is done (or failed)
                s = solve_one(seg, method=method, continuation=continuation, schedule=schedule, max_iter=max_iter,
                              tol=tol, constraint_tol=constraint_tol, verbose=verbose, callback=callback,
                              checkpoint=ck, options=options, out=out, q0=q0, v0=v0,
                              objective_scale=objective_scale, resume=rk)
            except KeyboardInterrupt:
                if not sols:
                    raise
                stopped_between = True  # before this segment had an iterate: keep the solved ones
                break
            s.segments = []
            sols.append(s)
            q0, v0 = s.trajectory["q"][-1], s.trajectory["v"][-1]
            if s.status is Status.INTERRUPTED:
                break
            if checkpoint is not None:
                s.save(f"{checkpoint}.seg{k}.done.npz")
        # concatenated trajectory (the first point of later segments is the previous end)
        keys = ("q", "v", "a", "tau")
        traj = {k: [sols[0].trajectory[k]] for k in keys}
        ts = [sols[0].trajectory["t"]]
        off = sols[0].trajectory["t"][-1]
        for s in sols[1:]:
            for k in keys:
                traj[k].append(s.trajectory[k][1:])
            ts.append(s.trajectory["t"][1:] + off)
            off += s.trajectory["t"][-1]
        trajectory = {k: np.concatenate(v) for k, v in traj.items()}
        trajectory["t"] = np.concatenate(ts)
        done = len(sols) == len(self.segments)
        success = done and all(s.success for s in sols)
        bad = [k for k, s in enumerate(sols) if not s.success]
        message = "all segments solved" if success else (
            f"segment(s) {bad} failed: " + "; ".join(sols[k].message for k in bad) if bad else
            f"stopped after {len(sols)} of {len(self.segments)} segments")
        interrupted = stopped_between or any(s.status is Status.INTERRUPTED for s in sols)
        status = Status.SOLVED if success else (Status.INTERRUPTED if interrupted else
                                                 next(s.status for s in sols if not s.success))
        return Solution(success=success, status=status, message=message, cost=float(sum(s.cost for s in sols)),
                        constraint_violation=float(max(s.constraint_violation for s in sols)),
                        iterations=int(sum(s.iterations for s in sols)), x=np.concatenate([s.x for s in sols]),
                        trajectory=trajectory, history=[h for s in sols for h in s.history], segments=sols,
                        problem=self.name, wall_time_s=float(sum(s.wall_time_s for s in sols)),
                        compile_time_s=float(sum(s.compile_time_s for s in sols)),
                        n_evaluations=int(sum(s.n_evaluations for s in sols)),
                        info=dict(segments=[s.problem for s in sols]))


def _load_done(path, seg, load_solution):
    """The solution of ``seg`` saved at ``path`` by an earlier run, or None (no file, or
    a file of another problem)."""
    if not os.path.exists(path):
        return None
    s = load_solution(path)
    if (s.info or {}).get("problem_hash") != seg.hash():
        return None
    s.segments = []
    return s


class _Precompiler:
    """Compiles the later segments' functions in a background thread while the first
    segment solves: the start state of segment ``k > 0`` is data of its compiled
    functions, not a constant, so they can be built before the previous segment ends.

    Why: a rollout's scan runs on one core, and on a 2-core machine the other one would
    wait; the tumbler's four segments spend about 60 s compiling. The results are the
    same (the same compiled functions, evaluated at the same points afterwards).
    ``wait(i)`` blocks until segment ``i`` of the list is compiled (or its compile
    failed: the solve then compiles it again and reports any error where it happens).
    Each segment's ``fun_jac`` and ``trajectory`` are compiled by evaluating them once at
    its own initial guess and start state; a problem that appears twice (or is the first
    segment, which the solve compiles itself) is skipped. ``MotionSequence.solve_options["precompile"]
    = False`` turns this off."""

    def __init__(self, segments, first=None):
        self._done = [threading.Event() for _ in segments]

        def run():
            seen = [first]
            for seg, ev in zip(segments, self._done):
                if any(seg is s for s in seen):  # the same problem again: compiled once
                    ev.set()
                    continue
                seen.append(seg)
                try:
                    x, d = jnp.asarray(np.asarray(seg.x0, float)), seg.data()
                    jax.block_until_ready(seg.compiled("fun_jac")(x, d))
                    jax.block_until_ready(seg.compiled("trajectory")(x, d))
                except Exception:  # noqa: BLE001 - the solve itself reports it
                    pass
                finally:
                    ev.set()

        self._thread = threading.Thread(target=run, name="cstorm-precompile", daemon=True)
        self._thread.start()

    def wait(self, i):
        self._done[i].wait()
