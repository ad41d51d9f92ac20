"""Robot models: the `Model` tree, joint types and the builder."""

from .joints import Joint, Revolute, Prismatic, Free, Ball
from .model import Model
from .builder import ModelBuilder
