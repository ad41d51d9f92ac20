"""Constraint terms of a motion problem.

Conventions: equality constraints are ``c(x) = 0``; inequality constraints ``c(x) >= 0``
(scipy's convention). A term returns a 1-D array of values from either the final state
(``end``: dict ``q, v, a, tau``) or the trajectory sampled on the problem's constraint
grid (``samples``: dict ``t (S,)``, ``q (S, nq)``, ``v, a, tau (S, nv)``; the grid is
every ``stride``-th integration step, ``S ~ n_path_samples`` points including both ends;
``samples["steps"]``: ``t, q, v, a, tau`` on every step, ``(N+1, ...)``).
Numbers given as strings name problem parameters.

**Staged constraints.** Every term has a ``stage`` (int, default 0): `solve` can switch
terms on in stages (terms with ``stage <= level`` are enforced at level ``level``),
warm-starting each stage from the last. All terms are always evaluated (one compiled
function per problem); switched-off ones are simply not passed to the solver.

Ready-made: `JointLimits` (position and velocity limits from the model, sampled),
`TorqueLimits` (motor torques, sampled, or on every step with ``dense=True``), `TerminalState` (passive states or base pose at
``t_final``, equality or bounds), `ContactDistance` (contact points clear of the
obstacles in a time window, e.g. a flight phase), `Periodic` (final state = start
state, for gait cycles with ``MotionProblem(free_initial=...)``), `AverageSpeed`,
`TerminalConstraint` and `PathConstraint` (user JAX callables). For robots that leave
the ground: `FlightClearance` and `SwingClearance` (a flight or swing phase somewhere in
the motion, no schedule), `AtRest` (the floating base ends at rest), `ForwardDistance`,
`PitchBound`, `ScaledTorqueLimits` (motor limits as O(1) ratios) and `SlipPower` (no
skating).
"""

from __future__ import annotations

import fnmatch

import numpy as np
import jax
import jax.numpy as jnp
from jax.scipy.special import logsumexp

from ..contact import Environment, contact_forces, contact_labels, ground
from ..errors import ProblemError
from .costs import joint_dofs, joint_error, jsonable, resolve

__all__ = ["Constraint", "JointLimits", "TorqueLimits", "window_index", "ks_max", "TerminalState", "ContactDistance",
           "Periodic", "AverageSpeed", "TerminalConstraint", "PathConstraint", "soft_clearance",
           "sampled_contact_distances", "FlightClearance", "SwingClearance", "AtRest", "ForwardDistance", "PitchBound",
           "ScaledTorqueLimits", "SlipPower"]


class Constraint:
    """Base class. ``kind``: ``"eq"`` or ``"ineq"`` (``>= 0``). Subclasses implement
    ``values(ctx, end, samples) -> (k,)`` and may override ``check(problem)``."""

    kind = "eq"
    stage = 0
    name = None
    #: whether ``values`` reads ``samples["steps"]`` (every integration step): when no term
    #: does, the rollout records the constraint grid only (cheaper derivatives)
    uses_steps = False
    #: how ``method="ddp"`` evaluates the term (`cstorm.optimize.ddp_problem`): ``"path"``
    #: (at every node, `point_values`), ``"end"`` (at the final node: ``values`` with the
    #: start state as the only sample), ``"box"`` (bounds on the controls,
    #: `TorqueLimits.control_bounds`) or None (the term reads the whole trajectory at once)
    ddp = None

    def check(self, problem):
        pass

    def point_values(self, ctx, point):
        """The term's values at one instant, for ``ddp = "path"``: ``point`` is a dict
        ``t`` (s), ``q (nq,)``, ``v, a, tau (nv,)`` and ``contact`` (that instant's
        contact data, or None). Default: ``values`` on a one-sample trajectory."""
        one = {k: (None if point.get(k) is None else
                   jax.tree_util.tree_map(lambda y: jnp.asarray(y)[None], point[k]))
               for k in ("t", "q", "v", "a", "tau", "contact")}
        if one["contact"] is None:
            del one["contact"]
        return self.values(ctx, None, one)

    def node_mask(self, problem):
        """(N+1,) bool: the grid points where a ``"path"`` term holds (default: all)."""
        return np.ones(problem.n_steps + 1, bool)

    def values(self, ctx, end, samples):
        raise NotImplementedError

    def label(self):
        return self.name or type(self).__name__

    def describe(self) -> dict:
        return {"type": type(self).__name__, "kind": self.kind, "stage": self.stage}


def _set_common(obj, kind, stage, name):
    if kind not in ("eq", "ineq"):
        raise ProblemError(f"{type(obj).__name__}: kind must be 'eq' or 'ineq', got {kind!r}")
    obj.kind, obj.stage, obj.name = kind, int(stage), name


class JointLimits(Constraint):
    """Position limits ``q_lower <= q <= q_upper`` and velocity limits ``|v| <=
    velocity_limit`` from the model (finite entries only) of 1-DoF ``joints`` (default:
    all 1-DoF joints), sampled on the constraint grid. Inequalities."""

    kind = "ineq"
    ddp = "path"

    def __init__(self, joints=None, position=True, velocity=True, stage=0, name=None):
        self.joints, self.position, self.velocity = joints, position, velocity
        _set_common(self, "ineq", stage, name)

    def check(self, problem):
        m = problem.model
        names = self.joints if self.joints is not None else m.joint_names
        if isinstance(names, str):
            names = [names]
        lo, hi = np.asarray(m.q_lower), np.asarray(m.q_upper)
        vl = np.asarray(m.velocity_limit)
        ql, qu, vi = [], [], []
        for n in names:
            if n not in m.joint_names:
                raise ProblemError(f"JointLimits: no joint named {n!r}")
            i = m.joint_names.index(n)
            if m.joints[i].nq != 1:
                if self.joints is not None:
                    raise ProblemError(f"JointLimits: joint {n!r} is not 1-DoF")
                continue
            qs, vs = m.q_starts[i], m.v_starts[i]
            if self.position and np.isfinite(lo[qs]):
                ql.append(qs)
            if self.position and np.isfinite(hi[qs]):
                qu.append(qs)
            if self.velocity and np.isfinite(vl[vs]):
                vi.append(vs)
        self._ql, self._qu, self._vi = (np.array(x, int) for x in (ql, qu, vi))
        if not (len(ql) or len(qu) or len(vi)):
            raise ProblemError("JointLimits: the model has no finite position or velocity limits on these joints")

    def values(self, ctx, end, samples):
        m = ctx.model
        q, v = samples["q"], samples["v"]
        parts = [(q[:, self._ql] - m.q_lower[self._ql]).ravel(), (m.q_upper[self._qu] - q[:, self._qu]).ravel(),
                 (m.velocity_limit[self._vi] - v[:, self._vi]).ravel(),
                 (m.velocity_limit[self._vi] + v[:, self._vi]).ravel()]
        return jnp.concatenate(parts)

    def describe(self):
        return {"type": "JointLimits", "joints": self.joints, "stage": self.stage}


def window_index(sample_idx, n_steps):
    """The integration steps ``0..n_steps`` split into one window per constraint-grid
    sample: window ``k`` holds steps ``sample_idx[k] <= i < sample_idx[k+1]`` (the last
    window: the last sample alone). Returns an int array ``(S, L)``, ``L`` the longest
    window, shorter windows padded by repeating their first step (a repeat changes neither
    the max nor, by more than ``ln(L) / rho``, a `ks_max`)."""
    idx = np.asarray(sample_idx, int)
    bounds = np.append(idx, n_steps + 1)
    lens = np.diff(bounds)
    L = int(lens.max())
    W = np.empty((len(idx), L), int)
    for k, (a, n) in enumerate(zip(idx, lens)):
        W[k, :n] = np.arange(a, a + n)
        W[k, n:] = a
    return W


def ks_max(g, rho, axis):
    """Kreisselmeier-Steinhauser smooth maximum ``logsumexp(rho g) / rho`` along ``axis``:
    smooth (C-infinity), never below the true max and at most ``ln(n) / rho`` above it (``n``
    the entries along ``axis``). Stable for any ``rho g`` (logsumexp shifts by the max)."""
    return jax.nn.logsumexp(rho * g, axis=axis) / rho


class TorqueLimits(Constraint):
    """``|tau_i| <= factor * limit_i`` for the motor torques of the active joints (or the
    named ``joints``); ``limits``: scalar, (k,) or None (the model's ``effort_limit``);
    ``factor`` (a number or a problem parameter's name, default 1) lets a solve plan start
    with the limits relaxed and tighten them to 1. Inequalities, ``2 S k`` values: the
    upper then the lower bounds, sample-major, in N m, or with ``normalized=True``
    dimensionless (``factor - tau_i / limit_i``: O(1) like the other constraints', which
    SLSQP needs next to metre- and radian-sized terms; a 200 N m motor's raw values made it
    report "inequality constraints incompatible").

    ``dense=False``: the torques on the constraint grid only (``S ~ n_path_samples``
    samples). A contact impact between two samples can then need several times the limit
    for a few ms (2.9x on the tumbler's roll with 42 samples).
    ``dense=True``: every integration step counts. The steps are split into one window per
    grid sample (`window_index`) and each window's ``+tau/limit`` and ``-tau/limit`` enter
    through a smooth maximum (`ks_max` with sharpness ``rho``, default 200): the same ``2 S
    k`` values, never below the true worst step's, at most ``ln(L)/rho`` of the limit
    above it (``L`` steps per window: 1.2 % for 12 steps). So a motion that satisfies the
    dense constraints is within ``factor * limit`` on every step, exactly, and what
    `cstorm.report.torque_check` reads agrees."""

    kind = "ineq"
    ddp = "box"

    def __init__(self, limits=None, joints=None, stage=0, name=None, factor=1.0, normalized=False, dense=False,
                 rho=200.0):
        self.limits, self.joints = limits, joints
        self.factor, self.normalized, self.dense, self.rho = factor, bool(normalized), bool(dense), float(rho)
        if not self.rho > 0:
            raise ProblemError(f"TorqueLimits: rho must be positive, got {rho!r}")
        _set_common(self, "ineq", stage, name)

    def check(self, problem):
        self._idx = joint_dofs(problem, self.joints, problem.layout.va_idx)
        if self.limits is None:
            lim = np.asarray(problem.model.effort_limit)[self._idx]
            if not np.all(np.isfinite(lim)):
                raise ProblemError("TorqueLimits: the model's effort_limit is infinite for some of these joints; "
                                   "pass limits=")
        self._windows = window_index(problem.sample_idx, problem.n_steps) if self.dense else None

    @property
    def uses_steps(self):
        return self.dense

    def control_bounds(self, problem, params):
        """``(lb, ub)``, each (N+1, n_active) N m: the limits as bounds on the DDP's
        motor-torque controls (``-inf``/``inf`` for active joints this term does not
        limit). Raises `ProblemError` if the term limits a passive DoF."""
        va = list(problem.layout.va_idx)
        bad = [int(i) for i in self._idx if int(i) not in va]
        if bad:
            names = [n for n in problem.model.joint_names
                     if set(range(problem.model.joint_v(n).start, problem.model.joint_v(n).stop)) & set(bad)]
            raise ProblemError(f"TorqueLimits: method='ddp' bounds motor torques, and {names} are passive")
        lim = np.asarray(problem.model.effort_limit)[self._idx] if self.limits is None else \
            np.broadcast_to(np.asarray(resolve(self.limits, params), float), (len(self._idx),))
        f = float(np.asarray(resolve(self.factor, params)))
        n = problem.n_steps + 1
        lb, ub = np.full((n, len(va)), -np.inf), np.full((n, len(va)), np.inf)
        for i, lim_i in zip(self._idx, lim):
            k = va.index(int(i))
            lb[:, k], ub[:, k] = -f * lim_i, f * lim_i
        return lb, ub

    def ratios(self, samples, lim):
        """``(hi, lo)``, each ``(S, k)``: per sample the largest ``tau/lim`` and ``-tau/lim``
        (the sample itself, or its window's smooth max with ``dense``)."""
        if self.dense:
            r = samples["steps"]["tau"][:, self._idx][self._windows] / lim  # (S, L, k)
            return ks_max(r, self.rho, axis=1), ks_max(-r, self.rho, axis=1)
        r = samples["tau"][:, self._idx] / lim
        return r, -r

    def values(self, ctx, end, samples):
        lim = ctx.model.effort_limit[self._idx] if self.limits is None else \
            jnp.broadcast_to(resolve(self.limits, ctx.params), (len(self._idx),))
        f = resolve(self.factor, ctx.params)
        if self.normalized or self.dense:
            hi, lo = self.ratios(samples, lim)
            up, dn = f - hi, f - lo  # factor - |tau| / limit
            if not self.normalized:
                up, dn = lim * up, lim * dn
        else:  # N m, computed as factor limit -/+ tau
            tau = samples["tau"][:, self._idx]
            up, dn = f * lim - tau, f * lim + tau
        return jnp.concatenate([up.ravel(), dn.ravel()])

    def describe(self):
        d = {"type": "TorqueLimits", "limits": jsonable(self.limits), "joints": self.joints, "stage": self.stage}
        # only when used: hashes of earlier problems stay the same
        if self.factor != 1.0:
            d["factor"] = jsonable(self.factor)
        if self.normalized:
            d["normalized"] = True
        if self.dense:
            d.update(dense=True, rho=self.rho)
        return d


class TerminalState(Constraint):
    """Final state of joint ``joint``: position ``q`` (a free joint's (7,) pose, error on
    the manifold), velocity ``v`` and/or acceleration ``a`` (the joint's ``nv`` entries of
    the trajectory's ``a`` at ``t_final``: for a passive joint, what the dynamics gives at
    the final state; ``a=0`` with ``v=0`` asks for a state of rest *at equilibrium*, one
    the robot keeps, not one it passes through). ``kind="eq"`` (default): ``q(T) = q``,
    ``v(T) = v``, ``a(T) = a``. ``kind="ineq"`` with ``tol``: ``|error| <= tol``
    componentwise. Values (and ``tol``) may name problem parameters. Order of the values:
    position, velocity, acceleration parts (those given)."""

    ddp = "end"

    def __init__(self, joint, q=None, v=None, a=None, kind="eq", tol=0.0, stage=0, name=None):
        self.joint, self.q, self.v, self.a, self.tol = joint, q, v, a, tol
        _set_common(self, kind, stage, name)

    def check(self, problem):
        if self.joint not in problem.model.joint_names:
            raise ProblemError(f"TerminalState: no joint named {self.joint!r}; joints are "
                               f"{list(problem.model.joint_names)}")
        if self.q is None and self.v is None and self.a is None:
            raise ProblemError(f"TerminalState({self.joint!r}): give q, v and/or a")

    def values(self, ctx, end, samples):
        m = ctx.model
        errs = []
        if self.q is not None:
            errs.append(joint_error(m, self.joint, end["q"][m.joint_q(self.joint)],
                                    resolve(self.q, ctx.params).reshape(-1)))
        if self.v is not None:
            errs.append(end["v"][m.joint_v(self.joint)] - resolve(self.v, ctx.params).reshape(-1))
        if self.a is not None:
            errs.append(end["a"][m.joint_v(self.joint)] - resolve(self.a, ctx.params).reshape(-1))
        e = jnp.concatenate(errs)
        if self.kind == "eq":
            return e
        tol = resolve(self.tol, ctx.params)
        return jnp.concatenate([tol - e, tol + e])

    def label(self):
        return self.name or f"TerminalState({self.joint})"

    def describe(self):
        d = {"type": "TerminalState", "joint": self.joint, "q": jsonable(self.q), "v": jsonable(self.v),
             "kind": self.kind, "stage": self.stage}
        if self.a is not None:  # only when used: problem hashes of earlier problems stay the same
            d["a"] = jsonable(self.a)
        return d


class ContactDistance(Constraint):
    """Contact points clear of the obstacles: ``d_i(t) >= min_distance`` (m) for every
    contact point ``i`` whose robot geom matches one of ``geoms`` (glob patterns, default
    all points) at every constraint-grid sample with ``window[0] <= t <= window[1]`` (s;
    default the whole motion). Inequalities: the values ``d_i(t) - min_distance``, shape
    ``(n_samples_in_window * n_points,)``, sample-major. ``min_distance`` may name a
    problem parameter (continuation can ramp it).

    ``d`` is the signed distance of `cstorm.contact_forces` (per feature: capsule end
    spheres, box corners, ...). With ``min_distance >= d_on`` of the contact parameters
    the contact force is exactly zero in the window: a flight phase. Needs a problem with
    ``env`` and ``contact``. Between samples the constraint is not enforced (the grid has
    ``n_path_samples`` points).

    ``max_distance`` (m, or a parameter's name; default None) adds the opposite bound
    ``max_distance - d_i(t) >= 0`` (after the lower bounds): contact points kept loaded,
    e.g. a foot kept flat on the ground (``max_distance < d_on``: every point of the foot
    carries force and stays off the ``d_on`` end of the force ramp, where the force law is
    only C1, so the motion depends smoothly on the controls). ``min_distance=None`` with a
    ``max_distance`` gives the upper bound alone."""

    kind = "ineq"
    ddp = "path"

    def __init__(self, min_distance=None, window=None, geoms=None, stage=0, name=None, max_distance=None):
        if min_distance is None and max_distance is None:
            raise ProblemError("ContactDistance: give min_distance, max_distance or both")
        self.min_distance, self.max_distance = min_distance, max_distance
        self.window = None if window is None else (float(window[0]), float(window[1]))
        self.geoms = [geoms] if isinstance(geoms, str) else (None if geoms is None else list(geoms))
        _set_common(self, "ineq", stage, name)

    def check(self, problem):
        if problem.env is None:
            raise ProblemError("ContactDistance: the problem has no environment (MotionProblem(env=..., contact=...))")
        if self.window is not None:
            a, b = self.window
            if not (np.isfinite(a) and np.isfinite(b) and 0.0 <= a <= b <= problem.t_final):
                raise ProblemError(f"ContactDistance: window must satisfy 0 <= start <= end <= t_final="
                                   f"{problem.t_final:g} s, got {self.window}")
        labels = contact_labels(problem.model, problem.env)
        if self.geoms is None:
            pts = list(range(len(labels)))
        else:
            pts = [i for i, lab in enumerate(labels) if any(fnmatch.fnmatchcase(lab[0], g) for g in self.geoms)]
        if not pts:
            raise ProblemError(f"ContactDistance: no contact point of geoms {self.geoms}; the contact points "
                               f"belong to geoms {sorted({lab[0] for lab in labels})}")
        self._pts = np.array(pts, int)

    def values(self, ctx, end, samples):
        p = ctx.problem
        t = p.t[p.sample_idx]
        if self.window is None:
            rows = np.arange(len(t))
        else:
            rows = np.nonzero((t >= self.window[0] - 1e-12) & (t <= self.window[1] + 1e-12))[0]
            if not len(rows):
                raise ProblemError(f"ContactDistance: no constraint-grid sample lies in the window {self.window} s "
                                   f"(samples every {t[1] - t[0]:.4g} s); widen it or raise n_path_samples")
        d = samples["contact"].d[rows][:, self._pts]
        out = []
        if self.min_distance is not None:
            out.append((d - resolve(self.min_distance, ctx.params)).ravel())
        if self.max_distance is not None:
            out.append((resolve(self.max_distance, ctx.params) - d).ravel())
        return jnp.concatenate(out)

    def point_values(self, ctx, point):
        d = point["contact"].d[self._pts]
        out = []
        if self.min_distance is not None:
            out.append(d - resolve(self.min_distance, ctx.params))
        if self.max_distance is not None:
            out.append(resolve(self.max_distance, ctx.params) - d)
        return jnp.concatenate(out)

    def node_mask(self, problem):
        t = np.asarray(problem.t)
        if self.window is None:
            return np.ones(len(t), bool)
        return (t >= self.window[0] - 1e-12) & (t <= self.window[1] + 1e-12)

    def label(self):
        return self.name or "ContactDistance"

    def describe(self):
        out = {"type": "ContactDistance", "min_distance": jsonable(self.min_distance), "window": self.window,
               "geoms": self.geoms, "stage": self.stage}
        if self.max_distance is not None:
            out["max_distance"] = jsonable(self.max_distance)
        return out


class Periodic(Constraint):
    """The motion ends where it started: ``q_j(T) = q_j(0)`` for every joint ``j`` except
    those in ``exclude`` (e.g. ``("root_x",)``: a walker ends one stride ahead) and
    ``v_j(T) = v_j(0)`` for every joint except those in ``exclude_velocity`` (default
    none: an excluded position's velocity is still periodic). With ``swap`` (pairs of joint names, e.g. ``[("hip_l", "hip_r"),
    ...]``) the end state of each joint of a pair equals the start state of the other (a
    mirror-symmetric half cycle of a planar biped: one step, left and right exchanged);
    the joints of a pair must have the same type. ``which``: ``"q"``, ``"v"`` or ``"qv"``
    (default). Equalities, ``kind="eq"``; values: position errors on the manifold
    (``difference(q_partner(0), q_j(T))``, rad or m) then velocity errors (rad/s, m/s), joint
    by joint in model order. ``velocity_scale`` (s) multiplies the velocity errors.

    The start state is the trajectory's first sample, so with
    ``MotionProblem(free_initial=...)`` it is the optimized start state. Without free
    start variables a periodic motion at nonzero speed cannot be found by single
    shooting from a fixed start."""

    def __init__(self, exclude=(), swap=None, which="qv", velocity_scale=1.0, exclude_velocity=(), stage=0,
                 name=None):
        self.exclude = (exclude,) if isinstance(exclude, str) else tuple(exclude)
        self.exclude_velocity = (exclude_velocity,) if isinstance(exclude_velocity, str) else tuple(exclude_velocity)
        self.swap = None if swap is None else [tuple(p) for p in swap]
        if which not in ("q", "v", "qv"):
            raise ProblemError(f"Periodic: which must be 'q', 'v' or 'qv', got {which!r}")
        self.which, self.velocity_scale = which, float(velocity_scale)
        _set_common(self, "eq", stage, name)

    def check(self, problem):
        m = problem.model
        for n in self.exclude + self.exclude_velocity:
            if n not in m.joint_names:
                raise ProblemError(f"Periodic: exclude/exclude_velocity names {n!r}, which is not a joint; joints "
                                   f"are {list(m.joint_names)}")
        partner = {n: n for n in m.joint_names}
        for pair in self.swap or []:
            if len(pair) != 2 or any(n not in m.joint_names for n in pair):
                raise ProblemError(f"Periodic: swap entries must be pairs of joint names, got {pair!r}; joints are "
                                   f"{list(m.joint_names)}")
            a, b = pair
            if partner[a] != a or partner[b] != b:
                raise ProblemError(f"Periodic: joint {a!r} or {b!r} appears in more than one swap pair")
            ja, jb = m.joints[m.joint_names.index(a)], m.joints[m.joint_names.index(b)]
            if type(ja) is not type(jb):
                raise ProblemError(f"Periodic: swapped joints {a!r} and {b!r} have different types")
            partner[a], partner[b] = b, a
        self._q_pairs = tuple((n, partner[n]) for n in m.joint_names if n not in self.exclude) \
            if "q" in self.which else ()
        self._v_pairs = tuple((n, partner[n]) for n in m.joint_names if n not in self.exclude_velocity) \
            if "v" in self.which else ()
        if not (self._q_pairs or self._v_pairs):
            raise ProblemError("Periodic: every joint is excluded")

    def values(self, ctx, end, samples):
        m = ctx.model
        q0, v0 = samples["q"][0], samples["v"][0]
        qe = [joint_error(m, j, end["q"][m.joint_q(j)], q0[m.joint_q(p)]) for j, p in self._q_pairs]
        ve = [self.velocity_scale * (end["v"][m.joint_v(j)] - v0[m.joint_v(p)]) for j, p in self._v_pairs]
        return jnp.concatenate(qe + ve)

    def label(self):
        return self.name or "Periodic"

    def describe(self):
        return {"type": "Periodic", "exclude": list(self.exclude), "exclude_velocity": list(self.exclude_velocity),
                "swap": self.swap, "which": self.which,
                "velocity_scale": self.velocity_scale, "stage": self.stage}


class AverageSpeed(Constraint):
    """Average speed along a 1-DoF joint (the planar base's ``root_x`` by default):
    ``(q_j(T) - q_j(0)) / t_final = speed`` (m/s or rad/s; ``speed`` may name a problem
    parameter, so continuation can ramp it). ``kind="eq"`` (default) or ``"ineq"`` (at
    least ``speed``). One value, m/s."""

    ddp = "end"

    def __init__(self, speed, joint="root_x", kind="eq", stage=0, name=None):
        self.speed, self.joint = speed, joint
        _set_common(self, kind, stage, name)

    def check(self, problem):
        m = problem.model
        if self.joint not in m.joint_names:
            raise ProblemError(f"AverageSpeed: no joint named {self.joint!r}; joints are {list(m.joint_names)}")
        if m.joints[m.joint_names.index(self.joint)].nq != 1:
            raise ProblemError(f"AverageSpeed: joint {self.joint!r} is not 1-DoF")
        self._i = m.joint_q(self.joint).start

    def values(self, ctx, end, samples):
        T = ctx.problem.t_final
        avg = (end["q"][self._i] - samples["q"][0, self._i]) / T
        return jnp.atleast_1d(avg - resolve(self.speed, ctx.params))

    def label(self):
        return self.name or f"AverageSpeed({self.joint})"

    def describe(self):
        return {"type": "AverageSpeed", "speed": jsonable(self.speed), "joint": self.joint, "kind": self.kind,
                "stage": self.stage}


class TerminalConstraint(Constraint):
    """User terminal constraint ``fn(q, v, params) -> (k,)`` at ``t_final`` (``= 0`` for
    ``kind="eq"``, ``>= 0`` for ``"ineq"``)."""

    ddp = "end"

    def __init__(self, fn, kind="eq", stage=0, name=None):
        self.fn = fn
        _set_common(self, kind, stage, name)

    def values(self, ctx, end, samples):
        return jnp.atleast_1d(self.fn(end["q"], end["v"], ctx.params)).ravel()


class PathConstraint(Constraint):
    """User path constraint ``fn(t, q, v, a, tau, params) -> (k,)`` evaluated (vmapped) at
    every sample of the constraint grid (``>= 0`` by default; ``kind="eq"`` for ``= 0``)."""

    ddp = "path"

    def __init__(self, fn, kind="ineq", stage=0, name=None):
        self.fn = fn
        _set_common(self, kind, stage, name)

    def values(self, ctx, end, samples):
        f = lambda t, q, v, a, tau: jnp.atleast_1d(self.fn(t, q, v, a, tau, ctx.params))
        return jax.vmap(f)(samples["t"], samples["q"], samples["v"], samples["a"], samples["tau"]).ravel()


# ---------------------------------------------------------------------------------------
# Terms for robots that leave the ground: flight and swing phases without a schedule, the
# floating base's landing, distance and tilt, normalized motor limits, no skating
# ---------------------------------------------------------------------------------------
def soft_clearance(d, tau_points, tau_time):
    """Smooth "highest clearance reached": ``tau_time logsumexp_s(c_s / tau_time)`` with
    ``c_s = -tau_points logsumexp_k(-d_sk / tau_points)`` (a smooth min over the contact
    points at sample ``s``). ``d``: (S, k) signed distances, m; returns a scalar, m. The
    smooth min is at most ``tau_points ln k`` below the true min; the smooth max at most
    ``tau_time ln S`` above the true max (about ``tau_time ln n`` when ``n`` samples are
    near the top)."""
    c = -tau_points * logsumexp(-d / tau_points, axis=1)
    return tau_time * logsumexp(c / tau_time)


def sampled_contact_distances(ctx, samples):
    """(S, k) signed contact distances (m) at the constraint-grid samples: the rollout's
    contact data when the samples carry it, else recomputed from the sampled states with
    `cstorm.contact_forces` (the problem's ``env`` and ``contact``)."""
    c = samples.get("contact")
    if c is not None and hasattr(c, "d"):
        return c.d
    p = ctx.problem
    return jax.vmap(lambda q, v: contact_forces(ctx.model, p.env, p.contact, q, v).d)(samples["q"], samples["v"])


class FlightClearance(Constraint):
    """A flight phase, without saying when: at some sample of the constraint grid every
    contact point is at least ``clearance`` (m, or a problem-parameter name) above the
    obstacles, through the smooth max-over-time of the smooth min-over-points of the
    contact distances (`soft_clearance`, sharpness ``tau_points`` and ``tau_time``, m).
    One inequality ``scale (soft_clearance - clearance) >= 0`` (``scale`` 1/m, default
    100: the value in cm, so that its sensitivities are of the order of the other
    constraints'). Needs a problem with contact (``env``/``contact``); the distances are
    `sampled_contact_distances`. The term reads the whole trajectory at once (``ddp =
    None``)."""

    kind = "ineq"

    def __init__(self, clearance, tau_points=1e-3, tau_time=2e-3, scale=100.0, stage=0, name="flight"):
        self.clearance, self.tau_points, self.tau_time = clearance, float(tau_points), float(tau_time)
        self.scale = float(scale)
        self.stage, self.name = int(stage), name

    def values(self, ctx, end, samples):
        if ctx.problem.env is None:  # (MotionProblem runs check() before it stores env)
            raise ProblemError("FlightClearance: the problem has no environment/contact model")
        peak = soft_clearance(sampled_contact_distances(ctx, samples), self.tau_points, self.tau_time)
        return jnp.atleast_1d(self.scale * (peak - resolve(self.clearance, ctx.params)))

    def describe(self):
        return {"type": "FlightClearance", "clearance": self.clearance, "tau_points": self.tau_points,
                "tau_time": self.tau_time, "scale": self.scale, "stage": self.stage}


class SwingClearance(Constraint):
    """Every foot swings: for each group of robot geoms (``groups``: a list of lists of
    geom names, e.g. ``[["foot_r_geom"], ["foot_l_geom"]]``), at some sample of the
    constraint grid all the group's contact points are at least ``clearance`` (m, or a
    problem-parameter name) above the obstacles. No schedule: the instant is not given.
    Per group, `soft_clearance` of the group's columns of `sampled_contact_distances`
    (sharpness ``tau_points``, ``tau_time``, m). One inequality per group, in group order:
    ``soft_clearance - clearance >= 0`` (m). Without an ``env`` the points are those
    against the ground. The term reads the whole trajectory at once (``ddp = None``)."""

    kind = "ineq"

    def __init__(self, groups, clearance, tau_points=1e-3, tau_time=2e-3, stage=0, name="swing"):
        self.groups = [[g] if isinstance(g, str) else list(g) for g in groups]
        self.clearance, self.tau_points, self.tau_time = clearance, float(tau_points), float(tau_time)
        self.kind, self.stage, self.name = "ineq", int(stage), name

    def check(self, problem):
        env = problem.env if problem.env is not None else Environment([ground()])
        labels = contact_labels(problem.model, env)
        self._idx = []
        for g in self.groups:
            pts = [i for i, lab in enumerate(labels) if lab[0] in g]
            if not pts:
                raise ProblemError(f"SwingClearance: no contact points on geoms {g}; geoms with contact points: "
                                   f"{sorted({lab[0] for lab in labels})}")
            self._idx.append(np.array(pts, int))

    def values(self, ctx, end, samples):
        d = sampled_contact_distances(ctx, samples)
        peaks = [soft_clearance(d[:, idx], self.tau_points, self.tau_time) for idx in self._idx]
        return jnp.stack(peaks) - resolve(self.clearance, ctx.params)

    def describe(self):
        return {"type": "SwingClearance", "groups": self.groups, "clearance": self.clearance,
                "tau_points": self.tau_points, "tau_time": self.tau_time, "stage": self.stage}


class AtRest(Constraint):
    """The passive DoFs (the floating base) end at rest: ``v_p(T) = 0`` and, with
    ``acceleration=True``, ``a_p(T) = 0`` (so the final state is a static equilibrium, not
    the turning point of a bounce); ``2 n_passive`` equalities (m/s, rad/s, m/s^2, rad/s^2;
    accelerations multiplied by ``accel_scale`` s), velocities first. With ``tol`` (a
    number or a problem parameter's name) they become the inequalities ``|value| <= tol``
    instead, as ``(tol - e, tol + e)`` (a landing tolerance that a solve plan can tighten:
    switching on equalities that are far from satisfied makes SLSQP take radian-sized
    steps); ``accel_tol`` (likewise) gives the accelerations their own tolerance, ``|a_p|
    <= accel_tol`` (m/s^2, rad/s^2; the values still multiplied by ``accel_scale``), values
    ``(tol - v, tol + v, s (accel_tol - a), s (accel_tol + a))``. Evaluated at the final
    node by DDP (``ddp = "end"``)."""

    kind = "eq"
    ddp = "end"

    def __init__(self, acceleration=True, accel_scale=0.1, tol=None, stage=0, name="at_rest", accel_tol=None):
        self.acceleration, self.accel_scale, self.tol = bool(acceleration), float(accel_scale), tol
        self.accel_tol = accel_tol
        if accel_tol is not None and (tol is None or not self.acceleration):
            raise ProblemError("AtRest: accel_tol needs acceleration=True and a velocity tol")
        self.kind = "eq" if tol is None else "ineq"
        self.stage, self.name = int(stage), name

    def check(self, problem):
        self._vp = np.array(problem.layout.vp_idx, int)
        if not len(self._vp):
            raise ProblemError("AtRest: the problem has no passive DoFs")

    def values(self, ctx, end, samples):
        v = end["v"][self._vp]
        if self.accel_tol is not None:
            tv, ta = resolve(self.tol, ctx.params), resolve(self.accel_tol, ctx.params)
            a = end["a"][self._vp]
            return jnp.concatenate([tv - v, tv + v, self.accel_scale * (ta - a), self.accel_scale * (ta + a)])
        out = [v]
        if self.acceleration:
            out.append(self.accel_scale * end["a"][self._vp])
        e = jnp.concatenate(out)
        if self.tol is None:
            return e
        tol = resolve(self.tol, ctx.params)
        return jnp.concatenate([tol - e, tol + e])

    def describe(self):
        d = {"type": "AtRest", "acceleration": self.acceleration, "accel_scale": self.accel_scale,
             "tol": self.tol, "stage": self.stage}
        if self.accel_tol is not None:  # only when used: earlier problems' hashes stay the same
            d["accel_tol"] = self.accel_tol
        return d


def _q_start(problem, joint, who):
    """The first configuration index of ``joint``; `ProblemError` (prefixed ``who``) if the
    model has no such joint."""
    if joint not in problem.model.joint_names:
        raise ProblemError(f"{who}: no joint named {joint!r}")
    return problem.model.joint_q(joint).start


class ForwardDistance(Constraint):
    """The motion covers a distance: ``scale (q_j(T) - q_j(0) - distance) >= 0`` for the
    prismatic base joint ``joint`` (default ``root_x``; ``distance`` in m, a
    problem-parameter name allowed; ``scale`` 1/m, default 10). One inequality. Evaluated
    at the final node by DDP (``ddp = "end"``)."""

    kind = "ineq"
    ddp = "end"

    def __init__(self, distance, joint="root_x", scale=10.0, stage=0, name="forward"):
        self.distance, self.joint, self.scale = distance, joint, float(scale)
        self.stage, self.name = int(stage), name

    def check(self, problem):
        self._i = _q_start(problem, self.joint, "ForwardDistance")

    def values(self, ctx, end, samples):
        return jnp.atleast_1d(self.scale * (end["q"][self._i] - samples["q"][0, self._i]
                                            - resolve(self.distance, ctx.params)))

    def describe(self):
        return {"type": "ForwardDistance", "distance": self.distance, "joint": self.joint, "stage": self.stage}


class PitchBound(Constraint):
    """``|q_j - center| <= bound`` for the base's pitch joint ``joint`` (default
    ``root_pitch``; ``center`` and ``bound`` rad, ``bound`` may name a problem parameter)
    on the constraint grid: keeps the robot from tipping over during the motion (and gives
    the optimizer a gradient against falling long before the end). ``2 S`` inequalities,
    ``(bound - e, bound + e)`` over the ``S`` samples. Evaluated at every node by DDP
    (``ddp = "path"``)."""

    kind = "ineq"
    ddp = "path"

    def __init__(self, bound, joint="root_pitch", center=0.0, stage=0, name="pitch_bound"):
        self.bound, self.joint, self.center = bound, joint, float(center)
        self.stage, self.name = int(stage), name

    def check(self, problem):
        self._i = _q_start(problem, self.joint, "PitchBound")

    def values(self, ctx, end, samples):
        e = samples["q"][:, self._i] - self.center
        b = resolve(self.bound, ctx.params)
        return jnp.concatenate([b - e, b + e])

    def describe(self):
        return {"type": "PitchBound", "bound": self.bound, "joint": self.joint, "center": self.center,
                "stage": self.stage}


class ScaledTorqueLimits(TorqueLimits):
    """``factor - |tau_i| / limit_i >= 0`` for the active joints' motors (the model's
    effort limits, which must be finite): `TorqueLimits` with ``normalized=True``,
    dimensionless values of order 1 like the other constraints' (SLSQP reports
    "inequality constraints incompatible" with raw N m values of a 200 N m motor), ``2 S
    n_active`` inequalities. ``factor`` (a number or a problem parameter's name, default
    1) lets a solve plan start with the limits relaxed and tighten them to 1.
    ``dense=True``: on every integration step, through a smooth max (sharpness ``rho``)
    per window of the constraint grid (see `TorqueLimits`), not only on the grid. Bounds
    on the controls for DDP (``ddp = "box"``)."""

    def __init__(self, factor=1.0, stage=0, name="torque_limits", dense=False, rho=200.0):
        super().__init__(stage=stage, name=name, normalized=True, dense=dense, rho=rho, factor=factor)

    def check(self, problem):
        lim = np.asarray(problem.model.effort_limit)[np.array(problem.layout.va_idx, int)]
        if not np.all(np.isfinite(lim)):
            raise ProblemError("ScaledTorqueLimits: the model's effort_limit is infinite for some active joints")
        super().check(problem)

    def describe(self):  # its own type name: the hashes of earlier problems stay the same
        d = {"type": "ScaledTorqueLimits", "stage": self.stage}
        if self.factor != 1.0:
            d["factor"] = self.factor
        if self.dense:
            d.update(dense=True, rho=self.rho)
        return d


class SlipPower(Constraint):
    """No skating: at every constraint-grid sample, the contacts' sliding power ``sum_k
    N_k sqrt(|v_t,k|^2 + v_eps^2)`` (W; ``N_k`` the normal force magnitude, N, ``v_t,k``
    the tangential velocity of contact point ``k``, m/s; ``v_eps`` m/s smooths the norm at
    zero slip) is at most ``limit`` (W, or a problem-parameter name). ``S`` inequalities,
    ``limit - power``. Needs the rollout's contact data at the samples. A stance foot's
    penalty friction creeps at ~1 cm/s under body weight (~3 W); a skimming swing foot at
    1 m/s under 40 N is 40 W. The term reads the whole trajectory at once (``ddp =
    None``)."""

    kind = "ineq"

    def __init__(self, limit, v_eps=1e-3, stage=0, name="slip power"):
        self.limit, self.v_eps, self.stage, self.name, self.kind = limit, float(v_eps), int(stage), name, "ineq"

    def values(self, ctx, end, samples):
        c = samples["contact"]
        v, n = c.velocity, c.n
        vt = v - jnp.sum(v * n, axis=-1, keepdims=True) * n
        speed = jnp.sqrt(jnp.sum(vt * vt, axis=-1) + self.v_eps ** 2)
        return resolve(self.limit, ctx.params) - jnp.sum(c.normal_magnitude * speed, axis=-1)

    def describe(self):
        return {"type": "SlipPower", "limit": self.limit, "v_eps": self.v_eps, "stage": self.stage}
