"""Shipped example problems, by name.

``cs.examples.get("acrobot")()`` builds the problem (keyword arguments select variants);
``cs.examples.names()`` lists them; ``cs.examples.acrobot(...)`` is the same function.
Each returns a `MotionProblem` (or `MotionSequence`) whose ``solve_options`` hold the
solve plan (continuation, staging) that makes ``cs.solve(problem)`` converge.

The robots of every example are in `robots` (``cs.robots``); `hopping` and `planar`
hold what several examples share (the hop-and-land problem, success criteria).

Registration: every module of this package that defines ``EXAMPLES = {name: factory}``
contributes its problems; modules are found with `pkgutil`, so adding an example is
adding a module (no central list to edit).
"""

from __future__ import annotations

import importlib
import pkgutil

from ..errors import InputError

_REGISTRY: dict | None = None


def registry() -> dict:
    """The registered problems, ``{name: factory}`` (built on first use: every module of
    the package is imported once). The dict itself: an entry added to it is a problem
    `get` finds (a test registers a stand-in this way)."""
    global _REGISTRY
    if _REGISTRY is None:
        reg = {}
        for info in pkgutil.iter_modules(__path__):
            if info.name.startswith("_"):
                continue
            mod = importlib.import_module(f"{__name__}.{info.name}")
            for name, fn in getattr(mod, "EXAMPLES", {}).items():
                if name in reg:
                    raise RuntimeError(f"example {name!r} registered twice ({mod.__name__})")
                reg[name] = fn
        _REGISTRY = reg
        # cs.examples.<name> is the factory, even where a module has the same name
        globals().update(reg)
    return _REGISTRY


def names() -> list:
    """Names of the shipped example problems."""
    return sorted(registry())


def get(name: str):
    """The problem factory registered under ``name`` (call it to build the problem)."""
    try:
        return registry()[name]
    except KeyError:
        raise InputError(f"unknown example problem {name!r}; known: {', '.join(names())}") from None


def __getattr__(name):  # cs.examples.acrobot(...), cs.examples.tumbler(...)
    if name.startswith("__"):
        raise AttributeError(name)
    reg = registry()
    if name in reg:
        return reg[name]
    raise AttributeError(f"module 'cstorm.examples' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(registry()))


registry()
