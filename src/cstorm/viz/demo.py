"""The main demo (``cstorm demo``, ``bash scripts/demo.sh``): a real optimal contact
motion, solved and written to files a person can look at.

Today the demo is the Luxo lamp's hop (`cstorm.examples.luxo`): the planar desk lamp
crouches, jumps one foot length forward (0.16 m) with a flight phase and lands at rest,
with minimal integral of squared torques, solved by SLSQP with exact gradients through
the smooth contact model. The demo writes the robot's description (``luxo_info.txt``:
tree, joints, masses, inertias, collision shapes) and then exactly what ``cstorm solve
luxo`` writes: ``summary.json``, ``solution.npz``, ``trajectory.csv``, PNG plots and
``animation.gif``. The tumbler sequence (`cstorm.examples.tumbler`) becomes the demo
once it solves end to end (it does not yet).
"""

from __future__ import annotations

import os

DEMO_PROBLEM = "luxo"  # the tumbler sequence takes its place once it solves end to end


def write_model_info(out: str, model) -> str:
    """Write ``<model.name>_info.txt`` (`cstorm.model.info.describe`) into ``out``;
    returns the text."""
    from ..model.info import describe

    text = describe(model)
    path = os.path.join(out, f"{model.name}_info.txt")
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        f.write(text + "\n")
    os.replace(tmp, path)
    return text
