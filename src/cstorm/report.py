"""Everything that turns a solved motion into files a person can look at: success
criteria, the re-simulation fidelity check, ``summary.json``, the trajectory CSV, plots
and the animation (`write_outputs`, used by ``cstorm solve`` and ``cstorm animate``).

Works for any `MotionProblem` or `MotionSequence` (planar drawings are in the world x-z
plane; see `cstorm.viz`). Every file is written atomically (a temporary file in the same
folder, then ``os.replace``); ``summary.json`` is written last.

Success criteria
----------------
A problem (or sequence) may carry ``success_criteria``: a callable ``(solution) ->
{name: {"value": float, "tol": float, "ok": bool, ...}}`` or a list of specs (dicts, or
`Criterion` objects) evaluated on the solution by `evaluate_criteria`:

- ``{"type": "final_q", "joint": J, "target": x, "tol": t}``: ``|q_J(T) - x| <= t``
  (rad or m; a free/ball joint's error is the norm of its tangent difference; ``x`` may
  name a problem parameter, whose final value is used);
- ``{"type": "final_v", "joint": J, "target": 0.0, "tol": t}``: ``|v_J(T) - x| <= t``;
- ``{"type": "displacement", "joint": J, "min": d}`` (or ``"max"``): ``q_J(T) - q_J(0)
  >= d`` for a 1-DoF joint (e.g. ``root_x``: forward distance, m);
- ``{"type": "periodic", "joints": [...], "tol": t}``: ``max |q(T) - q(0)|, |v(T) -
  v(0)|`` over the joints' DoFs (tangent differences) ``<= t``;
- ``{"type": "constraint_violation", "tol": 1e-6}``: the solver's final violation;
- ``{"type": "max_abs", "of": "tau" | "q" | "v", "joint": J, "max": m}``: the largest
  ``|.|`` of a joint's torque / position / velocity over the motion ``<= m``.

Every spec takes an optional ``"name"``. Results are ``{"value", "tol", "op"
("<=" or ">="), "ok"}``. For a sequence, each segment's criteria are checked on its own
segment solution (reported per segment and, prefixed ``"<segment>/"``, at the top) and
the sequence's criteria on the whole motion. **``summary.json``'s ``success`` is the
solver's success and every criterion ok** (``solver_success`` keeps the former alone).

Fidelity
--------
`fidelity` re-simulates every segment open-loop with the solution's own spline controls
from the planned start state of that segment, twice:

1. ``"fine"``: the *same* integrator at a quarter of the time step (``dt/4``), with
   cstorm's fixed-step rollout: the plan's time-discretization error (an optimizer that
   exploits integration error shows up here);
2. ``"dop853"``: scipy's adaptive 8th-order Dormand-Prince integrator (``rtol=1e-6``,
   ``atol=1e-8``; tighter tolerances change the reported deviations by < 1 %) on the
   continuous-time ODE, the active joints evaluated on their splines at the
   integrator's own times: an independent, error-controlled integrator,
   i.e. a reference solution of the motion's ODE (it also checks cstorm's rollout code:
   the half-step spline samples, the Lie-group updates).

The obvious second fixed-step rule, semi-implicit Euler at ``dt/4``, is available
(``checks=(..., "other")``) but not a default: its own first-order error dominates on
sensitive motions (the acrobot swing-up planned with RK4 at 20 ms ends 134 deg off with
Euler at 5 ms and still 1.5 deg off at 20 ms / 1024, while RK4 at 5 ms and DOP853 agree
with the plan to 0.04 deg), so it would measure Euler, not the plan.

Each check reports the deviation of the final *passive* state from the plan, positions
(m: prismatic DoFs, free-joint translations) and angles (deg: revolute DoFs, rotation
angle of free/ball joints) separately, and velocities (m/s, deg/s), plus the largest
position/angle deviation along the planned grid. A check is flagged (``ok: false``) when
a final position deviates by more than 1 cm or an angle by more than 2 deg
(``tol_position_m``, ``tol_angle_deg``), or a final velocity by more than 1 cm/s or 1
deg/s (``tol_velocity_m_s``, ``tol_angular_velocity_deg_s``): a plan whose landing "at
rest" is an artefact of a step past the integrator's stability limit (see
`cstorm.check_time_step`) can agree in positions and not in velocities (the Luxo hop
planned at 4 ms: 2.7 mm but 0.024 m/s and 14 deg/s). Segments
of a sequence are checked separately, each from its own planned start (chaining
open-loop re-simulations would measure the instability of, e.g., a handstand, not the
integration). Cost: the fixed-step check reuses `cstorm.simulate.simulate`'s compiled
rollout (segments with the same horizon, step and environment structure compile once);
the DOP853 check compiles one right-hand side per joint split and environment structure
(shared by all segments of a sequence) and then costs about
one dynamics evaluation plus dispatch (~0.5-1 ms for the tumbler with contact) per
right-hand-side call, ~5,000 calls for 2 s of tumbler motion with contact.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import platform
import sys
import tempfile
import time

import numpy as np

from .errors import DivergenceError, InputError, ProblemError

__all__ = ["Criterion", "evaluate_criteria", "fidelity", "make_summary", "write_csv", "write_json", "write_outputs",
           "render", "problem_segments", "problem_from_source", "select_segment", "solution_at", "atomic_write"]

TOL_POSITION_M = 0.01
TOL_ANGLE_DEG = 2.0
TOL_VELOCITY_M_S = 0.01
TOL_ANGULAR_VELOCITY_DEG_S = 1.0


# ---------------------------------------------------------------------------------------
# Atomic file writes
# ---------------------------------------------------------------------------------------
def atomic_write(path, write, suffix=""):
    """Call ``write(tmp_path)`` on a temporary path next to ``path``, then move it onto
    ``path`` (``os.replace``); the temporary is removed on error."""
    path = os.fspath(path)
    d = os.path.dirname(os.path.abspath(path))
    os.makedirs(d, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=suffix or os.path.splitext(path)[1], dir=d)
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual permissions
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def _umask():
    m = os.umask(0)
    os.umask(m)
    return m


def write_json(path, obj):
    """Write ``obj`` as indented JSON, atomically. NaN/inf become null (strict JSON)."""
    text = json.dumps(_strict(obj), indent=2, allow_nan=False)

    def w(tmp):
        with open(tmp, "w") as f:
            f.write(text + "\n")
    return atomic_write(path, w, ".json")


def _strict(x):
    if isinstance(x, dict):
        return {str(k): _strict(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_strict(v) for v in x]
    if isinstance(x, np.ndarray):
        return _strict(x.tolist())
    if isinstance(x, np.generic):
        return _strict(x.item())
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


# ---------------------------------------------------------------------------------------
# Problems, segments and sources
# ---------------------------------------------------------------------------------------
def problem_segments(problem) -> list:
    """The `MotionProblem` segments of a problem or sequence (a list, one entry for a
    single problem)."""
    from .optimize.problem import MotionProblem
    from .optimize.sequence import MotionSequence

    if isinstance(problem, MotionSequence):
        return list(problem.segments)
    if isinstance(problem, MotionProblem):
        return [problem]
    raise InputError(f"expected a MotionProblem or MotionSequence, got {type(problem).__name__}")


def segment_solutions(solution) -> list:
    """Per-segment `Solution` objects (the solution itself if it has no segments)."""
    return list(solution.segments) if solution.segments else [solution]


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
    from . import examples

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
        from .problemfile import load_problem_text

        robot = source.get("robot") or {}
        problem = load_problem_text(source["text"], source.get("path", "<stored TOML>"), source.get("overrides"),
                                    package_dirs=robot.get("package_dirs", ()), strict=robot.get("strict", False))
    else:
        raise InputError(f"cannot rebuild the problem: unknown source kind {kind!r} (expected 'example' or 'toml')")
    seg = source.get("segment")
    if seg is not None:
        problem = select_segment(problem, seg)
    return problem


def select_segment(problem, name):
    """The segment named ``name`` (or with that 0-based index) of a `MotionSequence`.

    The returned `MotionProblem` starts from its own ``q0``/``v0``: the nominal start of
    that segment as its author set it (for the shipped sequences, the nominal end posture
    of the previous segment, at rest), not the end of a solved previous segment."""
    from .optimize.sequence import MotionSequence

    if not isinstance(problem, MotionSequence):
        raise InputError(f"--segment: problem {problem.name!r} is a single motion, not a sequence of segments")
    names = [s.name for s in problem.segments]
    if name in names:
        return problem.segments[names.index(name)]
    try:
        k = int(name)
    except (TypeError, ValueError):
        k = None
    if k is not None and 0 <= k < len(names):
        return problem.segments[k]
    raise InputError(f"--segment: sequence {problem.name!r} has no segment {name!r}; segments are {names}")


def solution_at(problem, x=None, *, evaluate=True, message="not solved: the initial guess"):
    """A `Solution` of ``problem`` at the decision vector ``x`` without solving (default:
    the problem's initial guess ``problem.x0``; for a sequence, a list of per-segment
    vectors or None, each segment starting where the previous one ends, as in a sequence
    solve). ``success`` is False. With ``evaluate`` the cost and constraint violation are
    computed (one more compiled function per problem); otherwise they are NaN. Use it to
    look at initial guesses (``cstorm solve NAME --guess``) or to test output code."""
    import jax
    import jax.numpy as jnp
    from .optimize.solution import Solution, Status
    from .optimize.solve import _contact_dict

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
            traj["contact"] = c if isinstance(c, dict) else _contact_dict(c)
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
# Success criteria
# ---------------------------------------------------------------------------------------
@dataclasses.dataclass
class Criterion:
    """A data spec of one success criterion (see the module docstring): ``type`` and
    its fields as keyword arguments, e.g. ``Criterion("final_q", joint="root_pitch",
    target=3.14159, tol=0.05)``. Equivalent to the dict ``{"type": ..., **fields}``."""

    type: str
    fields: dict = dataclasses.field(default_factory=dict)

    def __init__(self, type, **fields):
        self.type, self.fields = type, fields

    def spec(self) -> dict:
        return {"type": self.type, **self.fields}


_CRITERIA = ("final_q", "final_v", "displacement", "periodic", "constraint_violation", "max_abs")


def check_criteria_spec(spec, model, where="success_criteria"):
    """Validate criterion specs (one, or a list) against a model (eager; raises
    `ProblemError` naming the entry (``where[i]``, or ``where`` for a single spec) and
    the key)."""
    if callable(spec) or spec is None:
        return
    single = isinstance(spec, (dict, Criterion))
    if single:
        spec = [spec]
    for i, c in enumerate(spec):
        c = c.spec() if isinstance(c, Criterion) else c
        w = where if single else f"{where}[{i}]"
        if not isinstance(c, dict):
            raise ProblemError(f"{w}: a criterion must be a dict or Criterion, got {type(c).__name__}")
        t = c.get("type")
        if t not in _CRITERIA:
            raise ProblemError(f"{w}: unknown criterion type {t!r}; known: {list(_CRITERIA)}")
        allowed = dict(final_q={"joint", "target", "tol"}, final_v={"joint", "target", "tol"},
                       displacement={"joint", "min", "max"}, periodic={"joints", "tol"},
                       constraint_violation={"tol"}, max_abs={"of", "joint", "max"})[t] | {"type", "name"}
        bad = sorted(set(c) - allowed)
        if bad:
            raise ProblemError(f"{w} ({t}): unknown keys {bad}; allowed: {sorted(allowed)}")
        joints = c.get("joints", []) if t == "periodic" else ([c["joint"]] if "joint" in c else [])
        if t in ("final_q", "final_v", "displacement", "max_abs") and "joint" not in c:
            raise ProblemError(f"{w} ({t}): missing key 'joint'")
        for j in joints:
            if j not in model.joint_names:
                raise ProblemError(f"{w} ({t}): no joint named {j!r}; joints are {list(model.joint_names)}")
        if t == "displacement":
            if ("min" in c) == ("max" in c):
                raise ProblemError(f"{w} (displacement): give exactly one of 'min' or 'max'")
            if model.joints[model.joint_names.index(c["joint"])].nq != 1:
                raise ProblemError(f"{w} (displacement): joint {c['joint']!r} is not 1-DoF")
        if t in ("final_q", "final_v", "periodic", "constraint_violation") and "tol" not in c:
            raise ProblemError(f"{w} ({t}): missing key 'tol'")
        if t == "final_q" and "target" not in c:
            raise ProblemError(f"{w} (final_q): missing key 'target'")
        if t == "max_abs" and (c.get("of") not in ("tau", "q", "v") or "max" not in c):
            raise ProblemError(f"{w} (max_abs): needs 'of' ('tau', 'q' or 'v') and 'max'")


def _criterion(c, model, sol):
    tr = sol.trajectory
    t = c["type"]
    name = c.get("name")
    if t in ("final_q", "final_v", "displacement", "max_abs"):
        j = model.joint_names.index(c["joint"])
        jt = model.joints[j]
        qs, vs = model.q_starts[j], model.v_starts[j]
        qsl, vsl = slice(qs, qs + jt.nq), slice(vs, vs + jt.nv)
    if t in ("final_q", "final_v"):
        target = c.get("target", 0.0)
        if isinstance(target, str):  # a problem parameter's final value
            if target not in (sol.params or {}):
                raise ProblemError(f"success criterion {c.get('name') or t}: target {target!r} is not a problem "
                                   f"parameter of the solution ({sorted(sol.params or {})})")
            target = sol.params[target]
        target = np.atleast_1d(np.asarray(target, float))
    if t == "final_q":
        err = np.asarray(jt.difference(np.asarray(target), np.asarray(tr["q"][-1][qsl])))
        val, tol, op = float(np.linalg.norm(err)), float(c["tol"]), "<="
        name = name or f"final_q[{c['joint']}]"
    elif t == "final_v":
        val, tol, op = float(np.linalg.norm(np.asarray(tr["v"][-1][vsl]) - target)), float(c["tol"]), "<="
        name = name or f"final_v[{c['joint']}]"
    elif t == "displacement":
        val = float(tr["q"][-1][qs] - tr["q"][0][qs])
        op, tol = (">=", float(c["min"])) if "min" in c else ("<=", float(c["max"]))
        name = name or f"displacement[{c['joint']}]"
    elif t == "periodic":
        errs = [0.0]
        for jn in c["joints"]:
            j = model.joint_names.index(jn)
            jt_, qs_, vs_ = model.joints[j], model.q_starts[j], model.v_starts[j]
            dq = np.asarray(jt_.difference(np.asarray(tr["q"][0][qs_:qs_ + jt_.nq]),
                                           np.asarray(tr["q"][-1][qs_:qs_ + jt_.nq])))
            dv = np.asarray(tr["v"][-1][vs_:vs_ + jt_.nv]) - np.asarray(tr["v"][0][vs_:vs_ + jt_.nv])
            errs += [float(np.max(np.abs(dq))), float(np.max(np.abs(dv)))]
        val, tol, op = max(errs), float(c["tol"]), "<="
        name = name or "periodic"
    elif t == "constraint_violation":
        val, tol, op = float(sol.constraint_violation), float(c["tol"]), "<="
        name = name or "constraint_violation"
    else:  # max_abs
        arr = np.asarray(tr[c["of"]])[:, qsl if c["of"] == "q" else vsl]
        val, tol, op = float(np.max(np.abs(arr))), float(c["max"]), "<="
        name = name or f"max_abs_{c['of']}[{c['joint']}]"
    ok = bool(np.isfinite(val) and (val <= tol if op == "<=" else val >= tol))
    return name, dict(value=val, tol=tol, op=op, ok=ok)


def evaluate_criteria(spec, model, solution) -> dict:
    """Evaluate ``spec`` (a callable ``(solution) -> dict`` or a list of specs) on a
    solution; returns ``{name: {"value", "tol", "op", "ok"}}`` ({} for no spec)."""
    if spec is None:
        return {}
    if callable(spec):
        res = spec(solution)
        if not isinstance(res, dict):
            raise ProblemError(f"success_criteria callable returned {type(res).__name__}, expected a dict "
                               "{name: {'value', 'tol', 'ok'}}")
        out = {}
        for k, v in res.items():
            if not (isinstance(v, dict) and "ok" in v):
                raise ProblemError(f"success_criteria: entry {k!r} must be a dict with at least 'ok', got {v!r}")
            out[str(k)] = {kk: (bool(vv) if kk == "ok" else _strict(vv)) for kk, vv in v.items()}
        return out
    if isinstance(spec, (dict, Criterion)):
        spec = [spec]
    check_criteria_spec(spec, model)
    out = {}
    for c in spec:
        name, r = _criterion(c.spec() if isinstance(c, Criterion) else c, model, solution)
        out[name] = r
    return out


def all_criteria(problem, solution) -> tuple:
    """``(criteria, per_segment)``: the combined dict (segment criteria prefixed with
    ``"<segment name>/"`` when the problem is a sequence) and a list of per-segment
    dicts."""
    segs, sols = problem_segments(problem), segment_solutions(solution)
    is_seq = not (len(segs) == 1 and segs[0] is problem)
    per_seg, combined = [], {}
    for p, s in zip(segs, sols):
        c = evaluate_criteria(getattr(p, "success_criteria", None), p.model, s)
        per_seg.append(c)
        for k, v in c.items():
            combined[f"{p.name}/{k}" if is_seq else k] = v
    if is_seq:
        combined.update(evaluate_criteria(getattr(problem, "success_criteria", None), segs[0].model, solution))
    return combined, per_seg


# ---------------------------------------------------------------------------------------
# Fidelity: re-simulation at dt/4 and with an independent adaptive integrator
# ---------------------------------------------------------------------------------------
_OTHER = {"rk4": "euler", "euler": "rk4"}
_contact_fn_cache: dict = {}
_rhs_cache: dict = {}


def _static_contact_fn(problem):
    """A (q, v) -> (f_ext, data) function for a problem with a user ``contact_fn`` (one
    per problem, so it can be a static argument of a compiled function)."""
    key = id(problem)
    if key not in _contact_fn_cache:
        m = problem.model
        _contact_fn_cache[key] = (problem, lambda q, v: problem._contact_fn(m, None, None, q, v))
    return _contact_fn_cache[key][1]


def _resimulate(problem, ctrl, q0, v0, dt, integrator):
    """Fixed-step re-simulation with cstorm's rollout (`cstorm.simulate.simulate`)."""
    from .simulate import simulate

    kw = {}
    if problem.env is not None:
        kw = dict(env=problem.env, contact=problem.contact)
    elif problem._contact_fn is not None:
        kw = dict(contact_fn=_static_contact_fn(problem))
    return simulate(problem.model, q0, v0, t_final=problem.t_final, dt=dt, active=problem.active, ctrl=ctrl,
                    spline=problem.spline, integrator=integrator, q_bound=problem.q_bound, v_bound=problem.v_bound,
                    **kw)


def _qdot_passive(model, layout, q, v):
    """Time derivative of the passive configuration entries (layout.qp_idx order):
    ``qdot = v`` for 1-DoF joints; a free joint's ``pdot = R v_body``, ``quat_dot = 1/2
    quat (x) (0, omega_body)``; a ball joint's ``quat_dot = 1/2 quat (x) (0, omega)``."""
    import jax.numpy as jnp
    from . import spatial as sp

    parts = []
    for i in layout.passive_joints:
        j = model.joints[i]
        qs, vs = model.q_starts[i], model.v_starts[i]
        qj, vj = q[qs:qs + j.nq], v[vs:vs + j.nv]
        kind = type(j).__name__
        if kind == "Free":
            quat = qj[3:7]
            parts += [sp.quat_to_rot(quat) @ vj[3:], 0.5 * sp.quat_mul(quat, jnp.concatenate([jnp.zeros(1), vj[:3]]))]
        elif kind == "Ball":
            parts.append(0.5 * sp.quat_mul(qj, jnp.concatenate([jnp.zeros(1), vj])))
        else:
            parts.append(vj)
    return jnp.concatenate(parts) if parts else jnp.zeros(0)


def _normalize_passive(model, layout, q):
    import jax.numpy as jnp

    for i in layout.passive_joints:
        j = model.joints[i]
        qs = model.q_starts[i]
        kind = type(j).__name__
        if kind == "Free":
            q = q.at[qs + 3:qs + 7].set(q[qs + 3:qs + 7] / jnp.linalg.norm(q[qs + 3:qs + 7]))
        elif kind == "Ball":
            q = q.at[qs:qs + 4].set(q[qs:qs + 4] / jnp.linalg.norm(q[qs:qs + 4]))
    return q


def _rhs_function(problem):
    """A compiled ``f(t, x, q_template, v_template, qa, va, aa, model, env, contact) ->
    xdot`` of the passive state ``x = (q_p, v_p)`` given the active joints' position,
    velocity and acceleration at ``t`` (evaluated on the host from the spline), so one
    compile serves every problem with the same joints split and environment structure
    (all segments of a sequence, whatever their horizon or control points)."""
    import jax
    import jax.numpy as jnp
    from .simulate import _stage

    layout = problem.layout
    user_cf = None if problem.env is not None or problem._contact_fn is None else _static_contact_fn(problem)
    key = (layout, problem.env is not None, user_cf)
    if key in _rhs_cache:
        return _rhs_cache[key]
    iqp, ivp = np.array(layout.qp_idx, int), np.array(layout.vp_idx, int)
    nqp = len(iqp)

    def f(t, x, q_tmpl, v_tmpl, qa, va, aa, model, env, contact):
        q = _normalize_passive(model, layout, q_tmpl.at[iqp].set(x[:nqp]))
        v = v_tmpl.at[ivp].set(x[nqp:])
        if env is not None:
            from .contact import contact_forces

            def cf(q_, v_):
                o = contact_forces(model, env, contact, q_, v_)
                return o.f_ext, o
        else:
            cf = user_cf
        q, v, a, tau, _, _ = _stage(model, layout, q, v, qa, va, aa, t, cf, None, None)
        return jnp.concatenate([_qdot_passive(model, layout, q, v), a[ivp]])

    fn = jax.jit(f)
    _rhs_cache[key] = fn
    return fn


def _adaptive(problem, ctrl, q0, v0, t_eval, rtol=1e-6, atol=1e-8):
    """Re-simulate with scipy's adaptive DOP853 (8th order, error-controlled) on the
    continuous-time ODE: active joints evaluated on their splines (scipy `BSpline` of
    the same knots and control points) at the solver's own times. Returns
    (q (len(t_eval), nq), v, n_rhs_evaluations)."""
    import jax.numpy as jnp
    from scipy.integrate import solve_ivp
    from scipy.interpolate import BSpline

    fn = _rhs_function(problem)
    layout, spl = problem.layout, problem.spline
    iqp, ivp = np.array(layout.qp_idx, int), np.array(layout.vp_idx, int)
    ia, iva = np.array(layout.qa_idx, int), np.array(layout.va_idx, int)
    ctrl = np.asarray(ctrl, float).reshape(spl.n_ctrl, -1)
    B0 = BSpline(np.asarray(spl.knots), ctrl, spl.degree, extrapolate=True)
    B1, B2 = B0.derivative(1), B0.derivative(2)
    q_t, v_t = jnp.asarray(q0, jnp.float64), jnp.asarray(v0, jnp.float64)
    args = (problem.model, problem.env, problem.contact)
    x0 = np.concatenate([np.asarray(q0)[iqp], np.asarray(v0)[ivp]])
    bound = max(problem.q_bound, problem.v_bound)
    T = problem.t_final

    def rhs(t, x):
        # a trial stage of a step that is too long may leave the bounds (a stiff contact
        # damper at an impact): NaN makes the step's error estimate NaN and solve_ivp
        # rejects the step and shortens it; a motion that really diverges ends with the
        # step size underflowing (status -1) or with accepted states out of bounds
        if not np.all(np.abs(x) < bound):
            return np.full_like(x, np.nan)
        tc = min(max(t, 0.0), T)
        return np.asarray(fn(t, jnp.asarray(x), q_t, v_t, B0(tc), B1(tc), B2(tc), *args))

    sol = solve_ivp(rhs, (0.0, T), x0, method="DOP853", t_eval=t_eval, rtol=rtol, atol=atol)
    if sol.status != 0 or sol.y.shape[1] != len(t_eval) or not np.all(np.abs(sol.y) < bound):
        t_end = float(sol.t[-1]) if len(sol.t) else 0.0
        raise DivergenceError(f"adaptive re-simulation (DOP853) failed or left the bounds by t = {t_end:.6g} s: "
                              f"{sol.message}")
    X = sol.y.T
    nqp = len(iqp)
    tt = np.clip(np.asarray(t_eval, float), 0.0, T)
    Q = np.tile(np.asarray(q0, float), (len(t_eval), 1))
    V = np.tile(np.asarray(v0, float), (len(t_eval), 1))
    Q[:, iqp], V[:, ivp] = X[:, :nqp], X[:, nqp:]
    if len(ia):
        Q[:, ia], V[:, iva] = B0(tt), B1(tt)
    for i in layout.passive_joints:  # unit quaternions
        j = problem.model.joints[i]
        qs = problem.model.q_starts[i]
        kind = type(j).__name__
        sl = slice(qs + 3, qs + 7) if kind == "Free" else slice(qs, qs + 4) if kind == "Ball" else None
        if sl is not None:
            Q[:, sl] /= np.linalg.norm(Q[:, sl], axis=1, keepdims=True)
    return Q, V, int(sol.nfev)


def _passive_deviation(model, layout, q_ref, v_ref, q, v):
    """Largest deviations of the passive DoFs between two states (host numpy):
    dict position_m, angle_deg, velocity_m_s, angular_velocity_deg_s (None where the
    model has no such passive DoF)."""
    pos, ang, vel, avel = [], [], [], []
    for i in layout.passive_joints:
        j = model.joints[i]
        qs, vs = model.q_starts[i], model.v_starts[i]
        qa, qb = np.asarray(q_ref[qs:qs + j.nq], float), np.asarray(q[qs:qs + j.nq], float)
        va, vb = np.asarray(v_ref[vs:vs + j.nv], float), np.asarray(v[vs:vs + j.nv], float)
        kind = type(j).__name__
        if kind == "Revolute":
            ang.append(abs(qb[0] - qa[0])), avel.append(abs(vb[0] - va[0]))
        elif kind == "Prismatic":
            pos.append(abs(qb[0] - qa[0])), vel.append(abs(vb[0] - va[0]))
        elif kind == "Free":
            pos.append(float(np.linalg.norm(qb[:3] - qa[:3])))
            ang.append(_quat_angle(qa[3:7], qb[3:7]))
            avel.append(float(np.linalg.norm(vb[:3] - va[:3]))), vel.append(float(np.linalg.norm(vb[3:] - va[3:])))
        elif kind == "Ball":
            ang.append(_quat_angle(qa, qb)), avel.append(float(np.linalg.norm(vb - va)))
        else:  # unknown joint type: count its tangent difference as a position
            pos.append(float(np.linalg.norm(np.asarray(j.difference(qa, qb))))), vel.append(
                float(np.linalg.norm(vb - va)))
    mx = lambda xs, s=1.0: (float(max(xs)) * s) if xs else None
    deg = 180.0 / math.pi
    return dict(position_m=mx(pos), angle_deg=mx(ang, deg), velocity_m_s=mx(vel), angular_velocity_deg_s=mx(avel, deg))


def _quat_angle(a, b):
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    return float(2.0 * math.acos(min(1.0, abs(float(np.dot(a, b))))))


def _flags(dev, tol_position, tol_angle, tol_velocity=TOL_VELOCITY_M_S,
           tol_angular_velocity=TOL_ANGULAR_VELOCITY_DEG_S):
    bad = []
    for key, tol, what, unit in (("position_m", tol_position, "position", "m"), ("angle_deg", tol_angle, "angle", "deg"),
                                 ("velocity_m_s", tol_velocity, "velocity", "m/s"),
                                 ("angular_velocity_deg_s", tol_angular_velocity, "angular velocity", "deg/s")):
        val = dev[key]
        if val is not None and not (val <= tol):
            bad.append(f"final passive {what} off by {val:.3g} {unit} (> {tol:g} {unit})")
    return bad


#: the checks of a torque-controlled (DDP) plan: its integrator at dt/factor and at
#: dt/(4 factor) (the torques are exact controls of the continuous system, held over
#: each step, so the only error is the integration's)
_TORQUE_CHECKS = ("fine", "finer")
_DEV_KEYS = ("position_m", "angle_deg", "velocity_m_s", "angular_velocity_deg_s", "path_position_m", "path_angle_deg")
CHECKS = ("fine", "dop853", "other")


def fidelity(problem, solution, *, checks=("fine", "dop853"), factor: int = 4,
             tol_position_m: float = TOL_POSITION_M, tol_angle_deg: float = TOL_ANGLE_DEG,
             tol_velocity_m_s: float = TOL_VELOCITY_M_S,
             tol_angular_velocity_deg_s: float = TOL_ANGULAR_VELOCITY_DEG_S,
             rtol: float = 1e-6, atol: float = 1e-8) -> dict:
    """Re-simulate every segment of ``solution`` open-loop with its own spline controls
    from its planned start state and compare with the plan.

    Checks (``checks``, in order):
      ``"fine"``: the planning integrator at ``dt / factor`` (cstorm's fixed-step
        rollout): the plan's own time-discretization error.
      ``"dop853"``: scipy's adaptive 8th-order Dormand-Prince integrator (``rtol``,
        ``atol``) on the continuous-time ODE, the active joints evaluated on their
        splines at the integrator's own times: an independent integrator whose error is
        controlled, i.e. a reference solution of the motion's ODE.
      ``"other"``: the other fixed-step rule (RK4 <-> semi-implicit Euler) at
        ``dt / factor``. Not a default: Euler's own first-order error dominates on
        sensitive motions (the acrobot swing-up planned with RK4 at 20 ms ends 134 deg
        off with Euler at 5 ms, 1.5 deg at 20 ms / 1024, while RK4 at 5 ms and DOP853
        agree with the plan to 0.03 deg).

    Returns a JSON-able dict: ``ok`` (bool: no check flagged), ``flags`` (list of str),
    the worst final deviations ``position_m``, ``angle_deg``, ``velocity_m_s``,
    ``angular_velocity_deg_s`` and along the grid ``path_position_m``,
    ``path_angle_deg`` (None where the robot has no such passive DoF), ``checks`` (per
    check: ``name``, ``integrator``, ``dt``, the deviations, ``flags``, ``ok``; for a
    sequence under ``segments``, per segment), ``tolerances``, ``method`` and
    ``wall_time_s``.
    """
    bad = [c for c in checks if c not in CHECKS]
    if bad:
        raise InputError(f"fidelity: unknown checks {bad}; known: {list(CHECKS)}")
    t0 = time.perf_counter()
    segs, sols = problem_segments(problem), segment_solutions(solution)
    segs = segs[:len(sols)]  # an interrupted sequence: check the segments that were solved
    seg_reports = []
    for p, s in zip(segs, sols):
        tr = s.trajectory
        q_plan, v_plan = np.asarray(tr["q"]), np.asarray(tr["v"])
        t_plan = np.asarray(tr["t"], float)
        torques = "ctrl" not in tr  # a DDP solution: motor torques held over each step
        ctrl = np.asarray(tr["u"] if torques else tr["ctrl"])
        entries = []
        for name in (_TORQUE_CHECKS if torques else checks):
            tc = time.perf_counter()
            if name == "dop853":
                entry = dict(name=name, integrator="dop853 (scipy, adaptive)", rtol=rtol, atol=atol)
            else:
                integ = p.integrator if name == "fine" else _OTHER[p.integrator]
                entry = dict(name=name, integrator=integ, dt=p.dt / factor, steps=p.n_steps * factor)
            if name == "finer":
                entry = dict(name=name, integrator=p.integrator, dt=p.dt / (4 * factor), steps=p.n_steps * 4 * factor)
            try:
                if torques:
                    from .optimize.ddp_problem import resimulate

                    f_ = factor if name == "fine" else 4 * factor
                    Q, V = resimulate(p, ctrl, q_plan[0], v_plan[0], f_, entry["integrator"])
                elif name == "dop853":
                    Q, V, nfev = _adaptive(p, ctrl, q_plan[0], v_plan[0], t_plan, rtol=rtol, atol=atol)
                    entry["rhs_evaluations"] = nfev
                else:
                    sim = _resimulate(p, ctrl, q_plan[0], v_plan[0], p.dt / factor, integ)
                    Q, V = sim.q[::factor], sim.v[::factor]
            except DivergenceError as e:
                entry.update({k: None for k in _DEV_KEYS}, diverged=True, ok=False,
                             flags=[f"{entry['integrator']}: re-simulation diverged: {e}"],
                             wall_time_s=time.perf_counter() - tc)
                entries.append(entry)
                continue
            dev = _passive_deviation(p.model, p.layout, q_plan[-1], v_plan[-1], Q[-1], V[-1])
            n = min(len(Q), len(q_plan))
            path = [_passive_deviation(p.model, p.layout, q_plan[k], v_plan[k], Q[k], V[k])
                    for k in range(0, n, max(1, n // 400))] + [dev]
            pmax = lambda key: max([d[key] for d in path if d[key] is not None], default=None)
            entry.update(dev, path_position_m=pmax("position_m"), path_angle_deg=pmax("angle_deg"), diverged=False)
            label = entry["integrator"] + (f" at dt={entry['dt']:g} s" if "dt" in entry else "")
            entry["flags"] = [f"{label}: {b}" for b in _flags(dev, tol_position_m, tol_angle_deg, tol_velocity_m_s,
                                                              tol_angular_velocity_deg_s)]
            entry["ok"] = not entry["flags"]
            entry["wall_time_s"] = time.perf_counter() - tc
            entries.append(entry)
        seg_reports.append(dict(segment=p.name, ok=all(c["ok"] for c in entries), checks=entries,
                                **_worst(entries)))
    all_checks = [c for r in seg_reports for c in r["checks"]]
    flags = [f"{r['segment']}: {f}" if len(seg_reports) > 1 else f for r in seg_reports for c in r["checks"]
             for f in c["flags"]]
    words = dict(fine=f"the planning integrator at dt/{factor}",
                 dop853=f"scipy's adaptive DOP853 (rtol={rtol:g}, atol={atol:g}) on the continuous-time ODE",
                 other=f"the other fixed-step integrator (rk4 <-> semi-implicit euler) at dt/{factor}",
                 finer=f"the planning integrator at dt/{4 * factor}")
    torque_plan = any("ctrl" not in s.trajectory for s in sols)
    out = dict(ok=not flags, flags=flags, **_worst(all_checks),
               tolerances=dict(position_m=tol_position_m, angle_deg=tol_angle_deg, velocity_m_s=tol_velocity_m_s,
                               angular_velocity_deg_s=tol_angular_velocity_deg_s),
               method=("each segment re-simulated open-loop with its solution's " +
                       ("motor torques (held over each step)" if torque_plan else "spline controls") +
                       " from its planned start state with " +
                       " and with ".join(words[c] for c in (_TORQUE_CHECKS if torque_plan else checks)) +
                       "; deviations of the final passive state from the plan (worst over checks and segments)"),
               wall_time_s=None)
    if len(seg_reports) == 1:
        out["checks"] = seg_reports[0]["checks"]
    else:
        out["segments"] = seg_reports
    out["wall_time_s"] = time.perf_counter() - t0
    return out


def _worst(checks):
    out = {}
    for k in _DEV_KEYS:
        vals = [c[k] for c in checks if c.get(k) is not None]
        out[k] = max(vals) if vals else None
    return out


# ---------------------------------------------------------------------------------------
# summary.json
# ---------------------------------------------------------------------------------------
_FIELDS = ("problem", "success", "message", "cost", "constraint_violation", "iterations", "wall_time_s",
           "compile_time_s")


def torque_check(problem, solution) -> dict:
    """The active joints' torques against the model's effort limits on *every* step of
    every segment's trajectory (not only on the constraint grid of ``TorqueLimits``-style
    constraints, which sample the path: a contact impact between two samples can need far
    more than the limit for a few ms). Joints without a finite limit are skipped.

    Returns ``{"ok", "worst_ratio", "joint", "t", "segment", "message", "segments": [{"segment",
    "ok", "worst_ratio", "joint", "t", "max_abs_tau": {joint: N m}, "ratio": {joint: |tau|/limit}}]}``
    (``ok``: every ratio <= 1 + 1e-6; ``t`` in the segment's own time, s)."""
    out_segs = []
    for prob, sol in zip(problem_segments(problem), segment_solutions(solution)):
        lim = np.asarray(prob.model.effort_limit, float)
        idx = [i for i in prob.layout.va_idx if np.isfinite(lim[i]) and lim[i] > 0]
        names = [_dof_names(prob.model, "v")[i] for i in idx]
        a = np.abs(np.asarray(sol.trajectory["tau"], float)[:, idx])  # (N+1, k)
        r = a / lim[idx]
        mx = dict(zip(names, map(float, a.max(axis=0, initial=0.0))))
        ratio = dict(zip(names, map(float, r.max(axis=0, initial=0.0))))
        worst = (0.0, None, None)
        if r.size and r.max() > 0:
            k, j = np.unravel_index(np.argmax(r), r.shape)
            worst = (float(r[k, j]), names[j], float(np.asarray(sol.trajectory["t"], float)[k]))
        out_segs.append(dict(segment=sol.problem or prob.name, ok=bool(worst[0] <= 1 + 1e-6), worst_ratio=worst[0],
                             joint=worst[1], t=worst[2], max_abs_tau=mx, ratio=ratio))
    w = max(out_segs, key=lambda r: r["worst_ratio"]) if out_segs else None
    ok = all(r["ok"] for r in out_segs)
    msg = ("every active joint's torque is within its effort limit on every step" if ok else
           f"{w['segment']}: {w['joint']} needs {w['worst_ratio']:.2f}x its effort limit at t = {w['t']:.3f} s "
           "(between the samples of a sampled torque-limit constraint; TorqueLimits(dense=True) enforces every step)")
    return dict(ok=ok, worst_ratio=w["worst_ratio"] if w else 0.0, joint=w["joint"] if w else None,
                t=w["t"] if w else None, segment=w["segment"] if w else None, message=msg, segments=out_segs)


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
    from . import __version__

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
                        **{k: fr.get(k) for k in _DEV_KEYS})]
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
    plans = [_strict(_jsonable(getattr(p, "solve_options", {}))) for p in segs]
    prov = dict(cstorm_version=__version__, problem_hash=problem_hash(problem), problem_kind=type(problem).__name__,
                solver_options=dict(method=solver_info.get("method"), max_iter=solver_info.get("max_iter"),
                                    tol=solver_info.get("tol"), constraint_tol=solver_info.get("constraint_tol"),
                                    options=solver_info.get("options"), plans=plans),
                success_criteria=_describe_criteria(problem),
                fidelity_tolerances=(fidelity_report or {}).get("tolerances"), source=source,
                python=sys.version.split()[0], platform=platform.platform(),
                created=time.strftime("%Y-%m-%dT%H:%M:%S%z"))
    try:
        import jax
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
    return _strict(out)


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
    return _strict(_jsonable(out))


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
def _dof_names(model, kind):
    out = []
    for j, n in zip(model.joints, model.joint_names):
        k = j.nq if kind == "q" else j.nv
        out += [n] if k == 1 else [f"{n}_{i}" for i in range(k)]
    return out


def write_csv(path, motion) -> str:
    """Write the trajectory of a `cstorm.viz.motion.Motion` as CSV (atomically): columns
    ``t`` (s), ``segment`` (index), ``q_<joint>`` (rad or m; ``_<i>`` per component of
    multi-DoF joints), ``v_<joint>`` (rad/s or m/s), ``tau_<joint>`` (N m or N: motor
    torque of active joints, spring/damper/limit force of passive ones) and, with contact,
    ``N_<geom>_<obstacle>[_<feature>]`` (normal force magnitude of each contact point, N).
    The header names every column."""
    m = motion.model
    cols = [motion.t[:, None], motion.segment_index[:, None].astype(float), motion.q, motion.v, motion.tau]
    header = ["t", "segment"] + [f"q_{n}" for n in _dof_names(m, "q")] + [f"v_{n}" for n in _dof_names(m, "v")] + \
        [f"tau_{n}" for n in _dof_names(m, "v")]
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
                  time_step=None) -> dict:
    """Write ``out_dir/``: ``solution.npz``, ``trajectory.csv``, the PNG plots
    (``joints.png``, ``torques.png``, ``contacts.png`` when there is contact,
    ``paths.png``), ``animation.gif`` (and ``animation.mp4`` if ffmpeg is on PATH) and,
    last, ``summary.json``. ``source`` (see `problem_from_source`) is stored in the
    solution's ``info`` and the provenance so ``cstorm animate`` can rebuild the problem.

    The solution is saved first (a failure later loses no solve); a fidelity check or
    a picture that fails (or a Ctrl-C during the fidelity check) is recorded in the
    summary's ``warnings`` (and the fidelity as not ok) instead of losing the other
    files. ``time_step``: per-segment `cstorm.check_time_step` results to record (see
    `make_summary`; a segment whose step is not ok also adds a ``warnings`` entry).
    Returns the summary dict (with ``files``: the names written)."""
    from .viz.motion import Motion

    os.makedirs(out_dir, exist_ok=True)
    say = log or (lambda msg: None)
    warnings_ = []
    files = []
    npz = os.path.join(out_dir, "solution.npz")
    if source is not None:
        solution.info = dict(solution.info or {}, source=source)
    if save_solution:
        solution.save(npz)
        files.append("solution.npz")
    if fidelity_report is None and check_fidelity:
        say("fidelity: re-simulating every segment at dt/4 and with DOP853 ...")
        try:
            fidelity_report = fidelity(problem, solution)
        except KeyboardInterrupt:
            fidelity_report = dict(ok=False, flags=["fidelity check interrupted (Ctrl-C)"])
            warnings_.append("fidelity check interrupted (Ctrl-C)")
        except Exception as e:  # recorded, not fatal: the solve's files still get written
            fidelity_report = dict(ok=False, flags=[f"fidelity check failed: {type(e).__name__}: {e}"])
            warnings_.append(f"fidelity check failed: {type(e).__name__}: {e}")
    criteria, per_seg = all_criteria(problem, solution)
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
        try:
            files += render(motion, out_dir, mp4=mp4, log=say, **kw)
        except Exception as e:
            warnings_.append(f"{what} failed: {type(e).__name__}: {e}")
            say(f"warning: {what} failed: {type(e).__name__}: {e}")
    summary["warnings"] = warnings_
    summary["files"] = sorted(files + ["summary.json"])
    write_json(os.path.join(out_dir, "summary.json"), summary)
    return summary


def render(motion, out_dir, *, plots=True, animation=True, mp4=True, log=None) -> list:
    """Write the PNG plots and the animation of a `Motion` into ``out_dir``; returns
    the file names written."""
    from .viz import animation as _anim
    from .viz import plots as _plots

    say = log or (lambda msg: None)
    files = []
    if plots:
        files += _plots.write_plots(motion, out_dir)
    if animation:
        t0 = time.perf_counter()
        files += _anim.write_animation(motion, out_dir, mp4=mp4)
        say(f"animation: {time.perf_counter() - t0:.1f} s")
    return files
