"""cstorm: optimal motions for robots that make and break contact.

The public API (see DESIGN.md) is re-exported here; nothing else is.
"""

__version__ = "0.1.0"

from .errors import CstormError, ModelError, ShapeError, InputError, DivergenceError, ProblemError
from .geometry.shapes import Sphere, Capsule, Box, Cylinder, Plane, ConvexMesh
