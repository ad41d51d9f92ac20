"""Everything that turns a solved motion into files a person can look at: success
criteria, the re-simulation fidelity check, ``summary.json``, the trajectory CSV, plots
and the animation (`write_outputs`, used by ``cstorm solve`` and ``cstorm animate``).

Works for any `MotionProblem` or `MotionSequence` (planar drawings are in the world x-z
plane; see `cstorm.viz`). Every file is written atomically (a temporary file in the same
folder, then ``os.replace``); ``summary.json`` is written last.

Success criteria: `cstorm.analysis.criteria`; fidelity: `cstorm.analysis.fidelity`;
the torque check: `cstorm.analysis.torque`; file writing: `cstorm.io.files`.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import sys
import time

import numpy as np
import jax
import jax.numpy as jnp

from . import examples
from .analysis.criteria import Criterion, all_criteria, check_criteria_spec, evaluate_criteria
from .analysis.fidelity import DEVIATION_KEYS, fidelity
from .analysis.segments import problem_segments, segment_solutions, select_segment
from .analysis.torque import torque_check
from .errors import InputError
from .model.info import dof_names
from .io.files import atomic_write, json_safe, write_json
from .io.problemfile import load_problem_text
from .optimize.solution import Solution, Status, contact_dict
from .viz import animation as _anim
from .viz import plots as _plots
from .version import __version__
from .viz.motion import Motion

__all__ = ["Criterion", "evaluate_criteria", "fidelity", "make_summary", "write_csv", "write_json", "write_outputs",
           "render", "problem_segments", "problem_from_source", "select_segment", "solution_at", "atomic_write",
           "torque_check", "check_criteria_spec", "all_criteria", "segment_solutions", "problem_hash"]


# ---------------------------------------------------------------------------------------
# Problems, segments and sources
# ---------------------------------------------------------------------------------------
def problem_hash(problem) -> str:
    """A short hash of the problem description (a sequence hashes its segments')."""
    segs = problem_segments(problem)
    if len(segs) == 1 and segs[0] is problem:
        return problem.hash()
    h = hashlib.sha256(json.dumps([problem.name] + [s.hash() for s in segs]).encode()).hexdigest()
    return h[:16]


def problem_from_source(source: dict):
    """Rebuild a problem from a provenance ``source`` dict: ``{"kind": "example", "name":
    ..., "kwargs": {...}}`` (a shipped example) or ``{"kind": "toml", "path": ...,
    "text": ...}`` (a TOML problem file; its stored text is used, the path resolves
    relative robot files; an optional ``"robot": {"package_dirs": [...], "strict": bool}``
    holds the command line's ``--package-dir`` and ``--strict``), each with an optional ``"segment"`` (name) selecting one
    segment of a sequence. Raises `InputError` saying why when it can't."""

    if not isinstance(source, dict) or "kind" not in source:
        raise InputError(f"cannot rebuild the problem: no usable source in the solution's metadata ({source!r}); "
                         "only solutions written by `cstorm solve` (or with report.write_outputs(source=...)) "
                         "record how to rebuild their problem")
    kind = source["kind"]
    if kind == "example":
        name = source.get("name")
        try:
            factory = examples.get(name)
        except InputError as e:
            raise InputError(f"cannot rebuild the problem: {e}") from None
        try:
            problem = factory(**source.get("kwargs", {}))
        except TypeError as e:
            raise InputError(f"cannot rebuild example {name!r} with arguments {source.get('kwargs')}: {e}") from None
    elif kind == "toml":

        robot = source.get("robot") or {}
        problem = load_problem_text(source["text"], source.get("path", "<stored TOML>"), source.get("overrides"),
                                    package_dirs=robot.get("package_dirs", ()), strict=robot.get("strict", False))
    else:
        raise InputError(f"cannot rebuild the problem: unknown source kind {kind!r} (expected 'example' or 'toml')")
    seg = source.get("segment")
    if seg is not None:
        problem = select_segment(problem, seg)
    return problem


def solution_at(problem, x=None, *, evaluate=True, message="not solved: the initial guess"):
    """A `Solution` of ``problem`` at the decision vector ``x`` without solving (default:
    the problem's initial guess ``problem.x0``; for a sequence, a list of per-segment
    vectors or None, each segment starting where the previous one ends, as in a sequence
    solve). ``success`` is False. With ``evaluate`` the cost and constraint violation are
    computed (one more compiled function per problem); otherwise they are NaN. Use it to
    look at initial guesses (``cstorm solve NAME --guess``) or to test output code."""

    segs = problem_segments(problem)
    xs = x if (x is not None and len(segs) > 1) else [x] * len(segs)
    if len(xs) != len(segs):
        raise InputError(f"solution_at: give one decision vector per segment ({len(segs)}), got {len(xs)}")
    sols = []
    q0 = v0 = None
    for p, xk in zip(segs, xs):
        guess = xk is None
        xk = np.asarray(p.x0 if xk is None else xk, float)
        if xk.shape != (p.n_vars,):
            raise InputError(f"solution_at: x for {p.name!r} must have shape ({p.n_vars},), got {xk.shape}")
        data = p.data(q0=q0, v0=v0)
        if guess:  # the guess as `solve` starts from it (multiple shooting: nodes on its rollout)
            xk = p.shoot_nodes(xk, data)
        tr = jax.tree_util.tree_map(np.asarray, p.compiled("trajectory")(jnp.asarray(xk), data))
        traj = dict(t=np.asarray(p.t), q=tr["q"], v=tr["v"], a=tr["a"], tau=tr["tau"], ctrl=tr["ctrl"])
        if tr.get("contact") is not None:
            c = tr["contact"]
            traj["contact"] = c if isinstance(c, dict) else contact_dict(c)
        cost = viol = float("nan")
        if evaluate:
            f, ce, ci, _ = (np.asarray(a) for a in p.compiled("fun")(jnp.asarray(xk), data))
            cost = float(f)
            viol = max([0.0] + ([float(np.max(np.abs(ce)))] if ce.size else []) +
                       ([float(np.max(np.maximum(0.0, -ci)))] if ci.size else []))
        sols.append(Solution(success=False, status=Status.NOT_SOLVED, message=message, cost=cost, constraint_violation=viol, iterations=0,
                             x=xk, trajectory=traj, problem=p.name,
                             params={k: np.asarray(v).tolist() for k, v in p.params.items()},
                             info=dict(problem_hash=p.hash())))
        q0, v0 = tr["q"][-1], tr["v"][-1]
    if len(segs) == 1 and segs[0] is problem:
        s = sols[0]
        s.segments = [Solution(**{**s.__dict__, "segments": []})]
        return s
    traj = {k: np.concatenate([sols[0].trajectory[k]] + [s.trajectory[k][1:] for s in sols[1:]])
            for k in ("q", "v", "a", "tau")}
    ts, off = [sols[0].trajectory["t"]], sols[0].trajectory["t"][-1]
    for s in sols[1:]:
        ts.append(s.trajectory["t"][1:] + off)
        off += s.trajectory["t"][-1]
    traj["t"] = np.concatenate(ts)
    return Solution(success=False, status=Status.NOT_SOLVED, message=message, cost=float(sum(s.cost for s in sols)),
                    constraint_violation=float(max(s.constraint_violation for s in sols)), iterations=0,
                    x=np.concatenate([s.x for s in sols]), trajectory=traj, segments=sols, problem=problem.name)


# ---------------------------------------------------------------------------------------
# summary.json
# ---------------------------------------------------------------------------------------
_FIELDS = ("problem", "success", "message", "cost", "constraint_violation", "iterations", "wall_time_s",
           "compile_time_s")


def make_summary(problem, solution, *, fidelity_report=None, criteria=None, per_segment_criteria=None,
                 source=None, extra_provenance=None, time_step=None) -> dict:
    """The ``summary.json`` dict: ``problem, success, solver_success, message, cost,
    constraint_violation, iterations, wall_time_s, compile_time_s, criteria, fidelity,
    segments`` (the same fields per segment) and ``provenance`` (cstorm version, problem
    hash, solver options, success criteria, source).

    ``torque_limits``: `torque_check` (the effort limits on every step; each segment
    carries its own). Like ``time_step``, it does not enter ``success``.

    ``time_step`` (optional): the `cstorm.check_time_step` result of each segment (a
    list, or one dict for a single problem). When given, every entry of ``segments``
    carries its own under ``"time_step"`` and the summary has ``"time_step"``: the dict
    itself for a single problem; for a sequence ``{"ok", "dt_limit", "message",
    "segments": [{"segment": name, ...}]}`` (``ok``: False if any segment's is, True if
    all are, else None; ``dt_limit``: the smallest; ``solution_ok`` likewise over the
    entries' ``"solution"`` checks, when ``cstorm solve`` added them). It does not enter
    ``success``."""

    segs, sols = problem_segments(problem), segment_solutions(solution)
    if criteria is None:
        criteria, per_segment_criteria = all_criteria(problem, solution)
    per_segment_criteria = per_segment_criteria or [{} for _ in sols]
    crit_ok = all(v.get("ok", False) for v in criteria.values())
    fr = fidelity_report or {}
    if "segments" in fr:
        seg_fid = fr["segments"]
    elif fr:
        seg_fid = [dict(segment=sols[0].problem, ok=fr["ok"], checks=fr.get("checks"),
                        **{k: fr.get(k) for k in DEVIATION_KEYS})]
    else:
        seg_fid = [None] * len(sols)
    segments = []
    for k, s in enumerate(sols):
        ck = per_segment_criteria[k] if k < len(per_segment_criteria) else {}
        ok_k = all(v.get("ok", False) for v in ck.values())
        segments.append(dict(problem=s.problem, success=bool(s.success and ok_k), solver_success=bool(s.success),
                             message=s.message, cost=float(s.cost), constraint_violation=float(s.constraint_violation),
                             iterations=int(s.iterations), wall_time_s=float(s.wall_time_s),
                             compile_time_s=float(s.compile_time_s), n_evaluations=int(s.n_evaluations),
                             t_final=float(np.asarray(s.trajectory["t"])[-1]), criteria=ck,
                             fidelity=seg_fid[k] if k < len(seg_fid) else None))
    ts_top = None
    if time_step is not None:
        ts = list(time_step) if isinstance(time_step, (list, tuple)) else [time_step]
        for k, seg in enumerate(segments):
            seg["time_step"] = ts[k] if k < len(ts) else None
        if len(segs) == 1 and segs[0] is problem:
            ts_top = ts[0] if ts else None
        else:
            def verdict(rs):
                oks = [(r or {}).get("ok") for r in rs]
                return False if False in oks else (True if oks and all(o is True for o in oks) else None)

            lims = [r["dt_limit"] for r in ts if r and r.get("dt_limit") is not None]
            bad = [f"{p.name}: {r['message']}" for p, r in zip(segs, ts) if r and r.get("ok") is False]
            ts_top = dict(ok=verdict(ts), dt_limit=min(lims) if lims else None,
                          message="; ".join(bad) if bad else "every segment's time step is inside its integrator's "
                                                                 "stability limit",
                          segments=[dict(segment=p.name, **(r or {})) for p, r in zip(segs, ts)])
            if any(r and "solution" in r for r in ts):
                ts_top["solution_ok"] = verdict([(r or {}).get("solution") for r in ts])
    message = solution.message
    if solution.success and not crit_ok:
        failed = [k for k, v in criteria.items() if not v.get("ok", False)]
        message = f"{message}; but success criteria failed: {failed}"
    solver_info = sols[0].info if sols else {}
    plans = [json_safe(_jsonable(getattr(p, "solve_options", {}))) for p in segs]
    prov = dict(cstorm_version=__version__, problem_hash=problem_hash(problem), problem_kind=type(problem).__name__,
                solver_options=dict(method=solver_info.get("method"), max_iter=solver_info.get("max_iter"),
                                    tol=solver_info.get("tol"), constraint_tol=solver_info.get("constraint_tol"),
                                    options=solver_info.get("options"), plans=plans),
                success_criteria=_describe_criteria(problem),
                fidelity_tolerances=(fidelity_report or {}).get("tolerances"), source=source,
                python=sys.version.split()[0], platform=platform.platform(),
                created=time.strftime("%Y-%m-%dT%H:%M:%S%z"))
    try:
        prov["jax_version"] = jax.__version__
    except Exception:  # pragma: no cover
        pass
    prov.update(extra_provenance or {})
    out = dict(problem=solution.problem or problem.name, success=bool(solution.success and crit_ok),
               solver_success=bool(solution.success), message=message, cost=float(solution.cost),
               constraint_violation=float(solution.constraint_violation),
               iterations=int(solution.iterations), wall_time_s=float(solution.wall_time_s),
               compile_time_s=float(solution.compile_time_s), n_evaluations=int(solution.n_evaluations),
               t_final=float(np.asarray(solution.trajectory["t"])[-1]), criteria=criteria,
               fidelity=fidelity_report, segments=segments, provenance=prov)
    if time_step is not None:
        out["time_step"] = ts_top
    tq = torque_check(problem, solution)
    out["torque_limits"] = {k: v for k, v in tq.items() if k != "segments"}
    for seg, r in zip(segments, tq["segments"]):
        seg["torque_limits"] = r
    return json_safe(out)


def _describe_criteria(problem):
    out = {}
    for p in problem_segments(problem) + ([problem] if problem not in problem_segments(problem) else []):
        spec = getattr(p, "success_criteria", None)
        if spec is None:
            continue
        if callable(spec):
            out[p.name] = f"callable {getattr(spec, '__qualname__', repr(spec))}"
        else:
            spec = [spec] if isinstance(spec, (dict, Criterion)) else spec
            out[p.name] = [c.spec() if isinstance(c, Criterion) else c for c in spec]
    return json_safe(_jsonable(out))


def _jsonable(d):
    if isinstance(d, dict):
        return {str(k): _jsonable(v) for k, v in d.items()}
    if isinstance(d, (list, tuple)):
        return [_jsonable(v) for v in d]
    if isinstance(d, (np.ndarray, np.generic)):
        return np.asarray(d).tolist()
    if isinstance(d, (str, int, float, bool)) or d is None:
        return d
    return repr(d)


# ---------------------------------------------------------------------------------------
# Trajectory CSV
# ---------------------------------------------------------------------------------------
def write_csv(path, motion) -> str:
    """Write the trajectory of a `cstorm.viz.motion.Motion` as CSV (atomically): columns
    ``t`` (s), ``segment`` (index), ``q_<joint>`` (rad or m; ``_<i>`` per component of
    multi-DoF joints), ``v_<joint>`` (rad/s or m/s), ``tau_<joint>`` (N m or N: motor
    torque of active joints, spring/damper/limit force of passive ones) and, with contact,
    ``N_<geom>_<obstacle>[_<feature>]`` (normal force magnitude of each contact point, N).
    The header names every column."""
    m = motion.model
    cols = [motion.t[:, None], motion.segment_index[:, None].astype(float), motion.q, motion.v, motion.tau]
    header = ["t", "segment"] + [f"q_{n}" for n in dof_names(m, "q")] + [f"v_{n}" for n in dof_names(m, "v")] + \
        [f"tau_{n}" for n in dof_names(m, "v")]
    if motion.contact is not None:
        cols.append(motion.contact["normal_magnitude"])
        header += [f"N_{lab}" for lab in motion.contact_names]
    data = np.concatenate([np.asarray(c, float) for c in cols], axis=1)

    def w(tmp):
        np.savetxt(tmp, data, delimiter=",", header=",".join(header), comments="", fmt="%.10g")
    return atomic_write(path, w, ".csv")


# ---------------------------------------------------------------------------------------
# Everything at once
# ---------------------------------------------------------------------------------------
def write_outputs(problem, solution, out_dir, *, source=None, check_fidelity=True, plots=True, animation=True,
                  save_solution=True, fidelity_report=None, extra_provenance=None, mp4=True, log=None,
                  time_step=None, stopped=None, phase=None, stop_reason=None) -> dict:
    """Write ``out_dir/``: ``solution.npz``, ``trajectory.csv``, the PNG plots
    (``joints.png``, ``torques.png``, ``contacts.png`` when there is contact,
    ``paths.png``), ``animation.gif`` (and ``animation.mp4`` if ffmpeg is on PATH) and,
    last, ``summary.json``. ``source`` (see `problem_from_source`) is stored in the
    solution's ``info`` and the provenance so ``cstorm animate`` can rebuild the problem.

    The solution is saved first (a failure later loses no solve); a fidelity check or
    a picture that fails is recorded in the summary's ``warnings`` (and the fidelity as
    not ok) instead of losing the other files. ``time_step``: per-segment
    `cstorm.check_time_step` results to record (see `make_summary`; a segment whose step
    is not ok also adds a ``warnings`` entry).

    Stopping. ``stopped`` (a reason, e.g. ``"SIGTERM"``) says the solve was stopped
    before it ended: only ``solution.npz``, ``trajectory.csv`` and ``summary.json`` are
    written (no fidelity check, success criteria or pictures), and the summary has
    ``success: false`` and ``stopped: {"reason", "phase"}``. A KeyboardInterrupt during
    the fidelity check, the success criteria or the pictures does the same from there on
    (reason ``stop_reason()`` when given and not None, else ``"KeyboardInterrupt"``). ``phase(name)`` is called as each phase starts
    (``"fidelity"``, ``"success criteria"``, ``"pictures"``, ``"animation"``, and
    ``"writing"`` after each; it may raise KeyboardInterrupt to stop there). Returns the summary dict (with
    ``files``: the names written)."""

    os.makedirs(out_dir, exist_ok=True)
    say = log or (lambda msg: None)
    enter = phase or (lambda name: None)
    interrupted = lambda: (stop_reason() if stop_reason else None) or "KeyboardInterrupt"
    warnings_ = []
    files = []
    stop = dict(reason=str(stopped), phase="solving") if stopped else None
    npz = os.path.join(out_dir, "solution.npz")
    if source is not None:
        solution.info = dict(solution.info or {}, source=source)
    if save_solution:
        solution.save(npz)
        files.append("solution.npz")
    if fidelity_report is None and check_fidelity and stop is None:
        torques = any("ctrl" not in s.trajectory for s in (solution.segments or [solution]))
        try:
            enter("fidelity")
            say("fidelity: re-simulating every segment at dt/4 and " + ("dt/16 (held torques)" if torques else
                                                                        "with DOP853") + " ...")
            fidelity_report = fidelity(problem, solution)
            enter("writing")  # inside the try: a signal until here is this phase's
        except KeyboardInterrupt:
            enter("writing")
            stop = dict(reason=interrupted(), phase="fidelity")
            fidelity_report = None
        except Exception as e:  # recorded, not fatal: the solve's files still get written
            enter("writing")
            fidelity_report = dict(ok=False, flags=[f"fidelity check failed: {type(e).__name__}: {e}"])
            warnings_.append(f"fidelity check failed: {type(e).__name__}: {e}")
    criteria, per_seg = {}, None  # stopped: not evaluated (they can simulate: hold tests)
    if stop is None:
        try:
            enter("success criteria")
            criteria, per_seg = all_criteria(problem, solution)
            enter("writing")
        except KeyboardInterrupt:
            enter("writing")
            stop = dict(reason=interrupted(), phase="success criteria")
    summary = make_summary(problem, solution, fidelity_report=fidelity_report, criteria=criteria,
                           per_segment_criteria=per_seg, source=source, extra_provenance=extra_provenance,
                           time_step=time_step)
    if time_step is not None:
        ts = list(time_step) if isinstance(time_step, (list, tuple)) else [time_step]
        names = [p.name for p in problem_segments(problem)]
        for n, r in zip(names, ts):
            pre = f"time step ({n})" if len(ts) > 1 else "time step"
            if r and r.get("ok") is False:
                warnings_.append(f"{pre}: the initial guess: {r['message']}")
            if r and (r.get("solution") or {}).get("ok") is False:
                warnings_.append(f"{pre}: the solution: {r['solution']['message']}")
    if not summary["torque_limits"]["ok"]:
        warnings_.append(f"torque limits: {summary['torque_limits']['message']}")
    solution.info = dict(solution.info or {}, provenance=summary["provenance"], criteria=criteria,
                         fidelity=fidelity_report)
    if save_solution:
        solution.save(npz)
    motion = Motion.from_solution(problem, solution)
    write_csv(os.path.join(out_dir, "trajectory.csv"), motion)
    files.append("trajectory.csv")
    for what, kw in (("plots", dict(plots=plots, animation=False)), ("animation", dict(plots=False,
                                                                                       animation=animation))):
        if stop is not None or not any(kw.values()):
            continue
        try:
            enter("pictures" if what == "plots" else "animation")
            files += render(motion, out_dir, mp4=mp4, log=say, **kw)
            enter("writing")
        except KeyboardInterrupt:
            enter("writing")
            stop = dict(reason=interrupted(), phase="pictures" if what == "plots" else "animation")
        except Exception as e:
            enter("writing")
            warnings_.append(f"{what} failed: {type(e).__name__}: {e}")
            say(f"warning: {what} failed: {type(e).__name__}: {e}")
    if stop is not None:
        summary["success"] = False
        summary["stopped"] = stop
        summary["message"] = f"stopped ({stop['reason']}) during {stop['phase']}: {summary['message']}"
    summary["warnings"] = warnings_
    summary["files"] = sorted(files + ["summary.json"])
    write_json(os.path.join(out_dir, "summary.json"), summary)
    return summary


def render(motion, out_dir, *, plots=True, animation=True, mp4=True, log=None) -> list:
    """Write the PNG plots and the animation of a `Motion` into ``out_dir``; returns
    the file names written."""

    say = log or (lambda msg: None)
    files = []
    if plots:
        files += _plots.write_plots(motion, out_dir)
    if animation:
        t0 = time.perf_counter()
        files += _anim.write_animation(motion, out_dir, mp4=mp4)
        say(f"animation: {time.perf_counter() - t0:.1f} s")
    return files
