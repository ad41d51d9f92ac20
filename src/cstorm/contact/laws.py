"""Smooth penalty contact (DESIGN.md, "The method", item 3; the draft's "Contact model,
Normal and Friction Forces", with its gamma'(0) corrected).

Conventions (SI units)
----------------------
- ``d``: signed distance between a robot shape and an obstacle shape, m; ``d < 0`` when
  penetrating.
- ``n``: unit normal ``(..., 3)`` pointing from the obstacle towards the robot (moving
  the robot along ``n`` increases ``d``); the force always pushes the robot out.
- ``v``: world velocity ``(..., 3)`` of the robot's near point ``p_rob`` (m/s), obstacles
  are static; ``v_n = v . n`` (m/s, > 0 when separating), ``v_t = v - v_n n``.
- Normal force ``N = beta(d) * P(k (d_on - d) - c v_n)`` along ``n`` (N), where ``P`` is
  the smooth non-negativity ``P(x) = (x + sqrt(x^2 + eps^2)) / 2`` (default) or the
  draft's ``P(x) = x`` (``pulling=True``: the damper can then pull the robot onto the
  ground and ``|N|`` has a kink where ``N`` changes sign). ``beta`` ramps from 0 at
  ``d_on`` to 1 at ``d_off`` (cubic, zero slope at both ends); since ``P`` sits inside
  ``beta`` the force is exactly zero for ``d >= d_on``. A resting body settles where
  ``N`` balances its weight, at ``d`` below ``d_on``: with ``d_on > 0`` it floats
  (about 3 mm above the ground with ``d_on = 0.01`` in the tumbler study); shift the
  ramp (``d_on = 0``, ``d_off < 0``) to rest at or slightly inside the surface.
- Friction ``f_t = -mu |N| gamma(|v_t|) v_t / |v_t|`` with
  ``gamma(s) = 1.5 s / v_max - 0.5 (s / v_max)^3`` below ``v_max`` and 1 above, computed
  division-free as ``-mu |N| (gamma(s)/s) v_t``. Note ``gamma'(0) = 1.5 / v_max`` (the
  draft's ``gamma'(0) = 1`` is wrong): near zero slip friction is a stiff viscous damper
  with coefficient ``1.5 mu |N| / v_max`` (N s/m); integrator steps must resolve it.
- Every switch (``d_on``, ``d_off``, ``v_max``, zero slip, the sign change of the
  spring-damper argument) is C1: values and first derivatives are continuous and no
  derivative is NaN, at zero slip and zero velocity included.

Layout: smoothing functions, then `ContactParams`, then the force law at one contact
point (`normal_force`, `friction_force`, `point_contact_force`). Contact points and
their assembly into body wrenches: `cstorm.contact.forces`.
"""

from __future__ import annotations

import jax
import numpy as np
import jax.numpy as jnp

from .._pytree import pytree_dataclass, is_concrete
from ..errors import ContactParamError

__all__ = [
    "smooth_nonneg",
    "beta",
    "gamma",
    "gamma_over_s",
    "ContactParams",
    "normal_force",
    "friction_force",
    "point_contact_force",
    "ContactData",
    "contact_forces",
    "contact_labels",
]


# ---------------------------------------------------------------------------------------
# Smoothing functions (pure, elementwise, broadcasting; C1 or better)
# ---------------------------------------------------------------------------------------


def smooth_nonneg(x, eps, pulling: bool = False):
    """Smooth non-negativity ``P(x) = (x + sqrt(x^2 + eps^2)) / 2`` (C-infinity).

    ``P(x) > max(x, 0)``, ``P(x) - max(x, 0) <= eps / 2`` (equality at ``x = 0``),
    ``P'(x) = (1 + x / sqrt(x^2 + eps^2)) / 2`` in ``(0, 1)``. Evaluated without
    cancellation for large ``|x|`` (``eps^2 / (2 (sqrt(x^2 + eps^2) - x))`` for ``x < 0``).

    Args:
      x: any shape, in the units of ``eps`` (N for contact forces).
      eps: ``> 0``, broadcastable with ``x``; the smoothing width.
      pulling: static; ``True`` returns ``x`` unchanged (the draft's form).
    Returns:
      ``P(x)``, shape ``broadcast(x, eps)``.
    """
    x = jnp.asarray(x)
    if pulling:
        return x
    eps2 = jnp.square(eps)
    pos = x >= 0.0
    r = jnp.sqrt(x * x + eps2)
    xn = jnp.where(pos, 0.0, x)  # <= 0, so sqrt(xn^2 + eps^2) - xn >= eps > 0
    neg_branch = eps2 / (2.0 * (jnp.sqrt(xn * xn + eps2) - xn))
    return jnp.where(pos, 0.5 * (x + r), neg_branch)


def beta(d, d_on, d_off):
    """Distance ramp: 0 for ``d >= d_on``, 1 for ``d <= d_off``, ``3 s^2 - 2 s^3`` with
    ``s = (d - d_on) / (d_off - d_on)`` in between (C1: zero slope at both ends).

    Args:
      d: signed distance, m, any shape.
      d_on, d_off: m, ``d_off < d_on``, broadcastable with ``d``.
    Returns:
      ``beta`` in ``[0, 1]``, shape ``broadcast(d, d_on, d_off)``; exactly 0 (with zero
      derivative) for ``d >= d_on``.
    """
    s = jnp.clip((d - d_on) / (d_off - d_on), 0.0, 1.0)
    return s * s * (3.0 - 2.0 * s)


def _gamma_over_s_sq(s2, v_max):
    """``gamma(s)/s`` as a function of ``s^2`` (no square root below ``v_max``, so smooth
    to all orders at zero slip); 1/s above with the root taken of an argument >= v_max^2."""
    v2 = jnp.square(v_max)
    below = s2 < v2
    slow = (3.0 - s2 / v2) / (2.0 * v_max)
    fast = 1.0 / jnp.sqrt(jnp.where(below, v2, s2))
    return jnp.where(below, slow, fast)


def gamma_over_s(s, v_max):
    """Division-free friction factor ``gamma(s)/s`` (1/(m/s)).

    ``(3 - s^2/v_max^2) / (2 v_max)`` for ``s < v_max`` (``1.5/v_max`` at ``s = 0``),
    ``1/s`` for ``s >= v_max``; C1 at ``v_max`` (value ``1/v_max``, slope
    ``-1/v_max^2``); finite value and gradient at ``s = 0``.

    Args:
      s: slip speed ``|v_t| >= 0``, m/s, any shape.
      v_max: m/s, ``> 0``, broadcastable with ``s``.
    """
    s = jnp.asarray(s)
    return _gamma_over_s_sq(s * s, v_max)


def gamma(s, v_max):
    """Friction ramp ``gamma(s) = 1.5 s/v_max - 0.5 (s/v_max)^3`` for ``s < v_max``, 1
    above (dimensionless; C1 at ``v_max``; ``gamma'(0) = 1.5/v_max``).

    Args:
      s: slip speed ``>= 0``, m/s, any shape; v_max: m/s, ``> 0``.
    """
    s = jnp.asarray(s)
    return s * gamma_over_s(s, v_max)


# ---------------------------------------------------------------------------------------
# Contact parameters
# ---------------------------------------------------------------------------------------


def _as_param(value):
    if isinstance(value, jax.core.Tracer):
        return value
    return jnp.asarray(np.asarray(value, dtype=np.float64))


@pytree_dataclass(meta=("pulling",))
class ContactParams:
    """Parameters of the smooth penalty contact law (a JAX pytree).

    Fields (numbers are differentiable array leaves; scalars, or arrays that broadcast
    against the distances they are used with, for per-pair or per-point values):
      stiffness: ``k >= 0``, N/m.
      damping: ``c >= 0``, N s/m.
      d_on: distance at which the force starts, m.
      d_off: distance at which the ramp ``beta`` reaches 1, m; ``d_off < d_on``.
      friction: Coulomb coefficient ``mu >= 0`` (default 0.3, the draft's).
      v_max: slip speed at which friction saturates, m/s, ``> 0`` (default 0.1).
      eps: width of the smooth non-negativity ``P``, N, ``> 0`` (default 0.01).
      pulling: static bool, default False; True uses the draft's ``P(x) = x`` (the
        damper may pull; ``|N|`` in the friction law then has a kink).

    Concrete values are validated on construction; `ContactParamError` (a `ShapeError`)
    names the parameter at fault. Values a JAX transformation passes through are not
    checked. Example (the values that worked in the tumbler study)::

        ContactParams(stiffness=5e3, damping=100.0, d_on=0.01, d_off=0.0, friction=0.8)
    """

    stiffness: jnp.ndarray
    damping: jnp.ndarray
    d_on: jnp.ndarray
    d_off: jnp.ndarray
    friction: jnp.ndarray = 0.3
    v_max: jnp.ndarray = 0.1
    eps: jnp.ndarray = 0.01
    pulling: bool = False

    def __post_init__(self):
        if not isinstance(self.pulling, (bool, np.bool_)):
            raise ContactParamError(f"ContactParams: pulling must be a bool, got {self.pulling!r}")
        object.__setattr__(self, "pulling", bool(self.pulling))
        vals = {}
        for name in self._data_fields:
            v = getattr(self, name)
            if is_concrete(v):
                try:
                    a = np.asarray(v, dtype=float)
                except (TypeError, ValueError):
                    raise ContactParamError(f"ContactParams: {name} must be a number or an array of numbers, got {v!r}") from None
                if not np.all(np.isfinite(a)):
                    raise ContactParamError(f"ContactParams: {name} must be finite, got {a.tolist()}")
                vals[name] = a
            object.__setattr__(self, name, _as_param(v))
        rules = (
            ("stiffness", lambda a: a >= 0, ">= 0 (N/m)"),
            ("damping", lambda a: a >= 0, ">= 0 (N s/m)"),
            ("friction", lambda a: a >= 0, ">= 0"),
            ("v_max", lambda a: a > 0, "> 0 (m/s)"),
            ("eps", lambda a: a > 0, "> 0 (N)"),
        )
        for name, ok, rel in rules:
            if name in vals and not np.all(ok(vals[name])):
                raise ContactParamError(f"ContactParams: {name} must be {rel}, got {vals[name].tolist()}")
        if "d_on" in vals and "d_off" in vals:
            try:
                bad = np.any(np.asarray(vals["d_off"]) >= np.asarray(vals["d_on"]))
            except ValueError:
                raise ContactParamError(
                    f"ContactParams: d_off shape {vals['d_off'].shape} does not broadcast with d_on shape "
                    f"{vals['d_on'].shape}"
                ) from None
            if bad:
                raise ContactParamError(
                    f"ContactParams: d_off must be < d_on (the force ramps from 0 at d_on to full at d_off), "
                    f"got d_off={vals['d_off'].tolist()}, d_on={vals['d_on'].tolist()}"
                )

    def replace(self, **changes) -> "ContactParams":
        """A copy with some fields changed, validated like a new object."""
        kw = {name: getattr(self, name) for name in self._data_fields + self._meta_fields}
        kw.update(changes)
        return ContactParams(**kw)


# ---------------------------------------------------------------------------------------
# Force law at one contact point (pure, broadcasting over leading axes)
# ---------------------------------------------------------------------------------------


def normal_force(d, v_n, params: ContactParams):
    """Magnitude of the normal force along ``n``: ``N = beta(d) P(k (d_on - d) - c v_n)``.

    Args:
      d: signed distance, m, shape ``(...)``.
      v_n: normal velocity ``v . n``, m/s (> 0 separating), broadcastable with ``d``.
      params: `ContactParams`.
    Returns:
      ``N`` in newtons, shape ``broadcast(d, v_n, params)``; ``N >= 0`` unless
      ``params.pulling``; exactly 0 for ``d >= d_on``.
    """
    x = params.stiffness * (params.d_on - d) - params.damping * v_n
    return beta(d, params.d_on, params.d_off) * smooth_nonneg(x, params.eps, params.pulling)


def friction_force(N_mag, v_t, params: ContactParams):
    """Friction force on the robot point, ``-mu |N| (gamma(s)/s) v_t`` with ``s = |v_t|``.

    Opposes the slip; magnitude ``mu |N| gamma(|v_t|)``, which is ``mu |N|`` for
    ``|v_t| >= v_max``; a viscous ``-1.5 mu |N| / v_max * v_t`` near zero slip. No square
    root is taken below ``v_max`` (the factor depends on ``|v_t|^2`` there), so values and
    derivatives of every order are finite at ``v_t = 0``.

    Args:
      N_mag: normal force along ``n`` from `normal_force`, N, shape ``(...)``; its
        absolute value is used (it is ``>= 0`` already unless ``params.pulling``).
      v_t: tangential slip velocity ``(..., 3)``, m/s (``v_t . n = 0``).
      params: `ContactParams` (``friction``, ``v_max`` broadcast against ``(...)``).
    Returns:
      ``(..., 3)``, N, world axes.
    """
    v_t = jnp.asarray(v_t)
    s2 = jnp.sum(v_t * v_t, axis=-1)
    scale = params.friction * jnp.abs(N_mag) * _gamma_over_s_sq(s2, params.v_max)
    return -scale[..., None] * v_t


def point_contact_force(d, n, v, params: ContactParams):
    """Total contact force on a robot point (normal plus friction).

    Args:
      d: signed distance, m, shape ``(...)``.
      n: unit normal from the obstacle towards the robot, ``(..., 3)``, world axes.
      v: world velocity of the robot point, ``(..., 3)``, m/s (obstacle static).
      params: `ContactParams`, fields broadcastable against ``(...)``.
    Returns:
      ``(f, N_mag, f_t)``: ``f = N_mag n + f_t`` ``(..., 3)`` N, the force on the robot
      point in world axes; ``N_mag`` ``(...)`` N, the normal force along ``n`` (see
      `normal_force`); ``f_t`` ``(..., 3)`` N, the friction force (``f_t . n = 0``).
      All exactly zero for ``d >= d_on``.
    """
    n = jnp.asarray(n)
    v = jnp.asarray(v)
    v_n = jnp.sum(v * n, axis=-1)
    v_t = v - v_n[..., None] * n
    N_mag = normal_force(d, v_n, params)
    f_t = friction_force(N_mag, v_t, params)
    f = N_mag[..., None] * n + f_t
    return f, N_mag, f_t
