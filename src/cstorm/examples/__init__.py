"""Shipped example problems, by name.

``cs.examples.get("acrobot")()`` builds the problem (keyword arguments select variants);
``cs.examples.names()`` lists them; ``cs.examples.acrobot(...)`` is the same function.
Each returns a `MotionProblem` (or `MotionSequence`) whose ``solve_options`` hold the
solve plan (continuation, staging) that makes ``cs.solve(problem)`` converge.
"""

from __future__ import annotations

from ..errors import InputError
from .acrobot import acrobot, acrobot_model

_REGISTRY = {
    "acrobot": acrobot,
}

__all__ = ["get", "names", "acrobot", "acrobot_model"]


def names() -> list:
    """Names of the shipped example problems."""
    return sorted(_REGISTRY)


def get(name: str):
    """The problem factory registered under ``name`` (call it to build the problem)."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise InputError(f"unknown example problem {name!r}; known: {', '.join(names())}") from None
