"""cstorm: optimal motions for robots that make and break contact.

The public API (see DESIGN.md) is re-exported here; nothing else is. cstorm computes in
float64: enable it with ``jax.config.update("jax_enable_x64", True)`` before use (the CLI
and the test-suite do; cstorm never changes global JAX flags on import).
"""

from .version import __version__

from .errors import CstormError, ModelError, ModelWarning, ShapeError, InputError, DivergenceError, ProblemError
from .geometry.shapes import Sphere, Capsule, Box, Cylinder, Plane, ConvexMesh
from .model import Model, ModelBuilder, Revolute, Prismatic, Free, Ball
from .model.urdf import load_urdf
from .model.mjcf import load_mjcf
from .dynamics import (
    forward_kinematics, body_velocities, frame_pose, rnea, bias_forces, gravity_forces, mass_matrix, aba,
    hybrid_dynamics, point_jacobian, kinetic_energy, potential_energy, center_of_mass, passive_forces,
    integrate, difference, normalize,
    rnea_derivatives, aba_derivatives, hybrid_dynamics_derivatives, RNEADerivatives, ABADerivatives,
    HybridDerivatives,
)
from .trajectory import QuinticBSpline
from .contact import ContactParams
from .geometry import signed_distance
from .contact import Environment, Obstacle, ground, incline, platform, step
from .contact import contact_forces, ContactData, contact_labels
from . import simulate
from .optimize import MotionProblem, MotionSequence, solve, Solution, Status, load_solution, check_gradients
from .analysis.timestep import check_time_step
from . import examples
from .examples import robots
from .allocator import tune_allocator
