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
    import jax

    jax.config.update("jax_enable_x64", True)
    cache = os.environ.get("CSTORM_JAX_CACHE", os.path.join(os.path.expanduser("~"), ".cache", "cstorm", "jax"))
    try:
        jax.config.update("jax_compilation_cache_dir", cache)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
    except Exception:  # pragma: no cover - cache is an optimization only
        pass


def load_model(spec: str, floating_base=None):
    """A model from a shipped robot name, a URDF path or an MJCF path."""
    import cstorm as cs

    if spec in cs.robots.REGISTRY:
        return cs.robots.get(spec)
    if not os.path.exists(spec):
        raise cs.ModelError(f"{spec!r} is neither a shipped robot ({', '.join(cs.robots.names())}) nor a file")
    if spec.lower().endswith(".urdf"):
        return cs.load_urdf(spec, floating_base=floating_base)
    if spec.lower().endswith(".xml") or spec.lower().endswith(".mjcf"):
        return cs.load_mjcf(spec)
    raise cs.ModelError(f"{spec}: unknown model file type (expected .urdf or .xml)")


def cmd_info(args):
    from .model.info import describe

    model = load_model(args.model, floating_base=args.floating_base)
    if args.json:
        print(json.dumps(_model_json(model)))
    else:
        print(describe(model))
    return 0


def _model_json(model):
    import numpy as np

    return dict(
        name=model.name, nq=model.nq, nv=model.nv, n_bodies=model.n_bodies,
        bodies=[dict(name=n, parent=(model.body_names[p] if p >= 0 else None), joint=j, joint_type=jt.name,
                     mass=float(m)) for n, p, j, jt, m in zip(model.body_names, model.parents, model.joint_names,
                                                              model.joints, np.asarray(model.mass))],
        geoms=list(model.geom_names), total_mass=float(np.sum(np.asarray(model.mass))),
    )


def cmd_demo(args):
    """Foundation demo: describe the tumbler, then simulate a double pendulum released
    from horizontal with RK4 + ABA, and write a plot, a strobe picture and a CSV."""
    import numpy as np

    from .viz import demo as viz_demo

    out = args.out
    os.makedirs(out, exist_ok=True)
    from .model.info import describe
    import cstorm as cs

    info = describe(cs.robots.tumbler())
    with open(os.path.join(out, "tumbler_info.txt"), "w") as f:
        f.write(info + "\n")
    if not args.json:
        print(info, file=sys.stderr)
    summary = viz_demo.pendulum_demo(out, t_final=args.t_final)
    summary["files"] = sorted(os.listdir(out))
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"\ndouble pendulum, {summary['steps']} RK4 steps of {summary['dt']} s: relative energy drift "
              f"{summary['energy_drift_rel']:.2e}; compile {summary['compile_time_s']:.1f} s, run "
              f"{summary['run_time_s']:.3f} s", file=sys.stderr)
        print(f"wrote {', '.join(summary['files'])} to {out}", file=sys.stderr)
    return 0


def cmd_solve(args):
    """Solve a shipped example problem; write summary.json, solution.npz and a CSV."""
    import numpy as np

    import cstorm as cs

    problem = cs.examples.get(args.problem)()
    out = args.out or os.path.join("cstorm-out", args.problem)
    os.makedirs(out, exist_ok=True)
    sol = cs.solve(problem, method=args.method, max_iter=args.max_iter, verbose=not args.json,
                   out=sys.stderr, checkpoint=os.path.join(out, "checkpoint.npz") if args.checkpoint else None)
    sol.save(os.path.join(out, "solution.npz"))
    summary = sol.summary()
    summary["provenance"] = dict(cstorm=cs.__version__, problem=args.problem, method=args.method,
                                 max_iter=args.max_iter)
    _write_json(os.path.join(out, "summary.json"), summary)
    tr = sol.trajectory
    if tr is not None and "t" in tr:
        cols = [np.asarray(tr["t"])[:, None], np.asarray(tr["q"]), np.asarray(tr["v"])]
        model = problem.model
        header = ["t"] + [f"q_{n}" if model.joints[i].nq == 1 else f"q_{n}_{k}" for i, n in enumerate(model.joint_names)
                          for k in range(model.joints[i].nq)]
        header += [f"v_{n}" if model.joints[i].nv == 1 else f"v_{n}_{k}" for i, n in enumerate(model.joint_names)
                   for k in range(model.joints[i].nv)]
        tmp = os.path.join(out, ".trajectory.csv.tmp")
        np.savetxt(tmp, np.concatenate(cols, axis=1), delimiter=",", header=",".join(header), comments="")
        os.replace(tmp, os.path.join(out, "trajectory.csv"))
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"{args.problem}: {'success' if sol.success else 'FAILED'}: {sol.message}; cost {sol.cost:.6g}, "
              f"violation {sol.constraint_violation:.2e}, {sol.iterations} iterations; wrote {out}", file=sys.stderr)
    return 0 if sol.success else 1


def cmd_check_gradients(args):
    import cstorm as cs

    res = cs.check_gradients(cs.examples.get(args.problem)())
    if args.json:
        print(json.dumps({k: v for k, v in res.items() if isinstance(v, (int, float, str, bool))}))
    else:
        print(f"{args.problem}: max relative error of exact vs central-difference gradients: "
              f"{res['max_rel_error']:.3e}", file=sys.stderr)
    return 0


def _write_json(path, obj):
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(obj, f, indent=2, default=float)
    os.replace(tmp, path)


def build_parser():
    p = argparse.ArgumentParser(prog="cstorm", description="Optimal motions for robots that make and break contact.")
    sub = p.add_subparsers(dest="cmd", required=True)
    pi = sub.add_parser("info", help="describe a robot model (shipped name, URDF or MJCF path)")
    pi.add_argument("model")
    pi.add_argument("--floating-base", choices=["free", "planar"], default=None)
    pi.add_argument("--json", action="store_true")
    pi.set_defaults(fn=cmd_info)
    pd = sub.add_parser("demo", help="run the demo motion and write pictures")
    pd.add_argument("--out", default=os.path.join("cstorm-out", "demo"))
    pd.add_argument("--t-final", type=float, default=3.0)
    pd.add_argument("--json", action="store_true")
    pd.set_defaults(fn=cmd_demo)
    ps = sub.add_parser("solve", help="solve a shipped motion problem (e.g. acrobot)")
    ps.add_argument("problem")
    ps.add_argument("--out", default=None)
    ps.add_argument("--method", choices=["slsqp", "ipopt"], default="slsqp")
    ps.add_argument("--max-iter", type=int, default=500)
    ps.add_argument("--checkpoint", action="store_true", help="write DIR/checkpoint.npz every iteration")
    ps.add_argument("--json", action="store_true")
    ps.set_defaults(fn=cmd_solve)
    pg = sub.add_parser("check-gradients", help="exact vs finite-difference gradients of a shipped problem")
    pg.add_argument("problem")
    pg.add_argument("--json", action="store_true")
    pg.set_defaults(fn=cmd_check_gradients)
    return p


def main(argv=None):
    from .errors import CstormError, DivergenceError

    args = build_parser().parse_args(argv)
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
