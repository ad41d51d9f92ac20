"""The main demo (``cstorm demo``, ``bash scripts/demo.sh``): a real optimal contact
motion, solved and written to files a person can look at.

The demo is the draft paper's tumbling robot (`cstorm.examples.tumbler`): a
`MotionSequence` of four segments, start -> handstand -> roll -> standing -> start, each
solved by SLSQP with exact gradients through the smooth contact model from the state
where the previous one ended, with minimal integral of squared torques. The demo writes
the robot's description (``tumbler_info.txt``: tree, joints, masses, inertias, collision
shapes) and then exactly what ``cstorm solve tumbler`` writes: ``summary.json``,
``solution.npz``, ``trajectory.csv``, PNG plots and ``animation.gif``. ``cstorm solve
luxo`` is a shorter alternative (the Luxo lamp's hop).
"""

from __future__ import annotations

import os

DEMO_PROBLEM = "tumbler"


def write_model_info(out: str, model) -> str:
    """Write ``<model.name>_info.txt`` (`cstorm.model.info.describe`) into ``out``;
    returns the text."""
    from ..io.files import write_text
    from ..model.info import describe

    text = describe(model)
    path = os.path.join(out, f"{model.name}_info.txt")
    write_text(path, text + "\n")
    return text
