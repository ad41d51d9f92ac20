"""Motion optimization: problems (single or multiple shooting with B-spline active
paths), cost and constraint terms, initial guesses, sequences of segments, the solver
front end, solutions and gradient checks."""

from . import costs, constraints
from .costs import Cost, TorqueSquared, Power, StateTarget, CoMTarget, RunningCost, TerminalCost, LandingPenalty
from .constraints import (Constraint, JointLimits, TorqueLimits, TerminalState, ContactDistance, Periodic,
                          AverageSpeed, TerminalConstraint, PathConstraint, FlightClearance, SwingClearance, AtRest,
                          ForwardDistance, PitchBound, ScaledTorqueLimits, SlipPower)
from .guesses import keyframe_guess
from .problem import MotionProblem
from .sequence import MotionSequence
from .solve import solve
from .solution import Solution, Status, load_solution
from .gradcheck import check_gradients

__all__ = ["MotionProblem", "MotionSequence", "solve", "Solution", "Status", "load_solution", "check_gradients",
           "costs", "constraints", "keyframe_guess",
           "Cost", "TorqueSquared", "Power", "StateTarget", "CoMTarget", "RunningCost", "TerminalCost",
           "LandingPenalty",
           "Constraint", "JointLimits", "TorqueLimits", "TerminalState", "ContactDistance", "Periodic", "AverageSpeed",
           "TerminalConstraint", "PathConstraint", "FlightClearance", "SwingClearance", "AtRest", "ForwardDistance",
           "PitchBound", "ScaledTorqueLimits", "SlipPower"]
