"""Cost terms of a motion problem: ``J = Psi(terminal) + integral of L dt`` (the draft's
"Generating Motions"; DESIGN.md item 5).

A cost term has a running part ``running(ctx, t, q, v, a, tau, contact) -> scalar``
(integrated by the rollout's integrator, as the third component of the ODE state) and/or
a terminal part ``terminal(ctx, end) -> scalar``. ``ctx`` is the `EvalContext` (model,
layout, problem parameters); ``end`` holds the final state ``q, v, a, tau`` (full model
vectors, SI units). Numbers given as strings name problem parameters (``params=`` of
`MotionProblem`), so continuation can ramp them without recompiling.

Ready-made terms: `TorqueSquared` (the paper's default), `Power`, `StateTarget`
(passive-state or base-pose targets, manifold-aware), `CoMTarget`, and `RunningCost` /
`TerminalCost` for user JAX callables; `LandingPenalty` (a floating base's landing at
rest, as a penalty).
"""

from __future__ import annotations

import numpy as np
import jax.numpy as jnp

from ..dynamics.energy import center_of_mass
from ..errors import ProblemError

__all__ = ["Cost", "TorqueSquared", "Power", "StateTarget", "CoMTarget", "RunningCost", "TerminalCost",
           "LandingPenalty", "resolve", "joint_dofs", "joint_error", "jsonable"]


def resolve(value, params):
    """A number, array, or the name of a problem parameter -> a JAX array."""
    if isinstance(value, str):
        if value not in params:
            raise ProblemError(f"unknown problem parameter {value!r}; parameters are {sorted(params)}")
        return jnp.asarray(params[value])
    return jnp.asarray(value)


class Cost:
    """Base class. Subclasses override `running` and/or `terminal` (return None when
    they have no such part) and may override `check(problem)` (eager validation)."""

    weight = 1.0

    def check(self, problem):
        pass

    def running(self, ctx, t, q, v, a, tau, contact):
        return None

    def terminal(self, ctx, end):
        return None

    def describe(self) -> dict:
        return {"type": type(self).__name__}


def joint_dofs(problem, joints, default):
    """(k,) int: the velocity indices of ``joints`` (a joint name or a list of them) in
    ``problem.model``, or ``default`` when ``joints`` is None. Raises `ProblemError` for
    an unknown name."""
    if joints is None:
        return np.array(default, dtype=int)
    if isinstance(joints, str):
        joints = [joints]
    idx = []
    for n in joints:
        if n not in problem.model.joint_names:
            raise ProblemError(f"cost: no joint named {n!r}; joints are {list(problem.model.joint_names)}")
        s = problem.model.joint_v(n)
        idx += list(range(s.start, s.stop))
    return np.array(idx, dtype=int)


class TorqueSquared(Cost):
    """Running cost ``weight * 1/2 sum tau_i^2`` (N^2 m^2 s) over the motor torques of the
    active joints (or of the named ``joints``): the draft's default ``1/2 |psi|^2`` with
    ``psi = tau_a``."""

    def __init__(self, weight=1.0, joints=None):
        self.weight, self.joints = weight, joints

    def check(self, problem):
        self._idx = joint_dofs(problem, self.joints, problem.layout.va_idx)

    def running(self, ctx, t, q, v, a, tau, contact):
        x = tau[self._idx]
        return 0.5 * resolve(self.weight, ctx.params) * jnp.sum(x * x)

    def describe(self):
        return {"type": "TorqueSquared", "weight": self.weight, "joints": self.joints}


class Power(Cost):
    """Running cost ``weight * 1/2 sum (tau_i v_i)^2`` over the active joints (or the named
    ``joints``): squared mechanical power, smooth (W^2 s)."""

    def __init__(self, weight=1.0, joints=None):
        self.weight, self.joints = weight, joints

    def check(self, problem):
        self._idx = joint_dofs(problem, self.joints, problem.layout.va_idx)

    def running(self, ctx, t, q, v, a, tau, contact):
        p = tau[self._idx] * v[self._idx]
        return 0.5 * resolve(self.weight, ctx.params) * jnp.sum(p * p)

    def describe(self):
        return {"type": "Power", "weight": self.weight, "joints": self.joints}


def joint_error(model, joint, qj, target):
    """Tangent-space error of one joint's configuration ``qj`` from ``target`` (both in
    the joint's q coordinates): ``difference(target, qj)`` (nv of the joint,)."""
    i = model.joint_names.index(joint)
    return model.joints[i].difference(target, qj)


class StateTarget(Cost):
    """Terminal cost ``weight/2 (|q_err|^2 + |v_err|^2)`` pulling joint ``joint`` to a
    target position ``q`` (rad or m; a (7,) pose ``[x y z qw qx qy qz]`` for a free joint,
    error measured on the manifold) and/or velocity ``v``. ``q``/``v`` may name problem
    parameters. ``weight_v`` weights the velocity part (default ``weight``)."""

    def __init__(self, joint, q=None, v=None, weight=1.0, weight_v=None):
        self.joint, self.q, self.v, self.weight = joint, q, v, weight
        self.weight_v = weight if weight_v is None else weight_v

    def check(self, problem):
        if self.joint not in problem.model.joint_names:
            raise ProblemError(f"StateTarget: no joint named {self.joint!r}")
        if self.q is None and self.v is None:
            raise ProblemError(f"StateTarget({self.joint!r}): give q and/or v")

    def terminal(self, ctx, end):
        m = ctx.model
        out = 0.0
        if self.q is not None:
            e = joint_error(m, self.joint, end["q"][m.joint_q(self.joint)], resolve(self.q, ctx.params).reshape(-1))
            out = out + 0.5 * resolve(self.weight, ctx.params) * jnp.sum(e * e)
        if self.v is not None:
            e = end["v"][m.joint_v(self.joint)] - resolve(self.v, ctx.params).reshape(-1)
            out = out + 0.5 * resolve(self.weight_v, ctx.params) * jnp.sum(e * e)
        return out

    def describe(self):
        return {"type": "StateTarget", "joint": self.joint, "q": jsonable(self.q), "v": jsonable(self.v),
                "weight": self.weight}


class CoMTarget(Cost):
    """Terminal cost ``weight/2 sum_{i in axes} (com_i - target_i)^2`` on the centre of
    mass (world frame, m); ``target`` (3,) may name a problem parameter."""

    def __init__(self, target, weight=1.0, axes=(0, 1, 2)):
        self.target, self.weight, self.axes = target, weight, tuple(axes)

    def terminal(self, ctx, end):
        c = center_of_mass(ctx.model, end["q"])
        e = (c - resolve(self.target, ctx.params))[np.array(self.axes, int)]
        return 0.5 * resolve(self.weight, ctx.params) * jnp.sum(e * e)

    def describe(self):
        return {"type": "CoMTarget", "target": jsonable(self.target), "weight": self.weight, "axes": self.axes}


class RunningCost(Cost):
    """User running cost ``weight * fn(t, q, v, a, tau, params)`` (a JAX callable
    returning a scalar; ``params``: the problem-parameter dict)."""

    def __init__(self, fn, weight=1.0):
        self.fn, self.weight = fn, weight

    def running(self, ctx, t, q, v, a, tau, contact):
        return resolve(self.weight, ctx.params) * self.fn(t, q, v, a, tau, ctx.params)

    def describe(self):
        return {"type": "RunningCost", "fn": getattr(self.fn, "__name__", repr(self.fn))}


class TerminalCost(Cost):
    """User terminal cost ``weight * fn(q, v, params)`` (a JAX callable, scalar)."""

    def __init__(self, fn, weight=1.0):
        self.fn, self.weight = fn, weight

    def terminal(self, ctx, end):
        return resolve(self.weight, ctx.params) * self.fn(end["q"], end["v"], ctx.params)

    def describe(self):
        return {"type": "TerminalCost", "fn": getattr(self.fn, "__name__", repr(self.fn))}


def jsonable(x):
    """A term's number, array or parameter name as JSON data (for ``describe``): None,
    str, int, float and bool as they are, anything else a nested list of floats."""
    if x is None or isinstance(x, (str, int, float, bool)):
        return x
    return np.asarray(x, dtype=float).tolist()


class LandingPenalty(Cost):
    """Terminal cost ``weight/2 (|q_b(T) - q_rest|^2 + |v_p(T)|^2)`` over the base DoFs
    ``joints`` (1-DoF joints, default ``root_z, root_pitch``: m, rad; ``q_rest``: a dict
    joint name -> rest position) and every passive velocity (m/s, rad/s): the landing at
    rest as a penalty, for the first stages of a solve, before `constraints.AtRest` and
    the terminal base pose become constraints (SLSQP's linearized landing constraints
    throw a robot that has not yet learnt to hop far from its guess). ``weight`` may name
    a problem parameter (units of the cost per m^2)."""

    def __init__(self, weight, q_rest, joints=("root_z", "root_pitch")):
        self.weight, self.q_rest, self.joints = weight, {k: float(v) for k, v in q_rest.items()}, tuple(joints)

    def check(self, problem):
        m = problem.model
        self._qi = np.array([m.joint_q(n).start for n in self.joints], int)
        self._qr = np.array([self.q_rest[n] for n in self.joints])
        self._vp = np.array(problem.layout.vp_idx, int)

    def terminal(self, ctx, end):
        e = end["q"][self._qi] - self._qr
        v = end["v"][self._vp]
        return 0.5 * resolve(self.weight, ctx.params) * (jnp.sum(e * e) + jnp.sum(v * v))

    def describe(self):
        return {"type": "LandingPenalty", "weight": self.weight, "q_rest": self.q_rest, "joints": list(self.joints)}
