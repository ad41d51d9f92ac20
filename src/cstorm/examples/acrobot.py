"""The acrobot (Spong 1995, "The swing up control problem for the Acrobot"): two links in
a vertical plane, the shoulder passive, the elbow actuated; swing up from hanging to
upright.

Model: `cs.robots.acrobot_model` (Spong's parameters).
"""

from __future__ import annotations

import numpy as np

from ..optimize import constraints, costs
from ..optimize.problem import MotionProblem
from ..trajectory import QuinticBSpline
from .robots import acrobot_model


def acrobot(t_final: float = 3.0, n_ctrl: int = 16, dt: float = 0.01, integrator: str = "rk4",
            continuation: bool = True, shooting: int = 1):
    """Acrobot swing-up: from hanging at rest, ``q = (0, 0)``, to upright at rest,
    ``q = (pi, 0)``, in ``t_final`` s, moving only the elbow; minimize the integral of
    ``1/2 tau_elbow^2``.

    The elbow's path is a quintic B-spline (``n_ctrl`` control points) that starts and
    ends at rest at 0 rad by construction; the shoulder's final angle and velocity are
    terminal equality constraints (``pi`` rad, 0 rad/s). The default solve ramps the
    shoulder's target through ``pi * (0.25, 0.5, 0.75, 0.875, 1)`` (continuation on the
    problem parameter ``"target"``), warm-starting each stage: straight at ``pi`` SLSQP
    wanders (reaching the unstable upright equilibrium at rest is badly conditioned for
    single shooting), and the last step of the ramp needs the finer 0.875 stop.

    ``shooting``: shooting intervals (see `cstorm.optimize.problem`; 1: single shooting).

    Returns a `MotionProblem`; ``cs.solve(problem)`` solves it (the problem's
    ``solve_options`` hold the continuation schedule).
    """
    model = acrobot_model()
    spl = QuinticBSpline(n_ctrl, t_final)
    # initial guess: a small elbow oscillation near the hanging pendulum's frequency
    w = 2 * np.pi / 2.0
    t = np.linspace(0, t_final, 4 * n_ctrl)
    guess = 0.3 * np.sin(w * t) * np.sin(np.pi * t / t_final) ** 2
    prob = MotionProblem(
        model, active=["elbow"], t_final=t_final, n_ctrl=n_ctrl, dt=dt, q0=np.zeros(2),
        q_final_active={"elbow": 0.0}, rest_end=True,
        costs=[costs.TorqueSquared(weight=1.0)],
        constraints=[constraints.TerminalState("shoulder", q="target", v=0.0)],
        params={"target": np.pi}, integrator=integrator, name="acrobot",
        initial_guess={"elbow": (t, guess)}, shooting=shooting,
    )
    if continuation:
        prob.solve_options["continuation"] = {"target": [np.pi * s for s in (0.25, 0.5, 0.75, 0.875, 1.0)]}
    return prob


EXAMPLES = {"acrobot": acrobot}
