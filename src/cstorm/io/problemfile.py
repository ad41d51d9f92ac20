"""TOML problem files: a motion problem described as data (``cstorm solve file.toml``).

The schema is documented in docs/problem-files.md; in short::

    name = "acrobot_swing_up"
    [robot]        file = "acrobot.urdf" (URDF/MJCF, relative to this file) | name = "tumbler"
                   floating_base = "planar" | "free"      (URDF only)
                   package_dirs = ["dir", ...]  (URDF package:// roots), strict = true
    [environment]  [[environment.obstacle]] type = "ground" | "incline" | "box" | "platform"
                   | "step" | "sphere" (+ their arguments); pairs; self_collision
    [contact]      stiffness, damping, d_on, d_off, friction, v_max, eps;
                   [[contact.pair]] geom, obstacle (+ overrides)
    [motion]       active, t_final, dt, n_ctrl, integrator, q0, v0, q_final_active,
                   v_final_active, rest_start, rest_end, params, initial_guess, ...
    [[cost]]       type = "torque_squared" | "power" | "state_target" | "com_target"
    [[constraint]] type = "terminal_state" | "joint_limits" | "torque_limits"
    [solver]       method, max_iter, tol, constraint_tol, continuation, schedule, options
    [[criterion]]  success criteria (see `cstorm.report`)

Parsed with the standard library's `tomllib`. Every error is a `ProblemFileError` (an
`InputError`) whose message names the file, the table and key, and what is wrong.
Unknown tables and keys are errors (they are usually typos). Units are SI, angles in
radians.
"""

from __future__ import annotations

import math
import os
import tomllib

import numpy as np

import cstorm as cs

from ..analysis.criteria import check_criteria_spec
from ..contact import environment as E
from ..errors import CstormError, InputError
from ..optimize import constraints as K, costs as C
from ..optimize.problem import MotionProblem

__all__ = ["ProblemFileError", "load_problem", "load_problem_text", "read_problem_file"]


class ProblemFileError(InputError):
    """A TOML problem file is malformed; the message names the file, table and key."""


_TOP = {"name", "description", "robot", "environment", "contact", "motion", "cost", "constraint", "solver",
        "criterion"}


class _Ctx:
    def __init__(self, path):
        self.path = path

    def err(self, where, msg):
        return ProblemFileError(f"{self.path}: {where}: {msg}")

    # -- typed getters -----------------------------------------------------------------
    def table(self, d, key, where, required=False):
        if key not in d:
            if required:
                raise self.err(where, f"missing table [{key}]" if where == "top level" else f"missing key {key!r}")
            return {}
        v = d[key]
        if not isinstance(v, dict):
            raise self.err(where, f"{key!r} must be a table, got {_tname(v)}")
        return v

    def keys(self, d, allowed, where):
        bad = sorted(set(d) - set(allowed))
        if bad:
            raise self.err(where, f"unknown key(s) {bad}; allowed: {sorted(allowed)}")

    def number(self, d, key, where, required=False, default=None, positive=False, nonneg=False, integer=False):
        if key not in d:
            if required:
                raise self.err(where, f"missing key {key!r}")
            return default
        v = d[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise self.err(f"{where} {key}", f"expected a number, got {_tname(v)} {v!r}")
        if integer and not isinstance(v, int):
            raise self.err(f"{where} {key}", f"expected an integer, got {v!r}")
        if not math.isfinite(v):
            raise self.err(f"{where} {key}", f"must be finite, got {v!r}")
        if positive and not v > 0:
            raise self.err(f"{where} {key}", f"must be > 0, got {v!r}")
        if nonneg and not v >= 0:
            raise self.err(f"{where} {key}", f"must be >= 0, got {v!r}")
        return v

    def string(self, d, key, where, required=False, default=None, choices=None):
        if key not in d:
            if required:
                raise self.err(where, f"missing key {key!r}")
            return default
        v = d[key]
        if not isinstance(v, str):
            raise self.err(f"{where} {key}", f"expected a string, got {_tname(v)} {v!r}")
        if choices is not None and v not in choices:
            raise self.err(f"{where} {key}", f"must be one of {list(choices)}, got {v!r}")
        return v

    def boolean(self, d, key, where, default=False):
        if key not in d:
            return default
        v = d[key]
        if not isinstance(v, bool):
            raise self.err(f"{where} {key}", f"expected true or false, got {v!r}")
        return v

    def numbers(self, v, where, length=None):
        """A number or list of numbers -> float array."""
        vals = v if isinstance(v, list) else [v]
        for x in vals:
            if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
                raise self.err(where, f"expected finite numbers, got {v!r}")
        a = np.asarray(vals, dtype=float)
        if length is not None and a.shape != (length,):
            raise self.err(where, f"expected {length} number(s), got {len(vals)}")
        return a

    def value_or_param(self, v, where, params):
        """A number, a list of numbers, or the name of a problem parameter."""
        if isinstance(v, str):
            if v not in params:
                raise self.err(where, f"{v!r} is not a number and not a parameter of [motion] params "
                                      f"({sorted(params)})")
            return v
        a = self.numbers(v, where)
        return float(a[0]) if not isinstance(v, list) else a

    def names(self, v, where, choices=None, what="joint"):
        vals = [v] if isinstance(v, str) else v
        if not isinstance(vals, list) or not all(isinstance(x, str) for x in vals):
            raise self.err(where, f"expected a {what} name or a list of names, got {v!r}")
        if choices is not None:
            bad = [x for x in vals if x not in choices]
            if bad:
                raise self.err(where, f"no {what}(s) named {bad}; {what}s are {list(choices)}")
        return vals


def _tname(v):
    return {dict: "a table", list: "an array", str: "a string", bool: "a boolean", int: "an integer",
            float: "a float"}.get(type(v), type(v).__name__)


def load_problem(path, overrides=None, package_dirs=(), strict=False):
    """Read a TOML problem file; returns a `MotionProblem` (with ``solve_options`` and
    ``success_criteria`` from the file). ``overrides``: see `apply_overrides`;
    ``package_dirs``, ``strict``: see `load_problem_text`."""
    path = os.fspath(path)
    return load_problem_text(read_problem_file(path), path, overrides, package_dirs=package_dirs, strict=strict)


def read_problem_file(path):
    """The text of the problem file ``path`` (UTF-8); a `ProblemFileError` naming the file
    if it cannot be read or is not UTF-8 text."""
    try:
        with open(path, "rb") as f:
            raw = f.read()
    except OSError as e:
        raise ProblemFileError(f"{path}: cannot read the problem file: {e.strerror or e}") from None
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ProblemFileError(f"{path}: not UTF-8 text: {e}") from None


def apply_overrides(doc: dict, overrides: dict, path: str = "<string>") -> dict:
    """Set values in a parsed TOML document: ``{"motion.dt": 0.01, "solver.continuation.
    target": [1.0, 2.0], "cost.0.weight": 2.0}`` (dotted keys; integer parts index arrays
    of tables; missing tables are created). Returns ``doc`` (changed in place)."""
    for key, value in (overrides or {}).items():
        parts = str(key).split(".")
        if not all(parts):
            raise ProblemFileError(f"{path}: override {key!r}: empty part in the dotted key")
        d = doc
        for i, part in enumerate(parts[:-1]):
            where = ".".join(parts[:i + 1])
            if isinstance(d, list):
                if not part.isdigit() or int(part) >= len(d):
                    raise ProblemFileError(f"{path}: override {key!r}: {where!r} needs an index < {len(d)}")
                d = d[int(part)]
            else:
                d = d.setdefault(part, {})
            if not isinstance(d, (dict, list)):
                raise ProblemFileError(f"{path}: override {key!r}: {where!r} is a value, not a table")
        last = parts[-1]
        if isinstance(d, list):
            if not last.isdigit() or int(last) >= len(d):
                raise ProblemFileError(f"{path}: override {key!r}: needs an index < {len(d)}")
            d[int(last)] = value
        else:
            d[last] = value
    return doc


def load_problem_text(text: str, path: str = "<string>", overrides=None, package_dirs=(), strict=False):
    """Build the problem from TOML ``text``; ``path`` names it in errors and is the base
    for relative robot file paths; ``overrides`` (dotted key -> value) change the parsed
    document first (`apply_overrides`). ``package_dirs`` (directories holding ROS
    packages, searched before the file's ``[robot] package_dirs``) and ``strict`` (or-ed
    with the file's ``[robot] strict``) are the command line's ``--package-dir`` and
    ``--strict``."""

    ctx = _Ctx(path)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ProblemFileError(f"{path}: not valid TOML: {e}") from None
    apply_overrides(doc, overrides, path)
    ctx.keys(doc, _TOP, "top level")
    base = os.path.dirname(os.path.abspath(path)) if os.path.exists(path) else os.getcwd()
    name = ctx.string(doc, "name", "top level", default=os.path.splitext(os.path.basename(path))[0] or "problem")

    # ---- robot ---------------------------------------------------------------------------
    rob = ctx.table(doc, "robot", "top level", required=True)
    ctx.keys(rob, {"name", "file", "floating_base", "package_dirs", "strict"}, "[robot]")
    fb = ctx.string(rob, "floating_base", "[robot]", choices=("free", "planar"))
    strict = bool(strict) or ctx.boolean(rob, "strict", "[robot]")
    pdirs = rob.get("package_dirs", [])
    if isinstance(pdirs, str):
        pdirs = [pdirs]
    if not isinstance(pdirs, list) or not all(isinstance(d, str) for d in pdirs):
        raise ctx.err("[robot] package_dirs", f"expected a directory or a list of directories, got {pdirs!r}")
    pdirs = [os.fspath(d) for d in package_dirs] + [d if os.path.isabs(d) else os.path.join(base, d) for d in pdirs]
    for d in pdirs:
        if not os.path.isdir(d):
            raise ctx.err("[robot] package_dirs", f"{d!r} is not a directory")
    if ("name" in rob) == ("file" in rob):
        raise ctx.err("[robot]", "give exactly one of 'name' (a shipped robot: "
                      f"{', '.join(cs.robots.names())}) or 'file' (a URDF or MJCF path)")
    try:
        if "name" in rob:
            rname = ctx.string(rob, "name", "[robot]")
            if rname not in cs.robots.REGISTRY:
                raise ctx.err("[robot] name", f"no shipped robot named {rname!r}; shipped robots: "
                              f"{cs.robots.names()}")
            if fb is not None:
                raise ctx.err("[robot] floating_base", "only for URDF files (shipped robots come with their base)")
            model = cs.robots.get(rname)
        else:
            rfile = ctx.string(rob, "file", "[robot]")
            full = rfile if os.path.isabs(rfile) else os.path.join(base, rfile)
            if not os.path.exists(full):
                raise ctx.err("[robot] file", f"{rfile!r} not found (looked for {full})")
            low = full.lower()
            check = "strict" if strict else "warn"
            if low.endswith(".urdf"):
                model = cs.load_urdf(full, floating_base=fb, package_dirs=pdirs, inertia_check=check)
            elif low.endswith(".xml") or low.endswith(".mjcf"):
                if fb is not None:
                    raise ctx.err("[robot] floating_base", "only for URDF files (MJCF files declare their joints)")
                model = cs.load_mjcf(full, inertia_check=check, strict=strict)
            else:
                raise ctx.err("[robot] file", f"{rfile!r}: unknown robot file type (expected .urdf or .xml)")
    except ProblemFileError:
        raise
    except CstormError as e:
        raise ctx.err("[robot]", str(e)) from None
    joints = list(model.joint_names)

    # ---- environment and contact -----------------------------------------------------------
    env = contact = None
    if "environment" in doc:
        env = _environment(ctx, ctx.table(doc, "environment", "top level"), cs)
        if "contact" not in doc:
            raise ctx.err("top level", "[environment] needs a [contact] table (stiffness, damping, d_on, d_off)")
        contact = _contact(ctx, ctx.table(doc, "contact", "top level"), cs)
    elif "contact" in doc:
        raise ctx.err("[contact]", "contact parameters without an [environment] (add obstacles, e.g. a ground)")

    # ---- motion ----------------------------------------------------------------------------
    mot = ctx.table(doc, "motion", "top level", required=True)
    W = "[motion]"
    ctx.keys(mot, {"active", "t_final", "dt", "n_ctrl", "integrator", "q0", "v0", "q_final_active",
                   "v_final_active", "rest_start", "rest_end", "params", "initial_guess", "n_path_samples",
                   "jacobian", "q_bound", "v_bound", "shooting"}, W)
    if "active" not in mot:
        raise ctx.err(W, "missing key 'active' (the names of the actuated joints)")
    active = ctx.names(mot["active"], f"{W} active", joints)
    t_final = ctx.number(mot, "t_final", W, required=True, positive=True)
    dt = ctx.number(mot, "dt", W, required=True, positive=True)
    if dt > t_final:
        raise ctx.err(f"{W} dt", f"must be <= t_final ({t_final}), got {dt}")
    n_ctrl = ctx.number(mot, "n_ctrl", W, required=True, integer=True)
    if n_ctrl < 6:
        raise ctx.err(f"{W} n_ctrl", f"must be an integer >= 6 (quintic B-spline), got {n_ctrl}")
    integrator = ctx.string(mot, "integrator", W, default="rk4", choices=("rk4", "euler"))
    params = {}
    for k, v in ctx.table(mot, "params", W).items():
        params[k] = ctx.numbers(v, f"{W} params.{k}")
        if not isinstance(v, list):
            params[k] = float(params[k][0])
    q0 = _state(ctx, mot.get("q0"), model, "q", f"{W} q0")
    v0 = _state(ctx, mot.get("v0"), model, "v", f"{W} v0")
    qfa = _active_values(ctx, mot, "q_final_active", active, W)
    vfa = _active_values(ctx, mot, "v_final_active", active, W)
    guess = None
    if "initial_guess" in mot:
        guess = {}
        for j, g in ctx.table(mot, "initial_guess", W).items():
            w = f"{W} initial_guess.{j}"
            ctx.names(j, w, active, "active joint")
            if not isinstance(g, dict) or set(g) != {"t", "q"}:
                raise ctx.err(w, "expected a table {t = [...], q = [...]} (times in s, positions)")
            ts, qs = ctx.numbers(g["t"], f"{w}.t"), ctx.numbers(g["q"], f"{w}.q")
            if ts.shape != qs.shape or len(ts) < 2:
                raise ctx.err(w, f"t and q must have the same length >= 2, got {len(ts)} and {len(qs)}")
            guess[j] = (ts, qs)

    # ---- costs and constraints -------------------------------------------------------------
    cost_terms = [_cost(ctx, c, k, joints, params, C) for k, c in enumerate(_array(ctx, doc, "cost"))]
    cons_terms = [_constraint(ctx, c, k, joints, params, K) for k, c in enumerate(_array(ctx, doc, "constraint"))]

    # ---- success criteria --------------------------------------------------------------------
    crit = []
    for k, c in enumerate(_array(ctx, doc, "criterion")):
        try:
            check_criteria_spec(c, model, where=f"[[criterion]] #{k + 1}")
        except CstormError as e:
            raise ProblemFileError(f"{path}: {e}") from None
        crit.append(dict(c))

    # ---- solver -----------------------------------------------------------------------------
    sol = ctx.table(doc, "solver", "top level")
    W = "[solver]"
    ctx.keys(sol, {"method", "max_iter", "tol", "constraint_tol", "continuation", "schedule", "options"}, W)
    opts = {}
    if "method" in sol:
        opts["method"] = ctx.string(sol, "method", W, choices=("slsqp", "trust-constr", "ipopt"))
    if "max_iter" in sol:
        opts["max_iter"] = ctx.number(sol, "max_iter", W, integer=True, positive=True)
    for k in ("tol", "constraint_tol"):
        if k in sol:
            opts[k] = ctx.number(sol, k, W, positive=True)
    if "continuation" in sol:
        cont = {}
        for k, v in ctx.table(sol, "continuation", W).items():
            if k not in params:
                raise ctx.err(f"{W} continuation.{k}", f"not a parameter of [motion] params ({sorted(params)})")
            if not isinstance(v, list) or not v:
                raise ctx.err(f"{W} continuation.{k}", "expected a non-empty array of values")
            cont[k] = [ctx.numbers(x, f"{W} continuation.{k}") if isinstance(x, list) else
                       float(ctx.numbers(x, f"{W} continuation.{k}")[0]) for x in v]
        if len({len(v) for v in cont.values()}) > 1:
            raise ctx.err(f"{W} continuation", "all arrays must have the same length (one stage per entry)")
        opts["continuation"] = cont
    if "schedule" in sol:
        sch = sol["schedule"]
        if not isinstance(sch, list) or not all(isinstance(s, dict) for s in sch):
            raise ctx.err(f"{W} schedule", "expected an array of tables {params = {...}, level = k}")
        out = []
        for i, s in enumerate(sch):
            w = f"{W} schedule[{i}]"
            ctx.keys(s, {"params", "level"}, w)
            sp = {}
            for k, v in ctx.table(s, "params", w).items():
                if k not in params:
                    raise ctx.err(f"{w} params.{k}", f"not a parameter of [motion] params ({sorted(params)})")
                a = ctx.numbers(v, f"{w} params.{k}")
                sp[k] = a if isinstance(v, list) else float(a[0])
            out.append(dict(params=sp, level=ctx.number(s, "level", w, integer=True, nonneg=True, default=0)))
        opts["schedule"] = out
    if "options" in sol:
        opts["options"] = ctx.table(sol, "options", W)

    try:
        prob = MotionProblem(model, active, t_final, int(n_ctrl), dt, q0, v0, env=env, contact=contact,
                             q_final_active=qfa, v_final_active=vfa,
                             rest_end=ctx.boolean(mot, "rest_end", "[motion]"),
                             rest_start=ctx.boolean(mot, "rest_start", "[motion]"), costs=cost_terms or None,
                             constraints=cons_terms, params=params, integrator=integrator,
                             n_path_samples=int(ctx.number(mot, "n_path_samples", "[motion]", default=50,
                                                           integer=True, positive=True)),
                             initial_guess=guess,
                             shooting=int(ctx.number(mot, "shooting", "[motion]", default=1, integer=True,
                                                     positive=True)),
                             jacobian=ctx.string(mot, "jacobian", "[motion]", default="auto",
                                                 choices=("auto", "fwd", "rev")),
                             q_bound=ctx.number(mot, "q_bound", "[motion]", default=1e4, positive=True),
                             v_bound=ctx.number(mot, "v_bound", "[motion]", default=1e4, positive=True),
                             name=name, success_criteria=crit or None)
    except ProblemFileError:
        raise
    except CstormError as e:
        raise ProblemFileError(f"{path}: the problem is ill-posed: {e}") from None
    prob.solve_options.update(opts)
    if "schedule" in opts and "continuation" in opts:
        raise ctx.err(W, "give either continuation or schedule, not both")
    return prob


# ---------------------------------------------------------------------------------------
# Pieces
# ---------------------------------------------------------------------------------------
def _array(ctx, doc, key):
    v = doc.get(key, [])
    if isinstance(v, dict):
        v = [v]
    if not isinstance(v, list) or not all(isinstance(x, dict) for x in v):
        raise ctx.err(f"[[{key}]]", f"expected an array of tables ([[{key}]] entries), got {_tname(v)}")
    return v


def _state(ctx, spec, model, kind, where):
    """q0 / v0: None (neutral / zeros), a full list, or a table joint -> value(s)."""
    n = model.nq if kind == "q" else model.nv
    base = np.asarray(model.neutral(), float) if kind == "q" else np.zeros(model.nv)
    if spec is None:
        return base
    if isinstance(spec, list):
        return ctx.numbers(spec, where, length=n)
    if not isinstance(spec, dict):
        raise ctx.err(where, f"expected a table {{joint = value}} or an array of {n} numbers, got {spec!r}")
    out = base.copy()
    for j, v in spec.items():
        if j not in model.joint_names:
            raise ctx.err(f"{where}.{j}", f"no joint named {j!r}; joints are {list(model.joint_names)}")
        sl = model.joint_q(j) if kind == "q" else model.joint_v(j)
        out[sl] = ctx.numbers(v, f"{where}.{j}", length=sl.stop - sl.start)
    return out


def _active_values(ctx, mot, key, active, where):
    if key not in mot:
        return None
    v = mot[key]
    w = f"{where} {key}"
    if isinstance(v, dict):
        ctx.names(list(v), w, active, "active joint")
        missing = [a for a in active if a not in v]
        if missing:
            raise ctx.err(w, f"missing values for active joints {missing}")
        return {j: float(ctx.numbers(x, f"{w}.{j}", length=1)[0]) for j, x in v.items()}
    return list(ctx.numbers(v, w, length=len(active)))


_OBSTACLES = {
    "ground": ({"height", "normal"}, set()),
    "incline": ({"angle", "axis", "height"}, {"angle"}),
    "box": ({"half_extents", "position"}, {"half_extents"}),
    "platform": ({"height", "center", "size", "depth"}, {"height"}),
    "step": ({"height", "x", "length", "width"}, {"height"}),
    "sphere": ({"radius", "center"}, {"radius"}),
}


def _environment(ctx, d, cs):

    ctx.keys(d, {"obstacle", "pairs", "self_collision", "cylinder_rim_points"}, "[environment]")
    obs = []
    items = _array(ctx, d, "obstacle")
    if not items:
        raise ctx.err("[environment]", "no obstacles: add [[environment.obstacle]] entries (e.g. type = \"ground\")")
    for k, o in enumerate(items):
        w = f"[[environment.obstacle]] #{k + 1}"
        t = ctx.string(o, "type", w, required=True, choices=tuple(_OBSTACLES))
        allowed, required = _OBSTACLES[t]
        ctx.keys(o, allowed | {"type", "name"}, f"{w} ({t})")
        for r in sorted(required):
            if r not in o:
                raise ctx.err(f"{w} ({t})", f"missing key {r!r}")
        kw = {}
        for key in allowed & set(o):
            v = o[key]
            if isinstance(v, list):
                kw[key] = ctx.numbers(v, f"{w} ({t}) {key}")
            else:
                kw[key] = ctx.number(o, key, f"{w} ({t})")
        kw["name"] = ctx.string(o, "name", w, default=t if t not in [x.name for x in obs] else f"{t}{k}")
        try:
            obs.append(getattr(E, t)(**kw))
        except (CstormError, TypeError, ValueError) as e:
            raise ctx.err(f"{w} ({t})", str(e)) from None
    pairs = d.get("pairs")
    sc = d.get("self_collision")
    for key, v in (("pairs", pairs), ("self_collision", sc)):
        if v is not None and not (isinstance(v, list) and all(
                isinstance(p, list) and len(p) == 2 and all(isinstance(s, str) for s in p) for p in v)):
            raise ctx.err(f"[environment] {key}", f"expected an array of [name, name] pairs, got {v!r}")
    try:
        return cs.Environment(obs, pairs=[tuple(p) for p in pairs] if pairs is not None else None,
                              self_collision=[tuple(p) for p in sc] if sc is not None else None,
                              cylinder_rim_points=int(ctx.number(d, "cylinder_rim_points", "[environment]", default=8,
                                                                 integer=True)))
    except CstormError as e:
        raise ctx.err("[environment]", str(e)) from None


_CONTACT_KEYS = {"stiffness", "damping", "d_on", "d_off", "friction", "v_max", "eps", "pulling"}


def _contact_params(ctx, d, where, cs, base=None):
    kw = dict(base or {})
    for k in _CONTACT_KEYS & set(d):
        kw[k] = ctx.boolean(d, k, where) if k == "pulling" else ctx.number(d, k, where)
    missing = [k for k in ("stiffness", "damping", "d_on", "d_off") if k not in kw]
    if missing:
        raise ctx.err(where, f"missing key(s) {missing}")
    try:
        return cs.ContactParams(**kw), kw
    except CstormError as e:
        raise ctx.err(where, str(e)) from None


def _contact(ctx, d, cs):
    ctx.keys(d, _CONTACT_KEYS | {"pair"}, "[contact]")
    default, kw = _contact_params(ctx, {k: v for k, v in d.items() if k != "pair"}, "[contact]", cs)
    pairs = _array(ctx, d, "pair")
    if not pairs:
        return default
    out = {}
    for k, p in enumerate(pairs):
        w = f"[[contact.pair]] #{k + 1}"
        ctx.keys(p, _CONTACT_KEYS | {"geom", "obstacle"}, w)
        key = (ctx.string(p, "geom", w, required=True), ctx.string(p, "obstacle", w, required=True))
        out[key] = _contact_params(ctx, {kk: v for kk, v in p.items() if kk not in ("geom", "obstacle")}, w, cs,
                                   base=kw)[0]
    out[("*", "*")] = default
    return out


_COSTS = {
    "torque_squared": ({"weight", "joints"}, set()),
    "power": ({"weight", "joints"}, set()),
    "state_target": ({"joint", "q", "v", "weight", "weight_v"}, {"joint"}),
    "com_target": ({"target", "weight", "axes"}, {"target"}),
}


def _entry_type(ctx, c, where, table):
    """``(type, where)`` of a ``[[cost]]`` or ``[[constraint]]`` entry: its ``type`` among
    ``table``'s, its keys checked against the type's allowed and required ones."""
    t = ctx.string(c, "type", where, required=True, choices=tuple(table))
    allowed, required = table[t]
    where = f"{where} ({t})"
    ctx.keys(c, allowed | {"type"}, where)
    for r in sorted(required):
        if r not in c:
            raise ctx.err(where, f"missing key {r!r}")
    return t, where


def _cost(ctx, c, k, joints, params, C):
    t, w = _entry_type(ctx, c, f"[[cost]] #{k + 1}", _COSTS)
    weight = ctx.value_or_param(c.get("weight", 1.0), f"{w} weight", params)
    if t in ("torque_squared", "power"):
        js = ctx.names(c["joints"], f"{w} joints", joints) if "joints" in c else None
        return (C.TorqueSquared if t == "torque_squared" else C.Power)(weight=weight, joints=js)
    if t == "state_target":
        j = ctx.names(c["joint"], f"{w} joint", joints)[0]
        if "q" not in c and "v" not in c and "a" not in c:
            raise ctx.err(w, "give q, v and/or a")
        q = ctx.value_or_param(c["q"], f"{w} q", params) if "q" in c else None
        v = ctx.value_or_param(c["v"], f"{w} v", params) if "v" in c else None
        wv = ctx.value_or_param(c["weight_v"], f"{w} weight_v", params) if "weight_v" in c else None
        return C.StateTarget(j, q=q, v=v, weight=weight, weight_v=wv)
    target = ctx.value_or_param(c["target"], f"{w} target", params)
    if not isinstance(target, str) and np.shape(target) != (3,):
        raise ctx.err(f"{w} target", "expected 3 numbers (x, y, z in m) or a parameter name")
    axes = c.get("axes", [0, 1, 2])
    if not (isinstance(axes, list) and axes and all(isinstance(a, int) and 0 <= a <= 2 for a in axes)):
        raise ctx.err(f"{w} axes", f"expected a list of axis indices 0 (x), 1 (y), 2 (z), got {axes!r}")
    return C.CoMTarget(target, weight=weight, axes=axes)


_CONSTRAINTS = {
    "terminal_state": ({"joint", "q", "v", "a", "kind", "tol", "stage", "name"}, {"joint"}),
    "joint_limits": ({"joints", "position", "velocity", "stage", "name"}, set()),
    "torque_limits": ({"limits", "joints", "stage", "name", "factor", "dense", "rho"}, set()),
}


def _constraint(ctx, c, k, joints, params, K):
    t, w = _entry_type(ctx, c, f"[[constraint]] #{k + 1}", _CONSTRAINTS)
    stage = ctx.number(c, "stage", w, default=0, integer=True, nonneg=True)
    name = ctx.string(c, "name", w)
    if t == "terminal_state":
        j = ctx.names(c["joint"], f"{w} joint", joints)[0]
        if "q" not in c and "v" not in c and "a" not in c:
            raise ctx.err(w, "give q, v and/or a")
        kind = ctx.string(c, "kind", w, default="eq", choices=("eq", "ineq"))
        tol = ctx.value_or_param(c.get("tol", 0.0), f"{w} tol", params)
        if kind == "ineq" and "tol" not in c:
            raise ctx.err(w, "kind = \"ineq\" needs tol (|error| <= tol)")
        q = ctx.value_or_param(c["q"], f"{w} q", params) if "q" in c else None
        v = ctx.value_or_param(c["v"], f"{w} v", params) if "v" in c else None
        a = ctx.value_or_param(c["a"], f"{w} a", params) if "a" in c else None
        return K.TerminalState(j, q=q, v=v, a=a, kind=kind, tol=tol, stage=stage, name=name)
    if t == "joint_limits":
        js = ctx.names(c["joints"], f"{w} joints", joints) if "joints" in c else None
        return K.JointLimits(js, position=ctx.boolean(c, "position", w, True),
                             velocity=ctx.boolean(c, "velocity", w, True), stage=stage, name=name)
    js = ctx.names(c["joints"], f"{w} joints", joints) if "joints" in c else None
    lim = ctx.value_or_param(c["limits"], f"{w} limits", params) if "limits" in c else None
    factor = ctx.value_or_param(c.get("factor", 1.0), f"{w} factor", params)
    rho = ctx.number(c, "rho", w, default=200.0, positive=True)
    return K.TorqueLimits(lim, joints=js, stage=stage, name=name, factor=factor, dense=ctx.boolean(c, "dense", w, False),
                          rho=rho)
