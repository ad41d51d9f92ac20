"""cstorm: optimal motions for robots that make and break contact.

The public API (see DESIGN.md) is re-exported here; nothing else is.
"""

__version__ = "0.1.0"

from .errors import CstormError, ModelError, ShapeError, InputError, DivergenceError, ProblemError
from .geometry.shapes import Sphere, Capsule, Box, Cylinder, Plane, ConvexMesh
from .model import Model, ModelBuilder, Revolute, Prismatic, Free, Ball
from .dynamics import (
    forward_kinematics, body_velocities, frame_pose, rnea, bias_forces, gravity_forces, mass_matrix, aba,
    hybrid_dynamics, point_jacobian, kinetic_energy, potential_energy, center_of_mass, passive_forces,
    integrate, difference, normalize,
)
