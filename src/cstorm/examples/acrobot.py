"""The acrobot (Spong 1995, "The swing up control problem for the Acrobot"): two links in
a vertical plane, the shoulder passive, the elbow actuated; swing up from hanging to
upright.

Model (Spong's parameters): links of length ``l = 1 m`` and mass ``m = 1 kg``, CoM at
the link's middle (0.5 m), inertia ``m l^2 / 12`` about the CoM, gravity 9.81 m/s^2 along
-z. Both joints rotate about the world/link y axis; at ``q = (0, 0)`` both links hang
straight down, at ``q = (pi, 0)`` the acrobot stands upright. Joints: ``shoulder`` (world
-> link1, at the origin), ``elbow`` (link1 -> link2, at the tip of link 1).
"""

from __future__ import annotations

import numpy as np

from ..model.builder import ModelBuilder
from ..trajectory import QuinticBSpline


def acrobot_model(length: float = 1.0, mass: float = 1.0, gravity: float = 9.81):
    """The acrobot `Model` (2 revolute joints about y: ``shoulder``, ``elbow``; links
    ``link1``, ``link2`` hanging along -z at q = 0)."""
    L, m = float(length), float(mass)
    Ic = m * L * L / 12.0
    inertia = np.diag([Ic, Ic, 1e-6 * Ic])  # a thin rod along z
    b = ModelBuilder("acrobot", gravity=(0.0, 0.0, -float(gravity)))
    b.add_body("link1", None, "revolute", joint_name="shoulder", mass=m, com=(0.0, 0.0, -L / 2), inertia=inertia,
               axis=(0.0, 1.0, 0.0))
    b.add_body("link2", "link1", "revolute", joint_name="elbow", mass=m, com=(0.0, 0.0, -L / 2), inertia=inertia,
               axis=(0.0, 1.0, 0.0), xyz=(0.0, 0.0, -L))
    b.add_frame("tip", "link2", xyz=(0.0, 0.0, -L))
    return b.build()


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
    from ..optimize import costs, constraints
    from ..optimize.problem import MotionProblem

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
