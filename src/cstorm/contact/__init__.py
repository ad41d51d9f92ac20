"""Smooth penalty contact between a robot and its environment.

- `laws`: the smoothing functions, `ContactParams` and the force law at one contact point
  (conventions: signed distance, normal, friction);
- `environment`: obstacles (`ground`, `incline`, `box`, `platform`, `step`, `sphere`) and
  the `Environment` that selects shape pairs;
- `plane`: the contact points of robot features against planes, with analytic
  derivatives w.r.t. ``(q, v)``;
- `forces`: every contact point of a robot in an environment and the body wrenches
  ``f_ext`` they make (`contact_forces`).
"""

from .laws import (ContactParams, beta, friction_force, gamma, gamma_over_s, normal_force, point_contact_force,
                   smooth_nonneg)
from .environment import CONTACT_MODES, Environment, Obstacle, box, ground, incline, platform, sphere, step
from .plane import plane_points
from .forces import ContactData, contact_forces, contact_labels

__all__ = ["ContactParams", "beta", "friction_force", "gamma", "gamma_over_s", "normal_force", "point_contact_force",
           "smooth_nonneg", "CONTACT_MODES", "Environment", "Obstacle", "box", "ground", "incline", "platform",
           "sphere", "step", "plane_points", "ContactData", "contact_forces", "contact_labels"]
