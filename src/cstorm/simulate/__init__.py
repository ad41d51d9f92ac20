"""Rollouts of the hybrid dynamics: active joints follow prescribed paths, the passive
state is integrated forward (RK4 with RKMK4 on free and ball joints, or semi-implicit
Euler), with contact forces from a contact model.

- `steps`: the active/passive layout (`RolloutLayout`), one dynamics stage, one
  integration step, the divergence guard and the checkpointed scan;
- `contact_hybrid`: contact forces and hybrid dynamics under one derivative rule;
- `tangents`: the time-parallel tangent rule (``derivatives="parallel"``);
- `rollout`: `rollout` (pure JAX) and `simulate` (eager, host results).
"""

from .steps import (DERIVATIVES, INTEGRATORS, RolloutLayout, active_paths, dexpinv, dynamics_stage, initial_carry,
                    passive_exp, time_grid)
from .contact_hybrid import contact_hybrid
from .tangents import scan_steps
from .rollout import Trajectory, check_divergence, rollout, simulate

__all__ = ["simulate", "rollout", "Trajectory", "RolloutLayout", "time_grid", "active_paths", "check_divergence",
           "DERIVATIVES", "INTEGRATORS", "dynamics_stage", "passive_exp", "dexpinv", "initial_carry", "contact_hybrid",
           "scan_steps"]
