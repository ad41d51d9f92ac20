"""Pieces shared by the planar capsule robots of the examples (`hopper`, `walker`,
`luxo`): MuJoCo's capsule inertia, contact distances read from a solution's trajectory,
one success-criterion entry, the longest run of a condition over a time grid, the hold
test of a motion that ends at rest, and a bound on the contacts' sliding power.

Not an example itself (the leading underscore keeps it out of the registry).
"""

from __future__ import annotations

import math

import numpy as np

import jax.numpy as jnp

from ..errors import ProblemError
from ..optimize.constraints import Constraint
from ..optimize.costs import resolve

__all__ = ["DENSITY", "capsule_inertia", "trajectory_contact_d", "criterion", "longest_run", "hold_test", "SlipPower"]

DENSITY = 1000.0  # kg/m^3, MuJoCo's default geom density


def capsule_inertia(radius, length, density=DENSITY, mass=None):
    """Mass (kg) and principal inertias ``(I_perp, I_perp, I_axial)`` (kg m^2, about the
    centre, axis along z) of a uniform solid capsule: a cylinder of ``length`` (m, the
    axis segment) plus two hemispheres of ``radius`` (m). The density is ``density``
    (kg/m^3; MuJoCo's ``inertiafromgeom``), or, with ``mass`` (kg) given, the density
    that gives that mass."""
    r, h = float(radius), float(length)
    vc, vs = math.pi * r * r * h, 4.0 / 3.0 * math.pi * r ** 3  # cylinder, the two hemispheres
    rho = float(density) if mass is None else float(mass) / (vc + vs)
    mc, ms = rho * vc, rho * vs
    # the two hemispheres about the capsule centre: each 83/320 m r^2 about its own CoM,
    # which lies 3r/8 from its flat face, i.e. h/2 + 3r/8 from the centre
    perp = mc * (3 * r * r + h * h) / 12.0 + ms * (2 * r * r / 5 + h * h / 4 + 3 * r * h / 8)
    axial = mc * r * r / 2 + ms * 2 * r * r / 5
    return mc + ms, (perp, perp, axial)


def trajectory_contact_d(tr, who="criteria"):
    """(N+1, k) signed contact distances (m) of a solution's trajectory dict ``tr`` (its
    ``contact`` entry: contact data, or a dict as loaded from ``solution.npz``). Raises
    `ProblemError` (prefixed ``who``) when the trajectory has none."""
    c = tr.get("contact")
    if c is None:
        raise ProblemError(f"{who}: the solution's trajectory has no contact data")
    if isinstance(c, dict):
        for k in ("d", "contact/d"):
            if k in c:
                return np.asarray(c[k])
        raise ProblemError(f"{who}: no contact distances in the trajectory (keys {sorted(c)})")
    return np.asarray(c.d)


def criterion(value, tol, ok, op="<="):
    """One success-criterion entry, as `cstorm.report` writes them: ``{"value", "tol",
    "op", "ok"}``."""
    return dict(value=float(value), tol=float(tol), op=op, ok=bool(ok))


def longest_run(t, flag):
    """Total and longest duration (s) over which ``flag`` (N+1,) bools holds at both ends
    of a step of the grid ``t`` (N+1,): ``(total, longest)``."""
    t, flag = np.asarray(t, float), np.asarray(flag, bool)
    dt = np.diff(t)
    seg = flag[:-1] & flag[1:]
    total, longest, run = float(np.sum(dt[seg])), 0.0, 0.0
    for ok, h in zip(seg, dt):
        run = run + h if ok else 0.0
        longest = max(longest, run)
    return total, longest


def hold_test(problem, solution, duration=1.0):
    """What "at rest" means physically: from the solution's final state, simulate
    ``duration`` s more with the active joints locked (zero active accelerations, same
    RK4 step, contact and environment) and measure how far the planar base (``root_x,
    root_z, root_pitch``, the first three coordinates) moves. Returns ``(pitch_dev,
    pos_dev, v_end)``: the largest pitch deviation from the final value (rad), the
    largest x-z displacement (m), and the largest base speed at the end of the hold (m/s,
    rad/s); all ``inf`` if the hold diverges."""
    from ..errors import DivergenceError
    from ..simulate import simulate

    p = problem
    qT, vT = np.asarray(solution.trajectory["q"][-1]), np.asarray(solution.trajectory["v"][-1])
    try:
        h = simulate(p.model, qT, vT, t_final=duration, dt=p.dt, active=p.active, env=p.env, contact=p.contact,
                     check=False)
    except DivergenceError:  # a diverging hold is a failed hold
        return math.inf, math.inf, math.inf
    q, v = np.asarray(h.q), np.asarray(h.v)
    pitch_dev = float(np.max(np.abs(q[:, 2] - qT[2])))
    pos_dev = float(np.max(np.linalg.norm(q[:, :2] - qT[:2], axis=1)))
    return pitch_dev, pos_dev, float(np.max(np.abs(v[-1, :3])))


class SlipPower(Constraint):
    """No skating: at every constraint-grid sample, the contact slip power
    ``sum_k N_k sqrt(|v_t,k|^2 + v_eps^2)`` (W; ``N_k`` the normal force magnitude,
    ``v_t,k`` the tangential velocity of contact point ``k``) is at most ``limit`` (W, or
    a problem-parameter name). A stance foot's penalty friction creeps at ~1 cm/s under
    body weight (~3 W); a skimming swing foot at 1 m/s under 40 N is 40 W."""

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
