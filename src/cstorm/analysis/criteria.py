"""Success criteria of a solved problem or sequence.

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
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..errors import ProblemError
from ..io.files import json_safe
from .segments import problem_segments, segment_solutions

__all__ = ["Criterion", "check_criteria_spec", "evaluate_criteria", "all_criteria"]


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
            out[str(k)] = {kk: (bool(vv) if kk == "ok" else json_safe(vv)) for kk, vv in v.items()}
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
