"""Argument validation at the boundary of the dynamics functions.

Shapes are static under `jit`, so they are always checked (at trace time). Values (unit
quaternions, finiteness) are checked only when concrete (eager calls)."""

from __future__ import annotations

import numpy as np
import jax.numpy as jnp

from .._pytree import is_concrete
from ..errors import InputError
from ..model.joints import Ball, Free


def vec(model, x, size, argname, fn):
    if x is None:
        raise InputError(f"{fn}: {argname} is required")
    x = jnp.asarray(x)
    if x.shape != (size,):
        raise InputError(f"{fn}: {argname} must have shape ({size},) for model {model.name!r}, got {x.shape}")
    return x


def config(model, q, fn, argname="q"):
    q = vec(model, q, model.nq, argname, fn)
    if model.has_quaternions() and is_concrete(q):
        qn = np.asarray(q)
        for name, j, s in zip(model.joint_names, model.joints, model.q_starts):
            if isinstance(j, (Free, Ball)):
                quat = qn[s + 3: s + 7] if isinstance(j, Free) else qn[s: s + 4]
                nrm = np.linalg.norm(quat)
                if not abs(nrm - 1.0) < 1e-6:
                    raise InputError(
                        f"{fn}: {argname}[{model.joint_q(name).start}:{model.joint_q(name).stop}] of joint {name!r} "
                        f"holds a quaternion of norm {nrm:.6g}; it must be unit (w, x, y, z). "
                        "Use cs.normalize(model, q)."
                    )
    return q


def fext(model, f_ext, fn):
    if f_ext is None:
        return None
    f_ext = jnp.asarray(f_ext)
    if f_ext.shape != (model.n_bodies, 6):
        raise InputError(f"{fn}: f_ext must have shape ({model.n_bodies}, 6) [torque about world origin; force], "
                         f"got {f_ext.shape}")
    return f_ext


def active(model, active, fn):
    a = tuple(bool(x) for x in active)
    if len(a) != model.nv:
        raise InputError(f"{fn}: active must be a tuple of nv={model.nv} bools, got length {len(a)}")
    return a


_active = active  # (`hybrid_inputs` takes an argument of the same name)


def hybrid_inputs(model, q, v, a_active, tau_passive, active, f_ext, fn):
    """Checked ``(q, v, a_active, tau_passive, active, f_ext)`` of a hybrid-dynamics call
    (or one of its derivatives) named ``fn`` in the errors."""
    active = _active(model, active, fn)
    q = config(model, q, fn)
    v = vec(model, v, model.nv, "v", fn)
    na = sum(active)
    a_active = vec(model, a_active, na, "a_active", fn)
    tau_passive = vec(model, tau_passive, model.nv - na, "tau_passive", fn)
    f_ext = fext(model, f_ext, fn)
    return q, v, a_active, tau_passive, active, f_ext
