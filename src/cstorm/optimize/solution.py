"""The result of `cstorm.solve`: a `Solution`, saved as one ``.npz`` file (arrays plus a
JSON metadata string; no pickle) with an atomic write, and read back by `load_solution`.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import os
from typing import Any

import numpy as np
import jax

from ..errors import InputError
from ..io.files import atomic_savez

__all__ = ["Solution", "Status", "load_solution", "atomic_savez", "contact_dict"]

_TRAJ_KEYS = ("t", "q", "v", "a", "tau")
_SCALARS = ("problem", "success", "status", "message", "cost", "constraint_violation", "iterations", "wall_time_s",
            "compile_time_s", "n_evaluations")


class Status(str, enum.Enum):
    """Why a solve stopped (`Solution.status`); branch on this, never on the message."""

    SOLVED = "solved"                # the solver converged and the constraints hold
    SOLVER_FAILED = "solver_failed"  # the solver stopped without converging (iteration limit, line search, ...)
    INFEASIBLE = "infeasible"        # the solver converged, but the violation exceeds constraint_tol
    DIVERGED = "diverged"            # the final motion's rollout diverged; the last sound stage end is returned
    INTERRUPTED = "interrupted"      # KeyboardInterrupt (Ctrl-C or a callback); the best iterate is returned
    NOT_SOLVED = "not_solved"        # no solve was run (an initial guess written as a motion)


@dataclasses.dataclass
class Solution:
    """A solved (or stopped) motion problem.

    Attributes:
      success: bool, the solver converged and the constraints hold (violation <= tol).
      status: `Status`, why the solve stopped (``Status.SOLVED`` exactly when
        ``success``). message: the same in words, with the solver's own message.
      cost: objective at ``x``. constraint_violation: ``max(|c_eq|, max(0, -c_in))`` over
        the enforced constraints at ``x``. iterations: solver iterations (all stages).
      x: (n_vars,) decision vector (free spline control points; see `MotionProblem`).
      trajectory: dict with ``t`` (N+1,) s, ``q`` (N+1, nq), ``v``, ``a``, ``tau``
        (N+1, nv) (``tau``: motor torques on active DoFs, spring/damper forces on passive
        ones), ``ctrl`` (n_ctrl, n_active) and, with contact, ``contact``: dict of
        per-point arrays stacked over the grid.
      history: list of per-iteration dicts ``iteration, stage, cost, violation, step,
        time`` (s since the solve started).
      segments: per-segment `Solution` objects (one entry for a single problem; its own
        ``segments`` is empty).
      problem: the problem's name. params: final problem parameters. wall_time_s,
        compile_time_s: timings. info: JSON-able extras (solver options, stages,
        problem description, problem hash, cstorm version).
    """

    success: bool
    message: str
    cost: float
    constraint_violation: float
    iterations: int
    x: np.ndarray
    trajectory: dict
    history: list = dataclasses.field(default_factory=list)
    segments: list = dataclasses.field(default_factory=list)
    problem: str = ""
    params: dict = dataclasses.field(default_factory=dict)
    wall_time_s: float = 0.0
    compile_time_s: float = 0.0
    n_evaluations: int = 0
    info: dict = dataclasses.field(default_factory=dict)
    status: Status = None

    def __post_init__(self):
        if self.status is None:
            self.status = Status.SOLVED if self.success else Status.SOLVER_FAILED
        self.status = Status(self.status)

    def __repr__(self):
        return (f"Solution(problem={self.problem!r}, status={self.status.value}, cost={self.cost:.6g}, "
                f"constraint_violation={self.constraint_violation:.3g}, iterations={self.iterations}, "
                f"message={self.message!r})")

    def summary(self) -> dict:
        """JSON-able summary (no arrays)."""
        out = {k: _py(getattr(self, k)) for k in _SCALARS}
        out["segments"] = [s.summary() for s in self.segments]
        return out

    # ------------------------------------------------------------------ persistence
    def _flatten(self, prefix, arrays):
        meta = {k: _py(getattr(self, k)) for k in _SCALARS}
        meta.update(history=_py(self.history), params=_py(self.params), info=_py(self.info))
        arrays[prefix + "x"] = np.asarray(self.x, dtype=float)
        tkeys = []
        for k, v in self.trajectory.items():
            if v is None:
                continue
            if isinstance(v, dict):
                for kk, vv in _flat_dict(v).items():
                    arrays[f"{prefix}traj/{k}/{kk}"] = np.asarray(vv)
                    tkeys.append(f"{k}/{kk}")
            else:
                arrays[f"{prefix}traj/{k}"] = np.asarray(v)
                tkeys.append(k)
        meta["trajectory_keys"] = tkeys
        meta["n_segments"] = len(self.segments)
        for i, s in enumerate(self.segments):
            meta.setdefault("segment_meta", []).append(s._flatten(f"{prefix}seg{i}/", arrays))
        return meta

    def save(self, path) -> str:
        """Write ``path`` (``.npz`` appended if missing) atomically: arrays plus a JSON
        metadata string. Returns the path written."""
        path = os.fspath(path)
        if not path.endswith(".npz"):
            path += ".npz"
        arrays: dict[str, np.ndarray] = {}
        meta = self._flatten("", arrays)
        meta["format"] = "cstorm-solution-1"
        arrays["meta_json"] = np.array(json.dumps(meta))
        atomic_savez(path, arrays)
        return path


def contact_dict(c):
    """A pytree of contact data (e.g. `cstorm.ContactData` over a trajectory) as a flat
    dict of numpy arrays keyed by the leaves' paths (``"d"``, ``"f_ext"``, nested fields
    joined by ``/``), as `Solution` trajectories store and save it."""
    leaves = jax.tree_util.tree_flatten_with_path(c)[0]
    return {jax.tree_util.keystr(p).strip(".[]'\"").replace("'", "").replace("][", "/") or str(i): np.asarray(v)
            for i, (p, v) in enumerate(leaves)}


def _flat_dict(d, prefix=""):
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flat_dict(v, key + "/"))
        else:
            out[key] = v
    return out


def _unflat(keys_values):
    out: dict = {}
    for k, v in keys_values:
        parts = k.split("/")
        d = out
        for p in parts[:-1]:
            d = d.setdefault(p, {})
        d[parts[-1]] = v
    return out


def _py(x):
    """Convert numpy scalars/arrays inside containers to JSON-able Python values."""
    if isinstance(x, dict):
        return {str(k): _py(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_py(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, enum.Enum):
        return x.value
    if isinstance(x, float) and not np.isfinite(x):
        return float(x)
    return x


def _build(meta, arrays, prefix):
    traj = _unflat((k, arrays[f"{prefix}traj/{k}"]) for k in meta["trajectory_keys"])
    segs = [_build(m, arrays, f"{prefix}seg{i}/") for i, m in enumerate(meta.get("segment_meta", []))]
    return Solution(success=bool(meta["success"]), message=meta["message"], cost=float(meta["cost"]),
                    constraint_violation=float(meta["constraint_violation"]), iterations=int(meta["iterations"]),
                    x=arrays[prefix + "x"], trajectory=traj, history=meta.get("history", []), segments=segs,
                    problem=meta.get("problem", ""), params=meta.get("params", {}),
                    wall_time_s=float(meta.get("wall_time_s", 0.0)),
                    compile_time_s=float(meta.get("compile_time_s", 0.0)),
                    n_evaluations=int(meta.get("n_evaluations", 0)), info=meta.get("info", {}),
                    status=meta.get("status"))


def load_solution(path) -> Solution:
    """Read a `Solution` written by `Solution.save` (no pickle)."""
    path = os.fspath(path)
    if not os.path.exists(path) and os.path.exists(path + ".npz"):
        path += ".npz"
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError) as e:
        raise InputError(f"load_solution: cannot read {path!r}: {e}") from None
    if "meta_json" not in arrays:
        raise InputError(f"load_solution: {path!r} is not a cstorm solution file (no meta_json)")
    meta = json.loads(str(arrays["meta_json"]))
    return _build(meta, arrays, "")
