"""Pieces shared by the planar capsule robots of the examples (`hopper`, `walker`,
`luxo`): MuJoCo's capsule inertia, contact distances read from a solution's trajectory,
one success-criterion entry, and the longest run of a condition over a time grid.

Not an example itself (the leading underscore keeps it out of the registry).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import ProblemError

__all__ = ["DENSITY", "capsule_inertia", "trajectory_contact_d", "criterion", "longest_run"]

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
