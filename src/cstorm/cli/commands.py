"""The ``cstorm`` command line.

Exit codes: 0 success, 1 a solve/simulation failed, 2 bad input. ``--json`` puts exactly
one JSON object on stdout (human messages go to stderr).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time


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

    out = args.out
    os.makedirs(out, exist_ok=True)
    problem, _ = resolve_problem(viz_demo.DEMO_PROBLEM)
    info = viz_demo.write_model_info(out, problem_segments(problem)[0].model)
    if not args.json:
        print(info + "\n", file=sys.stderr)
    solve_args = argparse.Namespace(
        problem=viz_demo.DEMO_PROBLEM, out=out, segment=None, method=None, max_iter=None, tol=None,
        checkpoint=False, resume=False, set=[], guess=args.guess, no_animation=args.no_animation,
        no_fidelity=args.no_fidelity, no_step_check=False, json=args.json, argv=args.argv)
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
    from ..report import problem_from_source

    if spec.lower().endswith(".toml") or (os.path.sep in spec and os.path.exists(spec)):
        if not os.path.exists(spec):
            raise InputError(f"problem file {spec!r} not found")
        with open(spec, "rb") as f:
            raw = f.read()
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as e:
            raise InputError(f"{spec}: not UTF-8 text: {e}") from None
        source = dict(kind="toml", path=os.path.abspath(spec), text=text)
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


def _check_time_steps(problem, log):
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
            print(f"cstorm solve: warning: {seg.name}: the initial guess: {r['message']}", file=sys.stderr)
        else:
            log(f"time step ({seg.name}): {r['message']}")
        out.append(r)
    return out


def _check_solution_steps(problem, sol, time_step):
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
            print(f"cstorm solve: warning: {seg.name}: the solution: {rs['message']}", file=sys.stderr)
        r["solution"] = rs


def cmd_solve(args):
    """Solve a shipped example or a TOML problem file; write summary.json, solution.npz,
    trajectory.csv, plots and an animation (see `cstorm.report.write_outputs`). Before
    solving, checks every segment's time step against its integrator's stability limit
    along its initial guess (`cstorm.check_time_step`; ``--no-step-check`` skips it),
    and after solving along the solution: a warning on stderr when past it, the results
    under ``time_step`` in summary.json."""
    import cstorm as cs
    from ..errors import InputError
    from ..optimize.sequence import MotionSequence
    from ..report import write_outputs

    problem, source = _with_warnings_on_stderr(args, lambda: resolve_problem(
        args.problem, _parse_set(args.set), args.segment, package_dirs=_package_dirs(args),
        strict=getattr(args, "strict", False)))
    label = problem.name if args.segment is None else f"{source.get('name', problem.name)}-{problem.name}"
    out = args.out or os.path.join("cstorm-out", label)
    os.makedirs(out, exist_ok=True)
    so = dict(getattr(problem, "solve_options", {}) or {})
    method = args.method or so.get("method", "slsqp")
    max_iter = args.max_iter if args.max_iter is not None else so.get("max_iter", 500)
    kw = {k: so[k] for k in ("tol", "constraint_tol", "options") if k in so}
    if args.tol is not None:
        kw["tol"] = args.tol
    if args.resume:
        if isinstance(problem, MotionSequence):
            raise InputError("--resume works for single problems; for a sequence use --segment NAME --resume")
        ck = os.path.join(out, "checkpoint.npz")
        if not os.path.exists(ck):
            raise InputError(f"--resume: no checkpoint at {ck} (write one with --checkpoint)")
        kw["resume"] = ck
    log = (lambda msg: None) if args.json else (lambda msg: print(msg, file=sys.stderr))
    log(f"cstorm solve {args.problem}" + (f" --segment {args.segment}" if args.segment else "") +
        f": {problem!r}; method {method}, max_iter {max_iter}; output {out}")
    time_step = None if getattr(args, "no_step_check", False) else _check_time_steps(problem, log)
    if args.guess:
        from ..report import solution_at

        sol = solution_at(problem, evaluate=False)
        log("--guess: not solving; writing the outputs of the initial guess (cost and violation not evaluated)")
    else:
        sol = cs.solve(problem, method=method, max_iter=max_iter, verbose=not args.json, out=sys.stderr,
                       checkpoint=os.path.join(out, "checkpoint.npz") if args.checkpoint else None, **kw)
        log(f"solved in {sol.wall_time_s:.1f} s (compile {sol.compile_time_s:.1f} s): {sol.message}")
    if time_step is not None and not args.guess:
        _check_solution_steps(problem, sol, time_step)
    summary = write_outputs(problem, sol, out, source=source, check_fidelity=not args.no_fidelity,
                            animation=not args.no_animation,
                            extra_provenance=dict(command=["cstorm"] + list(args.argv or [])), log=log,
                            time_step=time_step)
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
    return 0 if summary["success"] else 1


def cmd_animate(args):
    """Re-render plots and the animation from a saved solution (a directory holding
    solution.npz, or the .npz itself), rebuilding the problem from the solution's
    recorded source (a shipped example with its arguments, or the stored TOML text)."""
    import numpy as np

    import cstorm as cs
    from ..errors import InputError
    from ..report import problem_from_source, problem_segments, render, segment_solutions, write_csv
    from ..viz.motion import Motion

    path = args.solution
    npz = os.path.join(path, "solution.npz") if os.path.isdir(path) else path
    if not os.path.exists(npz):
        raise InputError(f"animate: no solution at {npz!r} (give a directory written by `cstorm solve` or its "
                         "solution.npz)")
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
    out = args.out or (path if os.path.isdir(path) else os.path.dirname(os.path.abspath(path)))
    os.makedirs(out, exist_ok=True)
    motion = Motion.from_solution(problem, sol)
    files = render(motion, out, animation=not args.no_animation)
    if args.csv:
        write_csv(os.path.join(out, "trajectory.csv"), motion)
        files.append("trajectory.csv")
    res = dict(success=True, problem=motion.name, out=os.path.abspath(out), files=sorted(files))
    if args.json:
        print(json.dumps(res))
    else:
        print(f"{motion.name}: wrote {', '.join(res['files'])} to {out}", file=sys.stderr)
    return 0


def cmd_check_gradients(args):
    import cstorm as cs

    res = cs.check_gradients(cs.examples.get(args.problem)())
    if args.json:
        print(json.dumps({k: v for k, v in res.items() if isinstance(v, (int, float, str, bool))}))
    else:
        print(f"{args.problem}: max relative error of exact vs central-difference gradients: "
              f"{res['max_rel_error']:.3e}", file=sys.stderr)
    return 0


def build_parser():
    p = _Parser(prog="cstorm", description="Optimal motions for robots that make and break contact.")
    sub = p.add_subparsers(dest="cmd", required=True)
    pi = sub.add_parser("info", help="describe a robot model (shipped robot or problem name, URDF, MJCF or TOML "
                                     "problem file)")
    pi.add_argument("model", help="a shipped robot (tumbler, double_pendulum), a shipped problem's name (its "
                                  "robot), or a .urdf / .xml / .toml path")
    pi.add_argument("--floating-base", choices=["free", "planar"], default=None)
    _robot_options(pi)
    pi.add_argument("--json", action="store_true")
    pi.set_defaults(fn=cmd_info)
    pd = sub.add_parser("demo", help="solve the demo motion (the tumbling robot's four segments) and write its "
                                     "files",
                        description="The main demo: write the tumbling robot's model description "
                                    "(tumbler_info.txt), solve start -> handstand -> roll -> standing -> start (as "
                                    "`cstorm solve tumbler`, 10-12 min on 2 cores) and write summary.json, "
                                    "solution.npz, trajectory.csv, PNG plots and animation.gif to --out. "
                                    "`cstorm solve luxo` is a shorter alternative (2-4 min).")
    pd.add_argument("--out", default=os.path.join("cstorm-out", "demo"), help="output directory "
                                                                               "(default ./cstorm-out/demo)")
    pd.add_argument("--guess", action="store_true", help="do not solve: write the outputs of the initial guess "
                                                          "(exit code 1, as for cstorm solve --guess)")
    pd.add_argument("--no-animation", action="store_true", help="skip the animation")
    pd.add_argument("--no-fidelity", action="store_true", help="skip the re-simulation fidelity check")
    pd.add_argument("--json", action="store_true", help="print exactly one JSON object (the summary) on stdout")
    pd.set_defaults(fn=cmd_demo)
    ps = sub.add_parser("solve", help="solve a shipped motion problem or a TOML problem file; write results",
                        description="Solve PROBLEM (a shipped example name or a .toml problem file) and write "
                                    "summary.json, solution.npz, trajectory.csv, PNG plots and animation.gif to "
                                    "--out (default ./cstorm-out/<problem>). Exit 0: solved and every success "
                                    "criterion met; 1: the solve failed; 2: bad input.")
    ps.add_argument("problem", help="shipped example name (e.g. acrobot) or path to a .toml problem file")
    ps.add_argument("--out", default=None, help="output directory (default ./cstorm-out/<problem>)")
    ps.add_argument("--segment", default=None, metavar="NAME",
                    help="solve only this segment of a sequence (name or 0-based index), from the segment's own "
                         "nominal start state (its q0, v0)")
    ps.add_argument("--method", choices=["slsqp", "trust-constr", "ipopt", "ddp"], default=None,
                    help="solver: the paper's SQP (slsqp, trust-constr, ipopt) on B-spline paths, or constrained DDP on per-step motor torques (ddp) (default: the problem's choice, else slsqp)")
    ps.add_argument("--max-iter", type=int, default=None, help="iteration limit per stage (default: the problem's, "
                                                               "else 500)")
    ps.add_argument("--tol", type=float, default=None, help="optimality tolerance")
    ps.add_argument("--checkpoint", action="store_true", help="write OUT/checkpoint.npz every iteration")
    ps.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.npz (single problems)")
    ps.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a shipped example's factory keyword argument (e.g. --set dt=0.02), or for a problem "
                         "file a dotted key of the file (e.g. --set motion.dt=0.01); VALUE is read as JSON")
    ps.add_argument("--guess", action="store_true",
                    help="do not solve: write the outputs (plots, animation) of the initial guess; its cost and "
                         "constraint violation are not evaluated (exit code 1)")
    ps.add_argument("--no-animation", action="store_true", help="skip the animation")
    ps.add_argument("--no-fidelity", action="store_true", help="skip the re-simulation fidelity check")
    ps.add_argument("--no-step-check", action="store_true",
                    help="skip the check of dt against the integrator's stability limit (cstorm.check_time_step), "
                         "run along the initial guess before solving and along the solution after")
    ps.add_argument("--json", action="store_true", help="print exactly one JSON object (the summary) on stdout")
    _robot_options(ps)
    ps.set_defaults(fn=cmd_solve)
    pa = sub.add_parser("animate", help="re-render plots and the animation of a saved solution")
    pa.add_argument("solution", help="a directory written by `cstorm solve`, or its solution.npz")
    pa.add_argument("--out", default=None, help="output directory (default: the solution's)")
    pa.add_argument("--no-animation", action="store_true", help="plots only")
    pa.add_argument("--csv", action="store_true", help="also rewrite trajectory.csv")
    pa.add_argument("--json", action="store_true")
    pa.set_defaults(fn=cmd_animate)
    pg = sub.add_parser("check-gradients", help="exact vs finite-difference gradients of a shipped problem")
    pg.add_argument("problem")
    pg.add_argument("--json", action="store_true")
    pg.set_defaults(fn=cmd_check_gradients)
    return p


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
    from ..errors import CstormError, DivergenceError

    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = build_parser().parse_args(argv)
    except _UsageError as e:
        if "--json" in argv:
            print(json.dumps(dict(success=False, error="UsageError", message=str(e))))
        print(f"usage error: {e} (see cstorm --help)", file=sys.stderr)
        return 2
    args.argv = argv
    _setup_jax()
    try:
        return args.fn(args)
    except DivergenceError as e:
        _fail(args, e, 1)
        return 1
    except CstormError as e:
        _fail(args, e, 2)
        return 2


def _fail(args, e, code):
    if getattr(args, "json", False):
        print(json.dumps(dict(success=False, error=type(e).__name__, message=str(e))))
    print(f"cstorm: error: {e}", file=sys.stderr)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
