"""Inertia validation: link-level checks on input, judgment on the merged bodies.

Links joined by fixed joints form one body; the dynamics see only the body's inertia
(mass, CoM, inertia about the CoM: the links' spatial inertias summed). So inertias are
judged on bodies, with tolerances relative to the body's own scale ``s`` (its largest
principal moment, floored at 1e-6 of the model's largest so that a point mass's
rounding noise is judged against the robot, not against zero):

- **errors, always** (the dynamics cannot survive them): NaN/inf, negative mass, a
  non-symmetric inertia matrix (beyond 1e-9 relative) on any link; a body whose
  principal moment is below ``-1e-9 s`` (indefinite: negative kinetic energy).
- **rounding noise, repaired with a note** (``Model.notes``): a body principal moment in
  ``[-1e-9 s, 0)`` is clipped to 0; a link whose own inertia is indefinite or breaks the
  triangle inequality but whose mass and inertia are below 1e-3 of its body's (a
  placeholder such as mass 1e-6 kg with every entry 1e-6 kg m^2) is noted.
- **implausible but computable, a warning per body** (`ModelWarning`, naming the links
  and the margin; ``inertia_check="strict"`` makes it a `ModelError`): a body that
  violates the triangle inequality ``I3 <= I1 + I2`` by more than ``1e-6 s``; a body that
  is fine but holds a non-negligible link that on its own violates it, or is indefinite
  (e.g. an antenna with principal moments [-3.5e-8, 3.5e-8, 9.1e-8] kg m^2 welded to a
  43 kg base).

Links welded to the world (a fixed base) do not enter the dynamics; their inertias get
only the always-errors checks and notes.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..errors import ModelError, ModelWarning

__all__ = ["INERTIA_CHECKS", "link_inertia", "judge_bodies"]

#: accepted values of ``inertia_check``; "lenient" is a synonym of "warn"
INERTIA_CHECKS = ("warn", "strict", "lenient")

NOISE = 1e-9  # relative: principal moments this far below 0 are rounding
TRIANGLE = 1e-6  # relative: URDFs print 6-7 significant digits
NEGLIGIBLE = 1e-3  # a link this light (mass and inertia) beside its body is a placeholder
FLOOR = 1e-6  # body scale floor, relative to the model's largest principal moment


def link_inertia(mass, com, inertia, where: str):
    """Check one link's mass (kg), CoM (3,) and inertia about the CoM: (3, 3), principal
    (3,) or URDF-ordered (6,) = (ixx, ixy, ixz, iyy, iyz, izz). Returns
    ``(mass, com (3,), inertia (3, 3) symmetric)``. Raises `ModelError` for NaN/inf,
    negative mass, wrong shapes and non-symmetric matrices; definiteness and the triangle
    inequality are judged later, on merged bodies (`judge_bodies`)."""
    m = float(mass)
    if not np.isfinite(m) or m < 0:
        raise ModelError(f"{where}: mass must be finite and >= 0, got {mass}")
    c = np.asarray(com, dtype=float).reshape(-1)
    if c.shape != (3,) or not np.all(np.isfinite(c)):
        raise ModelError(f"{where}: centre of mass must be 3 finite numbers, got {com}")
    I = np.asarray(inertia if inertia is not None else np.zeros((3, 3)), dtype=float)
    if I.shape == (3,):
        I = np.diag(I)
    elif I.shape == (6,):
        ixx, ixy, ixz, iyy, iyz, izz = I
        I = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    if I.shape != (3, 3) or not np.all(np.isfinite(I)):
        raise ModelError(f"{where}: inertia must be (3,), (6,) or (3, 3) finite numbers, got {np.shape(inertia)} "
                         f"{np.asarray(inertia).tolist()}")
    scale = max(1e-300, np.abs(I).max())
    if np.abs(I - I.T).max() > NOISE * scale:
        raise ModelError(f"{where}: inertia matrix is not symmetric:\n{I}")
    return m, c, 0.5 * (I + I.T)


def _moments(I):
    return np.linalg.eigvalsh(0.5 * (I + I.T))


def _fmt(ev):
    return "[" + ", ".join(f"{x:.3g}" for x in ev) + "]"


def judge_bodies(source: str, body_names, body_links, mass, inertia, links, check: str = "warn"):
    """Judge merged body inertias (see the module docstring).

    Args:
        source: file name for messages.
        body_names: (nb,) names; ``body_links``: for each body the names of its links
            (first the body's own link); key ``-1`` of the dict form is the world.
        mass: (nb,) merged masses; inertia: (nb, 3, 3) merged inertias about the CoM.
        links: {link name: (mass, inertia (3, 3) about its CoM)}.
        check: "warn" / "lenient" or "strict".
    Returns: ``(inertia (nb, 3, 3) repaired, notes: list[str])``; warns `ModelWarning`
        once per implausible body; raises `ModelError` for what cannot be survived (and,
        with ``check="strict"``, for the implausible).
    """
    strict = check == "strict"
    notes: list[str] = []
    inertia = np.array(inertia, dtype=float)
    model_scale = max((np.abs(_moments(I)).max() for _, I in links.values()), default=0.0)
    floor = FLOOR * model_scale

    # links welded to the world: not part of the dynamics
    for ln in body_links.get(-1, ()):
        m, I = links[ln]
        ev = _moments(I)
        s = max(np.abs(ev).max(), floor)
        if ev[0] < -NOISE * s or ev[2] > ev[0] + ev[1] + TRIANGLE * s:
            notes.append(f"link {ln!r} is welded to the world (not part of the dynamics); its inertia "
                         f"(principal moments {_fmt(ev)} kg m^2) is not physical")

    for b, name in enumerate(body_names):
        lnames = body_links[b]
        I = 0.5 * (inertia[b] + inertia[b].T)
        ev = _moments(I)
        s = max(np.abs(ev).max(), floor)
        what = f"{source}: body {name!r}" + (f" ({len(lnames)} links merged by fixed joints)" if len(lnames) > 1 else "")
        if ev[0] < -NOISE * s:
            parts = []
            for ln in lnames:
                evl = _moments(links[ln][1])
                if evl[0] < -NOISE * max(np.abs(evl).max(), floor):
                    parts.append(f"link {ln!r} {_fmt(evl)}")
            if len(lnames) > 1:
                what += f": links {list(lnames)}"
            raise ModelError(
                f"{what}: inertia is not positive semi-definite (principal moments {_fmt(ev)} kg m^2; "
                + (f"indefinite links: {', '.join(parts)}" if parts else "no single link is indefinite")
                + "): negative kinetic energy, the dynamics are not defined")
        if ev[0] < 0:
            w, V = np.linalg.eigh(I)
            inertia[b] = (V * np.maximum(w, 0.0)) @ V.T
            notes.append(f"body {name!r}: principal moment {ev[0]:.3g} kg m^2 (rounding noise beside {ev[2]:.3g}) "
                         "clipped to 0")
        else:
            inertia[b] = I
        problems = []
        margin = ev[2] - ev[0] - ev[1]
        body_bad = margin > TRIANGLE * s
        if body_bad:
            problems.append(f"the body violates the triangle inequality (principal moments {_fmt(ev)} kg m^2: "
                            f"I3 exceeds I1 + I2 by {margin:.3g}, {margin / s:.2%} of I3)")
        for ln in lnames:
            ml, Il = links[ln]
            evl = _moments(Il)
            sl = max(np.abs(evl).max(), floor)
            indefinite = evl[0] < -NOISE * sl
            ml_margin = evl[2] - evl[0] - evl[1]
            tri = ml_margin > TRIANGLE * sl
            if not (indefinite or tri):
                continue
            if len(lnames) == 1 and not indefinite:
                continue  # the body's own finding says it
            desc = (f"link {ln!r} on its own is " + ("indefinite" if indefinite else "not a rigid body's inertia")
                    + f" (principal moments {_fmt(evl)} kg m^2" + ("" if indefinite else
                                                                 f", I3 exceeds I1 + I2 by {ml_margin:.3g}") + ")")
            negligible = ml <= NEGLIGIBLE * mass[b] and sl <= NEGLIGIBLE * s
            if negligible and not indefinite:
                notes.append(f"body {name!r}: {desc}; it is a placeholder ({ml:.3g} kg beside {mass[b]:.3g} kg), "
                             "the merged body is physical")
            else:
                problems.append(desc + ("" if body_bad else "; the merged body's inertia is physical"))
        if problems:
            msg = f"{what}: implausible inertia: " + "; ".join(problems)
            if strict:
                raise ModelError(msg + " (inertia_check='strict'; the default 'warn' loads it with a warning)")
            warnings.warn(msg + "; loaded as is (inertia_check='strict' refuses it)", ModelWarning, stacklevel=4)
    return inertia, notes
