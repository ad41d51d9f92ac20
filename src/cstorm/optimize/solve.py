"""The solver front end: `solve(problem_or_sequence, method="slsqp" | "ipopt", ...)`.

Exact JAX gradients and constraint Jacobians (one compiled function per problem that
returns values and derivatives together; continuation and staging change only its
dynamic inputs). SLSQP is scipy's (the draft's BFGS SQP); IPOPT goes through casadi
(optional extra ``cstorm[ipopt]``) with a limited-memory Hessian and the same exact
first derivatives.

Stages. A solve runs a plan of stages, each warm-started from the previous one:
``continuation={"name": [v1, v2, ...]}`` ramps problem parameters (all lists the same
length); then staged constraints (terms with ``stage=1, 2, ...``) are switched on one
level at a time at the final parameter values. During the continuation stages the
constraints of level 0 are enforced. ``schedule=[{"params": {...}, "level": k}, ...]``
gives the plan explicitly. With neither, one stage with every constraint.

Robustness. A trial point whose rollout diverges is returned to the solver as a very
bad point (a huge objective and finite constraint values), so the line search backs
off; if a stage still ends at such a point, the solve returns the last stage end whose
rollout did not diverge, with ``success=False`` and the divergence (time, joint,
reason) in ``message``. Ctrl-C (KeyboardInterrupt, also raised from ``callback``)
stops the solve and returns the best iterate so far (feasible with the lowest cost,
else the least infeasible) with ``success=False``. ``checkpoint=path`` writes the current iterate and
stage atomically after every iteration; ``resume=path`` continues from such a file.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time

import numpy as np
import jax
import jax.numpy as jnp

from ..version import __version__
from ..errors import DivergenceError, InputError, ProblemError
from ..mapguard import relieve_map_pressure
from ..simulate import check_divergence
from .ddp_problem import solve_ddp
from .ipopt import run_ipopt
from .problem import MotionProblem, require_x64
from .bounds import clip_into, stage_bounds, variable_bounds
from .sequence import MotionSequence
from .solution import Solution, Status, atomic_savez, contact_dict

__all__ = ["solve", "check_solve_arguments", "resolve_objective_scale", "run_slsqp"]

_BIG = 1e12


class _Interrupted(Exception):
    pass


class _Evaluator:
    """Caches the compiled values+derivatives of one problem at the last x."""

    def __init__(self, problem: MotionProblem, data, mask_eq, mask_in):
        self.p, self.data = problem, data
        self.me, self.mi = mask_eq, mask_in
        self.fscale = 1.0  # the solver sees fscale * f (reported costs are unscaled)
        self.bounds = None  # (lb, ub) of the current stage (None: `variable_bounds`)
        self.fn = problem.compiled("fun_jac")
        self.x = None
        self.nev = 0
        self.f_good = None

    def at(self, x):
        x = np.asarray(x, dtype=float)
        if self.x is None or not np.array_equal(x, self.x):
            f, ce, ci, div, g, Je, Ji = (np.asarray(a) for a in self.fn(jnp.asarray(x), self.data))
            self.nev += 1
            self.x = x.copy()
            ce, ci = ce[self.me], ci[self.mi]
            Je, Ji = Je[self.me], Ji[self.mi]
            bad = bool(div) or not (np.isfinite(f) and np.all(np.isfinite(ce)) and np.all(np.isfinite(ci)))
            if bad:
                ref = abs(self.f_good) if self.f_good is not None else 1.0
                f = _BIG * (1.0 + ref)
                ce = np.where(np.isfinite(ce), ce, _BIG)
                ci = np.where(np.isfinite(ci), ci, -_BIG)
                g = np.nan_to_num(g, nan=0.0, posinf=0.0, neginf=0.0)
                Je = np.nan_to_num(Je, nan=0.0, posinf=0.0, neginf=0.0)
                Ji = np.nan_to_num(Ji, nan=0.0, posinf=0.0, neginf=0.0)
            else:
                self.f_good = float(f)
            self.vals = (float(f), ce, ci, bad, g, Je, Ji)
        return self.vals

    def violation(self, x):
        f, ce, ci, bad, *_ = self.at(x)
        v = 0.0
        if ce.size:
            v = max(v, float(np.max(np.abs(ce))))
        if ci.size:
            v = max(v, float(np.max(np.maximum(0.0, -ci))))
        return math.inf if bad else v


class _Tracker:
    """Per-iteration bookkeeping: history, best iterate, display, checkpoint, user
    callback."""

    def __init__(self, problem, verbose, callback, checkpoint, t0, tol, iteration0=0, out=None):
        self.p, self.verbose, self.callback, self.checkpoint = problem, verbose, callback, checkpoint
        self.t0, self.tol = t0, tol
        self.history = []
        self.iteration = iteration0
        self.best = None  # (x, cost, violation, stage)
        self.prev_x = None
        self.out = out or sys.stdout

    def header(self):
        if self.verbose:
            print(f"{'iter':>5} {'stage':>5} {'cost':>14} {'violation':>10} {'step':>10} {'time/s':>8}", file=self.out)

    def consider(self, x, cost, viol, stage):
        x = np.array(x, dtype=float)
        if not np.isfinite(cost):
            return
        b = self.best
        better = (b is None or (viol <= self.tol and (b[2] > self.tol or cost < b[1]))
                  or (viol > self.tol and b[2] > self.tol and viol < b[2]))
        if better:
            self.best = (x, cost, viol, stage)

    def record(self, x, ev, stage, stage_params):
        f, *_ = ev.at(x)
        viol = ev.violation(x)
        self.iteration += 1
        step = float(np.max(np.abs(x - self.prev_x))) if self.prev_x is not None else 0.0
        self.prev_x = np.array(x, dtype=float)
        el = time.perf_counter() - self.t0
        self.history.append(dict(iteration=self.iteration, stage=stage, cost=float(f), violation=float(viol),
                                 step=step, time=el))
        self.consider(x, f, viol, stage)
        if self.verbose:
            print(f"{self.iteration:5d} {stage:5d} {f:14.6e} {viol:10.2e} {step:10.2e} {el:8.2f}", file=self.out)
            self.out.flush()
        if self.checkpoint:
            atomic_savez(self.checkpoint, dict(
                x=np.asarray(x, float), stage=np.array(stage), iteration=np.array(self.iteration),
                problem_hash=np.array(self.p.hash()), params_json=np.array(json.dumps(
                    {k: np.asarray(v).tolist() for k, v in stage_params.items()}))))
        if self.callback is not None:
            self.callback(dict(iteration=self.iteration, stage=stage, x=np.array(x), cost=float(f),
                               violation=float(viol), step=step, time=el))


def _plan(problem, continuation, schedule):
    levels = problem.n_levels
    if schedule is not None:
        plan = []
        for i, s in enumerate(schedule):
            bad = set(s) - {"params", "level", "trust_region", "tol", "max_iter"}
            if bad:
                raise InputError(f"solve: schedule stage {i} has unknown keys {sorted(bad)} (known: params, level, "
                                 "trust_region, tol, max_iter)")
            plan.append((dict(s.get("params", {})), s.get("level", levels - 1)))
        return plan
    if continuation:
        lens = {len(v) for v in continuation.values()}
        if len(lens) != 1:
            raise InputError(f"solve: continuation lists must all have the same length, got {continuation}")
        K = lens.pop()
        for k in continuation:
            if k not in problem.params:
                raise InputError(f"solve: continuation parameter {k!r} is not a problem parameter "
                                 f"({sorted(problem.params)})")
        plan = [({k: v[i] for k, v in continuation.items()}, 0 if levels > 1 else levels - 1) for i in range(K)]
        final = plan[-1][0]
        plan += [(dict(final), lev) for lev in range(1, levels)]
        return plan
    if levels > 1:
        return [({}, lev) for lev in range(levels)]
    return [({}, 0)]


METHODS = ("slsqp", "trust-constr", "ipopt", "ddp")


def check_solve_arguments(method="slsqp", max_iter=500, tol=1e-8, constraint_tol=1e-6, options=None):
    """Raise `InputError` naming the argument when ``method``, ``max_iter`` (an integer
    >= 1), ``tol`` or ``constraint_tol`` (finite, > 0) or ``options`` (keys the chosen
    solver knows; for IPOPT any key, which IPOPT checks itself) is unusable, or when
    ``method="ipopt"`` and casadi is not installed. Cheap: `solve` and ``cstorm solve``
    call it before anything is compiled."""
    import importlib.util

    m = str(method).lower()
    if m not in METHODS:
        raise InputError(f"solve: method must be one of {list(METHODS)}, got {method!r}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise InputError(f"solve: max_iter must be an integer >= 1, got {max_iter!r}")
    for name, v in (("tol", tol), ("constraint_tol", constraint_tol)):
        try:
            ok = math.isfinite(float(v)) and float(v) > 0
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise InputError(f"solve: {name} must be a finite number > 0, got {v!r}")
    if m == "ipopt" and importlib.util.find_spec("casadi") is None:
        raise InputError("solve: method 'ipopt' needs casadi, which is not installed: pip install 'cstorm[ipopt]' "
                         "(or pip install casadi), or choose another method")
    if options is None:
        return
    if not isinstance(options, dict):
        raise InputError(f"solve: options must be a dict of solver options, got {type(options).__name__}")
    known = _solver_option_names(m)
    if known is not None:
        bad = sorted(set(map(str, options)) - known)
        if bad:
            raise InputError(f"solve: unknown {m} option(s) {bad}; known: {sorted(known)}")


def _solver_option_names(method):
    """The ``options`` keys a method accepts (None: not checked here)."""
    import dataclasses
    import inspect

    if method == "ddp":
        from .ddp import DDPOptions

        return {f.name for f in dataclasses.fields(DDPOptions)} - {"max_iter", "tol", "constraint_tol", "verbose"}
    try:
        if method == "slsqp":
            from scipy.optimize._slsqp_py import _minimize_slsqp as fn
            fixed = {"func", "x0", "args", "jac", "bounds", "constraints", "callback", "unknown_options"}
        elif method == "trust-constr":
            from scipy.optimize._trustregion_constr.minimize_trustregion_constr import \
                _minimize_trustregion_constr as fn
            fixed = {"fun", "x0", "args", "grad", "hess", "hessp", "bounds", "constraints", "callback"}
        else:
            return None
    except ImportError:  # pragma: no cover - scipy moved its private modules: scipy checks them itself
        return None
    return set(inspect.signature(fn).parameters) - fixed


def solve(problem, method: str = "slsqp", *, x0=None, continuation=None, schedule=None, max_iter: int = 500,
          tol: float = 1e-8, constraint_tol: float = 1e-6, verbose: bool = False, callback=None,
          checkpoint=None, resume=None, options=None, out=None, objective_scale="auto") -> Solution:
    """Solve a `MotionProblem` or `MotionSequence`.

    Args:
      problem: a `MotionProblem` or a `MotionSequence`.
      method: ``"slsqp"`` (scipy, default), ``"trust-constr"`` (scipy's trust-region SQP /
        interior point with BFGS Hessians: its radius adapts to how well each step's
        model predicted the change, for problems whose constraints are far from linear
        over SLSQP's steps) or ``"ipopt"`` (needs casadi: ``pip install cstorm[ipopt]``).
      x0: initial decision vector (default ``problem.x0``).
      continuation: ``{param: [values...]}``, a ramp of problem parameters, one stage per
        value (defaults to ``problem.solve_options["continuation"]`` if set). Every
        stage but the last only warm-starts the next: ``problem.solve_options`` may set
        ``"intermediate_tol"`` and ``"intermediate_max_iter"`` to loosen them (default:
        ``tol`` and ``max_iter``).
      schedule: explicit plan ``[{"params": {...}, "level": k}, ...]``; a stage may also
        set ``"trust_region"`` (its own box radius, see ``solve_options["trust_region"]``),
        ``"tol"`` and ``"max_iter"`` (its own optimality tolerance and iteration limit,
        instead of ``tol``/``max_iter`` or the intermediate ones).
        Refinement of failed stages: with ``problem.solve_options["refine"] = n`` (default
        0: off), a stage of a continuation or schedule that fails (the solver stops
        unsuccessfully with a violation above ``solve_options["refine_violation"]``,
        default 1e-2, or its end diverges) is run again from where it started, after a
        stage at the parameters halfway from the previous stage's (geometric mean where
        both are positive, else arithmetic; same level and stage options as the failed
        one), up to ``n`` halvings deep. ``Solution.info["stages"]`` lists the failed
        attempts too (``"refined": True``; the inserted stages carry
        ``"refinement_depth"``) under their plan's stage number. A stage whose
        parameters equal the previous stage's (only its constraint level changes) is not
        refined.
      max_iter: iteration limit per stage. tol: optimality tolerance (SLSQP ``ftol``,
        IPOPT ``tol``). constraint_tol: largest constraint violation counted as success.
      verbose: print one line per iteration (iteration, stage, cost, violation, step,
        time).
      callback: ``callback(info)`` after each iteration, ``info`` a dict with
        ``iteration, stage, x, cost, violation, step, time``; raising
        KeyboardInterrupt stops the solve (the best iterate is returned), raising
        StopIteration ends the current stage.
      checkpoint: path of an ``.npz`` written atomically after every iteration (a
        sequence writes one per segment, ``path.seg<k>.npz``, and each solved segment's
        solution to ``path.seg<k>.done.npz``).
      resume: path of such a checkpoint to continue from (stage and iterate; for a
        sequence the same ``path`` as ``checkpoint``: solved segments are taken from
        their ``.done.npz``, the next continues from its iterate).
      options: extra solver options (scipy ``options`` / IPOPT options).
      out: stream for the progress display (default stdout).
      objective_scale: ``"auto"`` (default; ``s / |grad f|_inf`` at each stage's start,
        ``s = problem.solve_options.get("first_step", 1.0)``),
        None (1) or a positive factor applied to the objective the solver sees (SLSQP's
        first step uses an identity Hessian, so an unscaled cost with large gradients
        throws it far away). Reported costs are unscaled.
    Returns:
      `Solution`. For a sequence, its ``segments`` hold one `Solution` per segment and
      its trajectory is their concatenation.
    """
    require_x64("solve")
    check_solve_arguments(method, max_iter, tol, constraint_tol, options)
    if isinstance(problem, MotionSequence):
        return problem.solve_segments(_solve_problem, method=method, continuation=continuation, schedule=schedule, max_iter=max_iter,
                              tol=tol, constraint_tol=constraint_tol, verbose=verbose, callback=callback,
                              checkpoint=checkpoint, options=options, out=out, objective_scale=objective_scale,
                              resume=resume)
    if not isinstance(problem, MotionProblem):
        raise InputError(f"solve: expected a MotionProblem or MotionSequence, got {type(problem).__name__}")
    return _solve_problem(problem, method=method, x0=x0, continuation=continuation, schedule=schedule,
                          max_iter=max_iter, tol=tol, constraint_tol=constraint_tol, verbose=verbose,
                          callback=callback, checkpoint=checkpoint, resume=resume, options=options, out=out,
                          objective_scale=objective_scale)


def _solve_problem(problem, *, method="slsqp", x0=None, continuation=None, schedule=None, max_iter=500, tol=1e-8,
                   constraint_tol=1e-6, verbose=False, callback=None, checkpoint=None, resume=None, options=None,
                   out=None, q0=None, v0=None, objective_scale="auto"):
    relieve_map_pressure(where="solve")
    method = method.lower()
    if method not in METHODS:
        raise InputError(f"solve: method must be one of {list(METHODS)}, got {method!r}")
    if method == "ddp":
        return solve_ddp(problem, q0=q0, v0=v0, max_iter=max_iter, tol=tol,
                         constraint_tol=constraint_tol, verbose=verbose, callback=callback, out=out,
                         options=options)
    if continuation is None and schedule is None:
        continuation = problem.solve_options.get("continuation")
        schedule = problem.solve_options.get("schedule")
    plan = _plan(problem, continuation, schedule)
    x = np.asarray(problem.x0 if x0 is None else x0, dtype=float).reshape(-1)
    if x.shape != (problem.n_vars,):
        raise InputError(f"solve: x0 must have shape ({problem.n_vars},), got {x.shape}")
    start_stage, it0 = 0, 0
    if resume is not None:
        try:
            with np.load(resume, allow_pickle=False) as z:
                rx, rstage, rit, rhash = z["x"], int(z["stage"]), int(z["iteration"]), str(z["problem_hash"])
        except (OSError, KeyError, ValueError) as e:
            raise InputError(f"solve: cannot resume from {resume!r}: {e}") from None
        if rhash != problem.hash() or rx.shape != x.shape:
            raise InputError(f"solve: checkpoint {resume!r} belongs to another problem (hash {rhash}, "
                             f"this problem {problem.hash()})")
        x, start_stage, it0 = rx.astype(float), min(rstage, len(plan) - 1), rit

    t0 = time.perf_counter()
    # compile once (timed separately): values + derivatives, then the trajectory
    data0 = problem.data(params=plan[start_stage][0], q0=q0, v0=v0)
    if x0 is None and resume is None and problem.shooting > 1:
        x = problem.shoot_nodes(x, data0)  # the default guess's nodes: its own rollout
    tc = time.perf_counter()
    stream = out or sys.stdout
    if verbose:
        print(f"{problem.name}: compiling the objective, the constraints and their derivatives ...", file=stream,
              flush=True)
    fj = problem.compiled("fun_jac")
    fj(jnp.asarray(x), data0)[0].block_until_ready()
    compile_s = time.perf_counter() - tc
    if verbose:
        print(f"{problem.name}: compiled in {compile_s:.1f} s", file=stream, flush=True)

    tracker = _Tracker(problem, verbose, callback, checkpoint, t0, constraint_tol, iteration0=it0, out=out)
    tracker.header()
    stages_info = []
    message, solver_ok, interrupted = "", False, False
    params_now = dict(problem.params)
    ev = None
    last_sound = None  # (x, stage) of the last stage end whose rollout did not diverge
    nev_done = 0  # evaluations of the finished stages' evaluators
    # the stages still to run: (plan index, params, level, the schedule entry's own
    # options, refinement depth); a failed stage may insert midpoint stages before it
    refine = int(problem.solve_options.get("refine", 0))
    refine_violation = float(problem.solve_options.get("refine_violation", 1e-2))
    queue = [dict(index=i, params=plan[i][0], level=plan[i][1],
                  extra=dict(schedule[i]) if schedule is not None else {}, depth=0)
             for i in range(start_stage, len(plan))]
    prev_params = _stage_params(problem, plan[start_stage - 1][0]) if start_stage > 0 else None
    k = 0
    while k < len(queue):
        st = queue[k]
        si, sparams, level = st["index"], st["params"], st["level"]
        nev_done += ev.nev if ev is not None else 0
        params_now = _stage_params(problem, sparams)
        data = problem.data(params=sparams, q0=q0, v0=v0)
        me, mi = problem.constraint_masks(level)
        ev = _Evaluator(problem, data, me, mi)
        x_start = np.array(x, float)
        f_init, *_rest = ev.at(x)
        if _rest[2] and k == 0:  # initial guess diverges
            traj = problem.compiled("trajectory")(jnp.asarray(x), data)
            check_divergence(problem.model, traj, problem.dt, f"{problem.name}: the initial guess's rollout")
        ev.fscale = resolve_objective_scale(objective_scale, ev, x, problem.solve_options.get("first_step", 1.0))
        ev.bounds = stage_bounds(problem, x, st["extra"].get("trust_region"))
        tracker.best = None  # best iterate of the current stage (earlier stages solve other problems)
        try:
            # intermediate stages only warm-start the next one: the problem may loosen them
            last = k == len(queue) - 1
            s_tol = tol if last else problem.solve_options.get("intermediate_tol", tol)
            s_it = max_iter if last else min(max_iter, problem.solve_options.get("intermediate_max_iter", max_iter))
            s_tol = float(st["extra"].get("tol", s_tol))  # a stage's own tolerance / iteration limit
            s_it = int(st["extra"].get("max_iter", s_it))
            if method == "slsqp":
                x, solver_ok, message, nit = run_slsqp(ev, x, tracker, si, params_now, s_it, s_tol, options)
            elif method == "trust-constr":
                x, solver_ok, message, nit = _run_trust_constr(ev, x, tracker, si, params_now, s_it, s_tol, options)
            else:
                x, solver_ok, message, nit = _run_ipopt(ev, x, tracker, si, params_now, s_it, s_tol, options)
        except KeyboardInterrupt:
            interrupted = True
            message = f"interrupted by the user in stage {si} (KeyboardInterrupt); returning the best iterate so far"
            if tracker.best is not None:
                x = tracker.best[0]
            else:
                x = ev.x if ev.x is not None else x
            stages_info.append(dict(stage=si, params=_jsonable(sparams), level=level, message=message,
                                    iterations=None))
            break
        end = ev.at(x)
        viol_end = ev.violation(x)
        info_row = dict(stage=si, params=_jsonable(sparams), level=level, message=message, iterations=nit,
                        cost=end[0], violation=viol_end)
        if st["depth"]:
            info_row["refinement_depth"] = st["depth"]
        failed = (not solver_ok and viol_end > refine_violation) or bool(end[3])
        mid = _midpoint(prev_params, params_now) if failed and st["depth"] < refine else None
        if mid is not None:
            # back to where this stage started, and approach its parameters in two steps
            info_row["refined"] = True
            stages_info.append(info_row)
            if verbose:
                print(f"stage {si} ({_jsonable(sparams)}, constraint level {level}): {message} (violation "
                      f"{viol_end:.3g}); refining: from this stage's start through {_jsonable(mid)}",
                      file=tracker.out)
            x = x_start
            queue[k:k + 1] = [dict(st, params=mid, depth=st["depth"] + 1), dict(st, depth=st["depth"] + 1)]
            continue
        stages_info.append(info_row)
        if not end[3]:
            last_sound = (np.array(x, float), si)
        if verbose and len(plan) > 1:
            print(f"stage {si} ({_jsonable(sparams)}, constraint level {level}): {message}", file=tracker.out)
        prev_params = params_now
        k += 1

    # final evaluation at x with all constraints of the last stage's level
    if not interrupted and tracker.best is not None and ev is not None:
        # prefer the solver's final point; fall back to the best iterate if the final
        # point is worse (e.g. a failed line search left an infeasible point)
        fx, vx = ev.at(x)[0], ev.violation(x)
        bx, bf, bv, _ = tracker.best
        if vx > constraint_tol and bv <= constraint_tol:
            x = bx
    f, *_ = ev.at(x)
    viol = ev.violation(x)
    data_final = ev.data
    traj = problem.compiled("trajectory")(jnp.asarray(x), data_final)
    traj = jax.tree_util.tree_map(np.asarray, traj)
    fell_back = None
    if bool(traj["diverged"]):
        try:
            check_divergence(problem.model, traj, problem.dt, f"{problem.name}: the final motion's rollout")
        except DivergenceError as e:
            if not interrupted and last_sound is None:
                raise
            if not interrupted:
                # a stage wandered off to where the rollout diverges: keep the user's
                # work, the last stage end whose rollout did not diverge, and say so
                fell_back = str(e)
                x = last_sound[0]
                f, *_ = ev.at(x)
                viol = ev.violation(x)
                traj = jax.tree_util.tree_map(np.asarray, problem.compiled("trajectory")(jnp.asarray(x), data_final))
    if interrupted:
        status = Status.INTERRUPTED
    elif fell_back is not None:
        status = Status.DIVERGED
    elif not solver_ok:
        status = Status.SOLVER_FAILED
    elif viol > constraint_tol:
        status = Status.INFEASIBLE
    else:
        status = Status.SOLVED
    success = status is Status.SOLVED
    if fell_back is not None:
        message = (f"{message}; {fell_back}; returning the end of stage {last_sound[1]} instead, the last whose "
                   "rollout did not diverge")
    if not interrupted and solver_ok and viol > constraint_tol:
        message = f"{message}; but the constraint violation {viol:.3g} exceeds constraint_tol={constraint_tol:g}"
    trajectory = dict(t=np.asarray(problem.t), q=traj["q"], v=traj["v"], a=traj["a"], tau=traj["tau"],
                      ctrl=traj["ctrl"])
    if traj.get("contact") is not None:
        c = traj["contact"]
        trajectory["contact"] = c if isinstance(c, dict) else contact_dict(c)
    info = dict(method=method, max_iter=max_iter, tol=tol, constraint_tol=constraint_tol, stages=stages_info,
                problem_hash=problem.hash(), problem_description=problem.describe(), cstorm_version=__version__,
                options=_jsonable(options or {}))
    sol = Solution(success=bool(success), status=status, message=message, cost=float(f), constraint_violation=float(viol),
                   iterations=tracker.iteration, x=np.asarray(x), trajectory=trajectory, history=tracker.history,
                   problem=problem.name, params={k: np.asarray(v).tolist() for k, v in params_now.items()},
                   wall_time_s=time.perf_counter() - t0, compile_time_s=compile_s,
                   n_evaluations=nev_done + (ev.nev if ev else 0), info=info)
    sol.segments = [Solution(**{**sol.__dict__, "segments": []})]
    return sol


def _stage_params(problem, sparams):
    """A stage's parameters: the problem's, with the stage's entries (as float arrays)."""
    return {**problem.params, **{k: np.asarray(v, float) for k, v in sparams.items()}}


def _midpoint(a, b):
    """Parameters halfway from stage parameters ``a`` to ``b`` (dicts of arrays with the
    same keys): the geometric mean where both are positive (tolerances and factors that
    ramp over decades), else the arithmetic mean. None if ``a`` is None or equals ``b``
    (nothing to refine)."""
    if a is None:
        return None
    mid, moved = {}, False
    for key, vb in b.items():
        vb = np.asarray(vb, float)
        va = np.asarray(a.get(key, vb), float)
        if va.shape != vb.shape:
            return None
        if np.array_equal(va, vb):
            mid[key] = vb
            continue
        moved = True
        mid[key] = np.where((va > 0) & (vb > 0), np.sqrt(np.abs(va * vb)), 0.5 * (va + vb))
    return {key: (float(v) if v.ndim == 0 else v.tolist()) for key, v in mid.items()} if moved else None


def resolve_objective_scale(spec, ev, x, first_step=1.0):
    """The factor applied to the objective seen by the solver, from `solve`'s
    ``objective_scale`` ``spec`` and the stage's evaluator ``ev`` at its start ``x``
    (n_vars,). ``"auto"``: ``first_step /
    |grad f(x_start)|_inf`` (so the first quasi-Newton step, taken with an identity
    Hessian, moves no control point by more than about ``first_step`` rad or m because of
    the cost; a problem sets ``solve_options["first_step"]``, default 1, where a radian
    throws its warm start away), ``first_step`` where the gradient vanishes."""
    if spec is None:
        return 1.0
    if spec == "auto":
        g = ev.at(x)[4]
        gmax = float(np.max(np.abs(g))) if g.size else 0.0
        return float(first_step) / gmax if np.isfinite(gmax) and gmax > 1e-12 else float(first_step)
    val = float(spec)
    if not (np.isfinite(val) and val > 0):
        raise InputError(f"solve: objective_scale must be 'auto', None or a positive number, got {spec!r}")
    return val


def _jsonable(d):
    if isinstance(d, dict):
        return {str(k): _jsonable(v) for k, v in d.items()}
    if isinstance(d, (list, tuple)):
        return [_jsonable(v) for v in d]
    if isinstance(d, (np.ndarray, np.generic)):
        return np.asarray(d).tolist()
    return d


# ---------------------------------------------------------------------------------------
# SLSQP
# ---------------------------------------------------------------------------------------
def run_slsqp(ev, x, tracker, stage, params, max_iter, tol, options):
    """One stage of `solve` with scipy's SLSQP, from ``x`` (n_vars,).

    Args:
      ev: the stage's evaluator: ``ev.at(x)`` -> ``(f, c_eq, c_in, diverged, grad f, J_eq,
        J_in)`` restricted to the stage's enforced rows (``ev.me``, ``ev.mi``: boolean
        masks over ``c_eq``, ``c_in``); the solver minimizes ``ev.fscale * f`` within
        ``ev.bounds`` (``(lb, ub)``, each (n_vars,); None: `variable_bounds` of ``ev.p``).
      tracker: records each iterate (``tracker.record(x, ev, stage, params)``).
      stage: the stage's index in the plan. params: its problem parameters.
      max_iter, tol: SLSQP's ``maxiter`` and ``ftol``. options: further SLSQP options
        (override those two).
    Returns:
      ``(x (n_vars,), solver_ok, message, iterations)``, ``solver_ok`` SLSQP's own
      verdict (`solve` also checks the constraint violation at ``x``)."""
    from scipy.optimize import Bounds, minimize

    cons = []
    if ev.me.any():
        cons.append(dict(type="eq", fun=lambda x: ev.at(x)[1], jac=lambda x: ev.at(x)[5]))
    if ev.mi.any():
        cons.append(dict(type="ineq", fun=lambda x: ev.at(x)[2], jac=lambda x: ev.at(x)[6]))

    def fun(x):
        v = ev.at(x)
        return ev.fscale * v[0], ev.fscale * v[4]

    def cb(xk):
        tracker.record(xk, ev, stage, params)

    opts = dict(maxiter=int(max_iter), ftol=float(tol))
    opts.update(options or {})
    lb, ub = getattr(ev, "bounds", None) or variable_bounds(ev.p)
    bounds = Bounds(lb, ub) if (np.isfinite(lb).any() or np.isfinite(ub).any()) else None
    res = minimize(fun, clip_into(x, lb, ub), jac=True, method="SLSQP", constraints=cons, options=opts,
                   callback=cb, bounds=bounds)
    return np.asarray(res.x), bool(res.success), f"SLSQP: {res.message}", int(res.nit)


# ---------------------------------------------------------------------------------------
# scipy trust-constr
# ---------------------------------------------------------------------------------------
def _run_trust_constr(ev, x, tracker, stage, params, max_iter, tol, options):
    """scipy's ``trust-constr``: equality-constrained SQP in a trust region (with an
    interior point for the inequalities), quasi-Newton (BFGS) Hessians of the objective
    and of each constraint block. ``tol`` is its ``gtol`` and ``xtol``;
    ``problem.solve_options["first_step"]`` its initial radius (default 1)."""
    from scipy.optimize import BFGS, Bounds, NonlinearConstraint, minimize

    cons = []
    if ev.me.any():
        cons.append(NonlinearConstraint(lambda x: ev.at(x)[1], 0.0, 0.0, jac=lambda x: ev.at(x)[5], hess=BFGS()))
    if ev.mi.any():
        cons.append(NonlinearConstraint(lambda x: ev.at(x)[2], 0.0, np.inf, jac=lambda x: ev.at(x)[6],
                                        hess=BFGS()))

    def fun(x):
        v = ev.at(x)
        return ev.fscale * v[0], ev.fscale * v[4]

    def cb(intermediate_result):
        tracker.record(intermediate_result.x, ev, stage, params)

    opts = dict(maxiter=int(max_iter), gtol=float(tol), xtol=float(tol),
                initial_tr_radius=float(ev.p.solve_options.get("first_step", 1.0)))
    opts.update(options or {})
    lb, ub = getattr(ev, "bounds", None) or variable_bounds(ev.p)
    bounds = Bounds(lb, ub, keep_feasible=True) if (np.isfinite(lb).any() or np.isfinite(ub).any()) else None
    x_in = clip_into(x, lb, ub)
    if bounds is not None:  # keep_feasible needs a strictly interior start (where both bounds are finite)
        fin = np.isfinite(lb) & np.isfinite(ub)
        w = np.where(fin, ub - lb, 0.0) * 1e-9
        x_in = np.where(fin, np.clip(x_in, lb + w, ub - w), x_in)
    res = minimize(fun, x_in, jac=True, hess=BFGS(), method="trust-constr", constraints=cons, options=opts,
                   callback=cb, bounds=bounds)
    ok = res.status in (1, 2)  # success is decided on the violation by the caller
    return np.asarray(res.x), bool(ok), f"trust-constr: {res.message}", int(res.nit)


# ---------------------------------------------------------------------------------------
# IPOPT through casadi
# ---------------------------------------------------------------------------------------
def _run_ipopt(ev, x, tracker, stage, params, max_iter, tol, options):
    try:
        import casadi as ca
    except ImportError:
        raise ProblemError("solve(method='ipopt') needs casadi: pip install 'cstorm[ipopt]' (or pip install casadi)") \
            from None
    return run_ipopt(ca, ev, x, tracker, stage, params, max_iter, tol, options)
