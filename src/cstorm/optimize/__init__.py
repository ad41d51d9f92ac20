"""Motion optimization: problems (single shooting with B-spline active paths), cost and
constraint terms, sequences of segments, the solver front end, solutions and gradient
checks."""

from . import costs, constraints
from .problem import MotionProblem
from .sequence import MotionSequence
from .solve import solve
from .solution import Solution, Status, load_solution
from .gradcheck import check_gradients

__all__ = ["MotionProblem", "MotionSequence", "solve", "Solution", "Status", "load_solution", "check_gradients", "costs",
           "constraints"]
