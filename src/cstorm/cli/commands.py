"""The ``cstorm`` command line.

Exit codes: 0 success, 1 a solve/simulation failed, 2 bad input. ``--json`` puts exactly
one JSON object on stdout (human messages go to stderr).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import threading


def _setup_jax():
    """float64, and JAX's persistent compilation cache in ``$CSTORM_JAX_CACHE`` (default
    ``~/.cache/cstorm/jax``; an empty value turns it off). A cache directory configured
    already (by a host program or the test-suite) is left as it is. Before JAX starts,
    `cstorm.allocator.tune_allocator` (``CSTORM_MALLOC=system`` leaves malloc as it is;
    inside a host program that has started JAX already it is left alone)."""
    from ..allocator import tune_allocator

    tune_allocator(late="skip")
    import jax

    jax.config.update("jax_enable_x64", True)
    cache = os.environ.get("CSTORM_JAX_CACHE", os.path.join(os.path.expanduser("~"), ".cache", "cstorm", "jax"))
    if not cache or jax.config.jax_compilation_cache_dir:
        return
    try:
        jax.config.update("jax_compilation_cache_dir", cache)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
    except Exception:  # pragma: no cover - cache is an optimization only
        pass


def load_model(spec: str, floating_base=None, package_dirs=(), strict=False):
    """A model from a shipped robot name, a shipped problem's name (its robot), a URDF,
    MJCF or TOML problem file path. ``package_dirs`` and ``strict`` go to the loaders
    (``--package-dir``, ``--strict``)."""
    import cstorm as cs
    from ..report import problem_segments

    if spec in cs.robots.REGISTRY:
        return cs.robots.get(spec)
    if not os.path.exists(spec):
        if spec in cs.examples.names():
            problem, _ = resolve_problem(spec)
            return problem_segments(problem)[0].model
        raise cs.ModelError(f"{spec!r} is neither a shipped robot ({', '.join(cs.robots.names())}), nor a shipped "
                            f"problem ({', '.join(cs.examples.names())}), nor a file")
    check = "strict" if strict else "warn"
    low = spec.lower()
    if low.endswith(".urdf"):
        return cs.load_urdf(spec, floating_base=floating_base, package_dirs=list(package_dirs), inertia_check=check)
    if low.endswith(".xml") or low.endswith(".mjcf"):
        return cs.load_mjcf(spec, inertia_check=check, strict=strict)
    if low.endswith(".toml"):
        problem, _ = resolve_problem(spec, package_dirs=package_dirs, strict=strict)
        return problem_segments(problem)[0].model
    raise cs.ModelError(f"{spec}: unknown model file type (expected .urdf, .xml, .mjcf or a .toml problem file)")


def cmd_info(args):
    from ..model.info import describe

    model = _with_warnings_on_stderr(args, lambda: load_model(args.model, floating_base=args.floating_base,
                                                              package_dirs=_package_dirs(args), strict=args.strict))
    if args.json:
        print(json.dumps(_model_json(model)))
    else:
        print(describe(model))
    return 0


def _package_dirs(args):
    """``--package-dir`` values, made absolute and checked."""
    from ..errors import InputError

    out = []
    for d in getattr(args, "package_dir", None) or []:
        if not os.path.isdir(d):
            raise InputError(f"--package-dir {d!r}: not a directory")
        out.append(os.path.abspath(d))
    return out


def _with_warnings_on_stderr(args, fn):
    """Run ``fn`` showing each model warning as one line on stderr (also under --json)."""
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = fn()
    for w in caught:
        print(f"cstorm {getattr(args, 'cmd', 'solve')}: warning: {w.message}", file=sys.stderr)
    return out


def _model_json(model):
    import numpy as np

    return dict(
        name=model.name, nq=model.nq, nv=model.nv, n_bodies=model.n_bodies,
        bodies=[dict(name=n, parent=(model.body_names[p] if p >= 0 else None), joint=j, joint_type=jt.name,
                     mass=float(m)) for n, p, j, jt, m in zip(model.body_names, model.parents, model.joint_names,
                                                              model.joints, np.asarray(model.mass))],
        geoms=list(model.geom_names), total_mass=float(np.sum(np.asarray(model.mass))), notes=list(model.notes),
    )


def cmd_demo(args):
    """The main demo: describe the demo robot, then solve its shipped motion problem
    (the tumbler sequence, `cstorm.viz.demo.DEMO_PROBLEM`) exactly as ``cstorm solve``
    does and write its outputs (summary.json, solution.npz, trajectory.csv, plots,
    animation) to ``--out``. Exit codes as for ``cstorm solve``."""
    from ..report import problem_segments
    from ..viz import demo as viz_demo
    from . import outdir

    out = args.out
    problem, _ = resolve_problem(viz_demo.DEMO_PROBLEM)
    outdir.prepare(out, force=args.force, resume=args.resume, command=["cstorm"] + list(args.argv or []))
    info = viz_demo.write_model_info(out, problem_segments(problem)[0].model)
    outdir.record(out, [f"{problem_segments(problem)[0].model.name}_info.txt"])
    if not args.quiet:
        print(info + "\n", file=sys.stderr)
    solve_args = argparse.Namespace(
        problem=viz_demo.DEMO_PROBLEM, out=out, segment=None, method=None, max_iter=None, tol=None,
        checkpoint=True, no_checkpoint=args.no_checkpoint, resume=args.resume, force=False, out_ready=True, set=[],
        guess=args.guess, no_animation=args.no_animation, no_fidelity=args.no_fidelity, no_step_check=False,
        json=args.json, quiet=args.quiet, argv=args.argv, run=args.run, cmd="demo")
    return cmd_solve(solve_args)


def _parse_set(items):
    """``--set KEY=VALUE`` pairs -> dict (VALUE parsed as JSON when it is JSON, else a
    string)."""
    from ..errors import InputError

    out = {}
    for it in items or []:
        if "=" not in it:
            raise InputError(f"--set {it!r}: expected KEY=VALUE (e.g. --set dt=0.02)")
        k, v = it.split("=", 1)
        try:
            out[k.strip()] = json.loads(v)
        except json.JSONDecodeError:
            out[k.strip()] = v
    return out


def resolve_problem(spec: str, kwargs=None, segment=None, package_dirs=(), strict=False):
    """``(problem, source)`` for a shipped example name or a TOML problem file path;
    ``kwargs`` go to the example's factory; ``segment`` selects one segment of a
    sequence (see `cstorm.report.select_segment`); ``package_dirs`` and ``strict`` go to
    a problem file's robot loader (shipped examples build their robots themselves)."""
    import cstorm as cs
    from ..errors import InputError
    from ..io.problemfile import read_problem_file
    from ..report import problem_from_source

    if spec.lower().endswith(".toml") or os.path.isdir(spec) or (os.path.sep in spec and os.path.exists(spec)):
        if not os.path.exists(spec):
            raise InputError(f"problem file {spec!r} not found")
        if os.path.isdir(spec):
            raise InputError(f"problem {spec!r} is a directory; give a .toml problem file or a shipped example "
                             f"({', '.join(cs.examples.names())})")
        source = dict(kind="toml", path=os.path.abspath(spec), text=read_problem_file(spec))
        if kwargs:
            source["overrides"] = dict(kwargs)
        if package_dirs or strict:
            source["robot"] = dict(package_dirs=list(package_dirs), strict=bool(strict))
    else:
        if spec not in cs.examples.names():
            raise InputError(f"unknown problem {spec!r}: not a shipped example ({', '.join(cs.examples.names())}) "
                             "and not a .toml problem file")
        source = dict(kind="example", name=spec, kwargs=dict(kwargs or {}))
    if segment is not None:
        source["segment"] = segment
    key = json.dumps(source, sort_keys=True, default=str)
    if key not in _PROBLEMS:
        if len(_PROBLEMS) >= 8:
            _PROBLEMS.pop(next(iter(_PROBLEMS)))
        _PROBLEMS[key] = problem_from_source(source)
    return _PROBLEMS[key], source


# problems built by `resolve_problem` in this process, by source: calling `main` again for
# the same problem (a notebook, the test-suite) reuses its compiled functions
_PROBLEMS: dict = {}


def _check_time_steps(problem, log, cmd="solve"):
    """`cstorm.check_time_step` on every segment (along its initial guess), before
    solving: a warning line on stderr (also under ``--json``) for each segment whose
    step is past its integrator's stability limit. Returns the per-segment results
    (recorded under ``time_step`` in summary.json; `_check_solution_steps` adds the
    check along the solution). A check that fails with an error is recorded (``ok:
    None``) and does not stop the solve. Cost: see `cstorm.analysis.timestep` (the
    linearization compiles once per robot and contact structure, ~10 s for the tumbler
    on a loaded 2-core machine; the guess's rollout at dt/4 is the fidelity check's,
    compiled once)."""
    from ..report import problem_segments
    from ..analysis.timestep import check_time_step

    out = []
    for seg in problem_segments(problem):
        try:
            r = check_time_step(seg)
        except Exception as e:  # the check must not stop a solve; say why it did not run
            r = dict(ok=None, dt=float(seg.dt), integrator=seg.integrator, dt_limit=None,
                     message=f"time-step check failed: {type(e).__name__}: {e}")
        if r.get("ok") is False or r.get("ok") is None:
            print(f"cstorm {cmd}: warning: {seg.name}: the initial guess: {r['message']}", file=sys.stderr)
        else:
            log(f"time step ({seg.name}): {r['message']}")
        out.append(r)
    return out


def _check_solution_steps(problem, sol, time_step, cmd="solve"):
    """After a solve: the check along each segment's solution (its controls rolled out at
    dt/4 from its start), stored as ``"solution"`` in that segment's entry of
    ``time_step``; a warning line on stderr where not ok. Cheap: the linearization and
    the rollout are compiled by then."""
    from ..report import problem_segments, segment_solutions
    from ..analysis.timestep import check_time_step

    for seg, s, r in zip(problem_segments(problem), segment_solutions(sol), time_step):
        try:
            rs = check_time_step(seg, along=s)
        except Exception as e:  # recorded, not fatal
            rs = dict(ok=None, dt=float(seg.dt), integrator=seg.integrator, dt_limit=None,
                      message=f"time-step check of the solution failed: {type(e).__name__}: {e}")
        if rs.get("ok") is not True:
            print(f"cstorm {cmd}: warning: {seg.name}: the solution: {rs['message']}", file=sys.stderr)
        r["solution"] = rs


def cmd_solve(args):
    """Solve a shipped example or a TOML problem file; write summary.json, solution.npz,
    trajectory.csv, plots and an animation (see `cstorm.report.write_outputs`) to a
    fresh output directory (`cstorm.cli.outdir`). Before solving, checks every
    segment's time step against its integrator's stability limit along its initial
    guess (`cstorm.check_time_step`; ``--no-step-check`` skips it), and after solving
    along the solution: a warning on stderr when past it, the results under
    ``time_step`` in summary.json. The solver writes a checkpoint every iteration
    (``--no-checkpoint``: none), removed once the run ends unstopped; a stopped run
    (`cstorm.cli.runstate`) keeps it for ``--resume``."""
    import cstorm as cs
    from ..errors import InputError
    from ..optimize.sequence import MotionSequence
    from ..optimize.solve import check_solve_arguments
    from ..optimize.solution import Status
    from ..report import write_outputs
    from . import outdir

    run = args.run
    cmd = getattr(args, "cmd", "solve")
    problem, source = _with_warnings_on_stderr(args, lambda: resolve_problem(
        args.problem, _parse_set(args.set), args.segment, package_dirs=_package_dirs(args),
        strict=getattr(args, "strict", False)))
    run.problem_name = problem.name
    label = problem.name if args.segment is None else f"{source.get('name', problem.name)}-{problem.name}"
    out = args.out or os.path.join("cstorm-out", label)
    so = dict(getattr(problem, "solve_options", {}) or {})
    method = args.method or so.get("method", "slsqp")
    max_iter = args.max_iter if args.max_iter is not None else so.get("max_iter", 500)
    kw = {k: so[k] for k in ("tol", "constraint_tol", "options") if k in so}
    if args.tol is not None:
        kw["tol"] = args.tol
    if not args.guess:
        check_solve_arguments(method, max_iter, kw.get("tol", 1e-8), kw.get("constraint_tol", 1e-6),
                              kw.get("options"))
    ck = os.path.join(out, "checkpoint.npz")
    is_seq = isinstance(problem, MotionSequence)
    if args.resume:
        if not (os.path.isdir(out) and outdir.checkpoint_files(out)):
            raise InputError(f"--resume: no checkpoint in {out} (a run writes one unless --no-checkpoint; a run "
                             "that ended unstopped removes it)")
        if not is_seq and not os.path.exists(ck):
            raise InputError(f"--resume: no checkpoint at {ck}")
        kw["resume"] = ck
    if not getattr(args, "out_ready", False):
        outdir.prepare(out, force=getattr(args, "force", False), resume=args.resume,
                       command=["cstorm"] + list(args.argv or []))
    run.out = out
    log = run.say
    log(f"cstorm {cmd} {args.problem}" + (f" --segment {args.segment}" if args.segment else "") +
        f": {problem!r}; method {method}, max_iter {max_iter}; output {out}")
    checkpoint = None if getattr(args, "no_checkpoint", False) else ck
    time_step = None
    try:
        if not getattr(args, "no_step_check", False):
            run.enter("checking the time step", "dt against the integrator's stability limit along the initial guess")
            time_step = _check_time_steps(problem, log, cmd)
        if args.guess:
            from ..report import solution_at

            run.enter("writing", "--guess: the outputs of the initial guess, not solved")
            sol = solution_at(problem, evaluate=False)
        else:
            run.enter("solving", "compiling first (10-90 s), then one line per iteration")
            sol = cs.solve(problem, method=method, max_iter=max_iter, verbose=not run.quiet, out=sys.stderr,
                           checkpoint=checkpoint, callback=run.callback, **kw)
            run.enter("writing")  # a signal from here on is noted, not raised: the outputs get written
            log(f"solved in {sol.wall_time_s:.1f} s (compile {sol.compile_time_s:.1f} s): {sol.message}")
    except KeyboardInterrupt:
        return _stopped_before_iterates(run, args, out)
    stopped = run.stop_reason or ("SIGINT" if getattr(sol, "status", None) is Status.INTERRUPTED else None)
    if time_step is not None and not args.guess and stopped is None:
        try:
            run.enter("checking the solution's time step")
            _check_solution_steps(problem, sol, time_step, cmd)
            run.enter("writing")
        except KeyboardInterrupt:
            run.enter("writing")
            stopped = run.stop_reason or "SIGINT"
    run.enter("writing", f"files to {out}")
    summary = write_outputs(problem, sol, out, source=source, check_fidelity=not args.no_fidelity,
                            animation=not args.no_animation,
                            extra_provenance=dict(command=["cstorm"] + list(args.argv or [])), log=log,
                            time_step=time_step, stopped=stopped, phase=run.enter,
                            stop_reason=lambda: run.stop_reason)
    if summary.get("stopped") and stopped is None:
        stopped = run.stop_reason or "SIGINT"
    if stopped is None:
        for f in outdir.checkpoint_files(out):  # a finished run leaves nothing to resume
            os.unlink(os.path.join(out, f))
    kept = outdir.checkpoint_files(out)
    outdir.record(out, list(summary["files"]) + kept)
    summary["out"] = os.path.abspath(out)
    if args.json:
        print(json.dumps(summary))
    else:
        fid = summary.get("fidelity") or {}
        fl = ("fidelity ok" if fid.get("ok") else f"fidelity FLAGGED: {'; '.join(fid.get('flags', []))}") if fid \
            else "fidelity not checked"
        dev = ", ".join(f"{k} {fid[k]:.2g}" for k in ("position_m", "angle_deg") if fid.get(k) is not None)
        failed = [k for k, v in summary["criteria"].items() if not v.get("ok")]
        g = lambda x, fmt: "n/a" if x is None else format(x, fmt)
        print(f"{summary['problem']}: {'success' if summary['success'] else 'FAILED'}: {summary['message']}\n"
              f"  cost {g(summary['cost'], '.6g')}, violation {g(summary['constraint_violation'], '.2e')}, "
              f"{summary['iterations']} iterations, {summary['wall_time_s']:.1f} s "
              f"(compile {summary['compile_time_s']:.1f} s)\n"
              f"  criteria: {len(summary['criteria']) - len(failed)}/{len(summary['criteria'])} ok"
              + (f" (failed: {failed})" if failed else "") + f"; {fl}" + (f" ({dev})" if dev else "") +
              "".join(f"\n  warning: {w}" for w in summary.get("warnings", [])) +
              f"\n  wrote {', '.join(summary['files'])} to {out}", file=sys.stderr)
    if stopped is not None:
        phase = (summary.get("stopped") or {}).get("phase", "solving")
        again = f"cstorm {cmd}" + ("" if cmd == "demo" else f" {args.problem}") + f" --out {out} --resume"
        print(f"cstorm: stopped by {stopped} during {phase}; wrote the best iterate (summary.json, solution.npz, "
              f"trajectory.csv) to {out}" + (f"; `{again}` continues" if kept else ""), file=sys.stderr, flush=True)
        return run.exit_code() if run.signum is not None else 130
    return 0 if summary["success"] else 1


def _stopped_before_iterates(run, args, out):
    """A run stopped before the solver had an iterate (checking the time step,
    compiling): a summary.json that says so, one line on stderr, 128 + the signal."""
    from . import outdir

    name = run.stop_reason or "SIGINT"
    where = "while checking the time step" if run.phase == "checking the time step" else "while compiling"
    run.write_stub(name, where)
    outdir.record(out, ["summary.json"] + outdir.checkpoint_files(out))
    if args.json:
        print(json.dumps(dict(success=False, error="Stopped", message=f"stopped by {name} {where}, before the "
                                                                       "first iterate", out=os.path.abspath(out))))
    print(f"cstorm: stopped by {name} {where}, before the first iterate; wrote {os.path.join(out, 'summary.json')}",
          file=sys.stderr, flush=True)
    return run.exit_code() if run.signum is not None else 130


def cmd_animate(args):
    """Re-render plots and the animation from a saved solution (a directory holding
    solution.npz, or the .npz itself), rebuilding the problem from the solution's
    recorded source (a shipped example with its arguments, or the stored TOML text)."""
    import numpy as np

    import cstorm as cs
    from ..errors import InputError
    from ..report import problem_from_source, problem_segments, render, segment_solutions, write_csv
    from ..viz.motion import Motion
    from . import outdir

    path = args.solution
    npz = os.path.join(path, "solution.npz") if os.path.isdir(path) else path
    if not os.path.exists(npz):
        raise InputError(f"animate: no solution at {npz!r} (give a directory written by `cstorm solve` or its "
                         "solution.npz)")
    if not npz.lower().endswith(".npz"):
        raise InputError(f"animate: {npz!r} is not a solution file (a .npz written by `cstorm solve`); give the "
                         "run's directory or its solution.npz")
    sol = cs.load_solution(npz)
    info = sol.info or {}
    source = info.get("source") or (info.get("provenance") or {}).get("source")
    if source is None:
        raise InputError(f"animate: {npz} does not record how to rebuild its problem (no 'source' in its metadata); "
                         "solutions written by `cstorm solve` do")
    problem = problem_from_source(source)
    segs, sols = problem_segments(problem), segment_solutions(sol)
    if len(sols) > len(segs) or any(p.model.nq != np.shape(s.trajectory["q"])[1] for p, s in zip(segs, sols)):
        raise InputError(f"animate: the rebuilt problem {problem.name!r} does not match the saved solution "
                         f"({len(segs)} segment(s), nq={segs[0].model.nq}; the solution has {len(sols)} segment(s), "
                         f"q of shape {np.shape(sols[0].trajectory['q'])})")
    stored = (info.get("provenance") or {}).get("problem_hash")
    from ..report import problem_hash
    if stored and stored != problem_hash(problem) and not args.json:
        print(f"cstorm animate: warning: the rebuilt problem's hash {problem_hash(problem)} differs from the saved "
              f"one {stored} (the example or file changed since); drawing anyway", file=sys.stderr)
    own = os.path.dirname(os.path.abspath(npz))
    out = args.out or own
    if os.path.abspath(out) != own:  # into the solution's own directory: the same run's pictures, redrawn
        outdir.prepare(out, force=args.force, command=["cstorm"] + list(args.argv or []))
    motion = Motion.from_solution(problem, sol)
    files = render(motion, out, animation=not args.no_animation)
    if args.csv:
        write_csv(os.path.join(out, "trajectory.csv"), motion)
        files.append("trajectory.csv")
    if outdir.read_manifest(out) is not None:
        outdir.record(out, files)
    res = dict(success=True, problem=motion.name, out=os.path.abspath(out), files=sorted(files))
    if args.json:
        print(json.dumps(res))
    else:
        print(f"{motion.name}: wrote {', '.join(res['files'])} to {out}", file=sys.stderr)
    return 0


def cmd_check_gradients(args):
    """Exact against central finite-difference Jacobians of the objective and the
    constraints (`cstorm.check_gradients` with the step sweep `cstorm.optimize.gradcheck.SWEEP`),
    at the initial guess and a random nearby point; a sequence segment by segment. Exit 0
    when every row's error (relative to the row's largest entry) is at most ``--tol``,
    else 1."""
    import cstorm as cs
    from ..optimize.gradcheck import SWEEP

    problem, _ = _with_warnings_on_stderr(args, lambda: resolve_problem(args.problem, _parse_set(args.set)))
    if not (args.tol > 0):
        from ..errors import InputError
        raise InputError(f"--tol must be > 0, got {args.tol}")
    args.run.say(f"checking gradients of {problem!r} (compiling first)")
    res = cs.check_gradients(problem, eps=SWEEP, tol=args.tol)
    segs = res.get("segments") or [dict(res, segment=problem.name)]
    if args.json:
        keep = lambda r: {k: v for k, v in r.items() if isinstance(v, (int, float, str, bool))}
        print(json.dumps(dict(keep(res), problem=problem.name, segments=[keep(r) for r in segs])))
    else:
        for r in segs:
            print(f"{r['segment']}: largest error per row (relative to the row's largest entry) "
                  f"{r['row_error']:.2e} at {r['worst_row']}: {'ok' if r['ok'] else 'WRONG'} (tol {args.tol:g})",
                  file=sys.stderr)
    return 0 if res["ok"] else 1


def build_parser():
    from .. import __version__

    p = _Parser(prog="cstorm", description="Optimal motions for robots that make and break contact. Exit codes: 0 "
                                           "success, 1 a solve failed, 2 bad input, 128 + N stopped by signal N "
                                           "(130 Ctrl-C, 143 SIGTERM, 129 SIGHUP).")
    p.add_argument("--version", action="version", version=f"cstorm {__version__}")
    sub = p.add_subparsers(dest="cmd", required=True)
    pi = sub.add_parser("info", help="describe a robot model (shipped robot or problem name, URDF, MJCF or TOML "
                                     "problem file)",
                        description="Describe a robot: its tree of bodies and joints (types, DoFs), masses, "
                                    "inertias, collision shapes and the loader's notes.")
    pi.add_argument("model", help="a shipped robot (tumbler, double_pendulum), a shipped problem's name (its "
                                  "robot), or a .urdf / .xml / .toml path")
    pi.add_argument("--floating-base", choices=["free", "planar"], default=None,
                    help="give a URDF's root body a floating base: free (6 DoF) or planar (x, z, pitch)")
    _robot_options(pi)
    pi.add_argument("--json", action="store_true", help="print the description as one JSON object on stdout")
    pi.set_defaults(fn=cmd_info)
    pd = sub.add_parser("demo", help="solve the demo motion (the tumbling robot's four segments) and write its "
                                     "files",
                        description="The main demo: write the tumbling robot's model description "
                                    "(tumbler_info.txt), solve start -> handstand -> roll -> standing -> start (as "
                                    "`cstorm solve tumbler`, 10-25 min on 2 cores) and write summary.json, "
                                    "solution.npz, trajectory.csv, PNG plots and animation.gif to --out. "
                                    "Stopped (Ctrl-C, SIGTERM, SIGHUP), it writes the segments solved so far; "
                                    "--resume continues. `cstorm solve luxo` is a shorter alternative (2-4 min).")
    pd.add_argument("--out", default=os.path.join("cstorm-out", "demo"), help="output directory "
                                                                               "(default ./cstorm-out/demo)")
    pd.add_argument("--guess", action="store_true", help="do not solve: write the outputs of the initial guess "
                                                          "(exit code 1, as for cstorm solve --guess)")
    _run_options(pd)
    pd.set_defaults(fn=cmd_demo)
    ps = sub.add_parser("solve", help="solve a shipped motion problem or a TOML problem file; write results",
                        description="Solve PROBLEM (a shipped example name or a .toml problem file) and write "
                                    "summary.json, solution.npz, trajectory.csv, PNG plots and animation.gif to "
                                    "--out (default ./cstorm-out/<problem>). Exit 0: solved and every success "
                                    "criterion met; 1: the solve failed; 2: bad input; 130/143/129: stopped by "
                                    "Ctrl-C/SIGTERM/SIGHUP (the best iterate is written; --resume continues).")
    ps.add_argument("problem", help="shipped example name (e.g. acrobot) or path to a .toml problem file")
    ps.add_argument("--out", default=None, help="output directory (default ./cstorm-out/<problem>); must be new, "
                                                "empty, or written by cstorm (see --force, --resume)")
    ps.add_argument("--segment", default=None, metavar="NAME",
                    help="solve only this segment of a sequence (name or 0-based index), from the segment's own "
                         "nominal start state (its q0, v0)")
    ps.add_argument("--method", choices=["slsqp", "trust-constr", "ipopt", "ddp"], default=None,
                    help="solver: the paper's SQP (slsqp, trust-constr, ipopt) on B-spline paths, or constrained "
                         "DDP on per-step motor torques (ddp) (default: the problem's choice, else slsqp)")
    ps.add_argument("--max-iter", type=int, default=None, help="iteration limit per stage, >= 1 (default: the "
                                                               "problem's, else 500)")
    ps.add_argument("--tol", type=float, default=None, help="optimality tolerance, > 0 (default: the problem's, "
                                                            "else 1e-8)")
    ps.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a shipped example's factory keyword argument (e.g. --set dt=0.02), or for a problem "
                         "file a dotted key of the file (e.g. --set motion.dt=0.01); VALUE is read as JSON")
    ps.add_argument("--guess", action="store_true",
                    help="do not solve: write the outputs (plots, animation) of the initial guess; its cost and "
                         "constraint violation are not evaluated (exit code 1)")
    ps.add_argument("--no-step-check", action="store_true",
                    help="skip the check of dt against the integrator's stability limit (cstorm.check_time_step), "
                         "run along the initial guess before solving and along the solution after")
    _run_options(ps)
    _robot_options(ps)
    ps.set_defaults(fn=cmd_solve)
    pa = sub.add_parser("animate", help="re-render plots and the animation of a saved solution",
                        description="Rebuild the problem a saved solution records and draw its plots and "
                                    "animation again, into the solution's directory or --out.")
    pa.add_argument("solution", help="a directory written by `cstorm solve`, or its solution.npz")
    pa.add_argument("--out", default=None, help="output directory (default: the solution's); another directory "
                                                "must be new, empty or written by cstorm (see --force)")
    pa.add_argument("--force", action="store_true", help="replace the files of an earlier cstorm run in --out")
    pa.add_argument("--no-animation", action="store_true", help="plots only")
    pa.add_argument("--csv", action="store_true", help="also rewrite trajectory.csv")
    pa.add_argument("--json", action="store_true", help="print the result (files written) as one JSON object")
    pa.add_argument("--quiet", action="store_true", help="no progress lines or bars on stderr")
    pa.set_defaults(fn=cmd_animate)
    pg = sub.add_parser("check-gradients", help="exact vs finite-difference gradients of a problem",
                        description="Compare the exact Jacobian of the objective and the constraints with central "
                                    "finite differences (steps 1e-4 ... 1e-7, each row at its best step) at the "
                                    "initial guess and at a random nearby point; a sequence segment by segment. "
                                    "Each row's error is relative to the row's largest entry. Exit 0 when every "
                                    "row agrees within --tol, 1 when one does not, 2 on bad input.")
    pg.add_argument("problem", help="shipped example name (e.g. hopper) or path to a .toml problem file")
    pg.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="as for `cstorm solve`: a factory argument or a dotted key of the problem file")
    pg.add_argument("--tol", type=float, default=1e-4, help="largest row error accepted (default 1e-4)")
    pg.add_argument("--json", action="store_true", help="print the result as one JSON object on stdout")
    pg.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    pg.set_defaults(fn=cmd_check_gradients)
    return p


def _run_options(p):
    """Options shared by ``solve`` and ``demo``."""
    p.add_argument("--force", action="store_true",
                   help="replace the files of an earlier cstorm run in the output directory (a directory cstorm "
                        "did not write is never touched)")
    p.add_argument("--resume", action="store_true",
                   help="continue a stopped run from the checkpoints in its output directory (a sequence: from "
                        "the segment where it stopped)")
    p.add_argument("--no-checkpoint", action="store_true",
                   help="write no checkpoint (by default the solver writes OUT/checkpoint.npz every iteration, "
                        "removed when the run ends unstopped)")
    p.add_argument("--checkpoint", action="store_true", help=argparse.SUPPRESS)  # the default; kept for scripts
    p.add_argument("--no-animation", action="store_true", help="skip the animation")
    p.add_argument("--no-fidelity", action="store_true", help="skip the re-simulation fidelity check")
    p.add_argument("--json", action="store_true", help="print exactly one JSON object (the summary) on stdout; "
                                                       "progress still goes to stderr")
    p.add_argument("--quiet", action="store_true", help="no progress lines, iterations or bars on stderr "
                                                        "(warnings, errors and the result still print)")


def _robot_options(p):
    p.add_argument("--package-dir", action="append", default=[], metavar="DIR",
                   help="a directory holding ROS packages (or one package), for URDF package:// mesh URIs; "
                        "repeatable; searched before ROS_PACKAGE_PATH and the directories around the file")
    p.add_argument("--strict", action="store_true",
                   help="refuse implausible inertias (triangle inequality violated) and MJCF elements cstorm "
                        "does not model, instead of loading with a warning")


class _UsageError(Exception):
    pass


class _Parser(argparse.ArgumentParser):
    """argparse with usage errors raised (so ``main`` can answer them with exit code 2
    and, under ``--json``, one JSON object) instead of exiting."""

    def error(self, message):
        raise _UsageError(f"{self.prog}: {message}")


def main(argv=None):
    """Run the ``cstorm`` command with ``argv`` (default ``sys.argv[1:]``); returns the
    exit code. Called without ``argv`` (as the command), it also handles SIGINT,
    SIGTERM and SIGHUP (`cstorm.cli.runstate`) and ends the process itself after a
    signal, so that no background compile outlives it."""
    import warnings

    from ..errors import CstormError, DivergenceError
    from .runstate import Run

    as_command = argv is None
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = build_parser().parse_args(argv)
    except _UsageError as e:
        if "--json" in argv:
            print(json.dumps(dict(success=False, error="UsageError", message=str(e))))
        print(f"usage error: {e} (see cstorm --help)", file=sys.stderr)
        return 2
    except SystemExit as e:  # --help, --version
        return int(e.code or 0)
    args.argv = argv
    args.run = Run(args.cmd, quiet=getattr(args, "quiet", False))
    from .. import progress

    progress.enable(not args.run.quiet)
    old_show = warnings.showwarning
    warnings.showwarning = _show_warning
    args.run.install(watch=as_command)
    try:
        _setup_jax()
        rc = args.fn(args)
    except KeyboardInterrupt:  # stopped outside a solve (loading a model, checking gradients)
        name = args.run.stop_reason or "SIGINT"
        print(f"cstorm: stopped by {name}", file=sys.stderr, flush=True)
        rc = args.run.exit_code()
    except DivergenceError as e:
        _fail(args, e, 1)
        rc = 1
    except CstormError as e:
        _fail(args, e, 2)
        rc = 2
    except MemoryError:
        _fail(args, MemoryError("out of memory; a shorter t_final, a larger dt or fewer control points (n_ctrl) "
                                "need less"), 2)
        rc = 2
    except Exception as e:  # a bug: one line, and the traceback where CSTORM_DEBUG asks for it
        if os.environ.get("CSTORM_DEBUG"):
            raise
        _fail(args, e, 1, prefix="internal error (please report it; CSTORM_DEBUG=1 shows the traceback): "
                                 f"{type(e).__name__}: ")
        rc = 1
    finally:
        progress.enable(False)
        warnings.showwarning = old_show
        args.run.restore()
    busy = [t for t in threading.enumerate() if t.name == "cstorm-precompile" and t.is_alive()]
    if as_command and (args.run.signum is not None or busy):
        sys.stdout.flush(), sys.stderr.flush()
        os._exit(rc)  # a background compile thread must not run into interpreter shutdown
    return rc


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """Warnings as one line: ``cstorm: warning: <message>``."""
    print(f"cstorm: warning: {message}", file=sys.stderr if file is None else file)


def _fail(args, e, code, prefix=""):
    if getattr(args, "json", False):
        print(json.dumps(dict(success=False, error=type(e).__name__, message=prefix + str(e))))
    print(f"cstorm: error: {prefix}{e}", file=sys.stderr)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
