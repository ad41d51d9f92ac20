"""The solver front end (`cstorm.optimize.solve`) in pieces that need no compiled
problem; solves of whole problems are in tests/test_optimize.py and the examples' tests."""

from __future__ import annotations

import numpy as np
import pytest

from cstorm.errors import InputError
from cstorm.optimize.solve import resolve_objective_scale


def test_first_step_scales_the_auto_objective_scale():
    """``solve_options["first_step"]`` (used by the hopping problems) scales SLSQP's
    first step: the auto objective scale is ``first_step / |grad f|_inf``; None is 1, a
    number is itself, anything else is refused."""

    class Ev:
        def at(self, x):
            return (0.0, None, None, False, np.array([0.5, -4.0]))

    assert resolve_objective_scale("auto", Ev(), None) == pytest.approx(0.25)
    assert resolve_objective_scale("auto", Ev(), None, 0.1) == pytest.approx(0.025)
    assert resolve_objective_scale(None, Ev(), None, 0.1) == 1.0
    assert resolve_objective_scale(3.0, Ev(), None) == 3.0
    with pytest.raises(InputError, match="objective_scale"):
        resolve_objective_scale(-1.0, Ev(), None)
