"""The ``cstorm`` command (`main`): ``info``, ``demo``, ``solve``, ``animate``,
``check-gradients``."""

from .commands import main

__all__ = ["main"]
