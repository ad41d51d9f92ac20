"""Compiled code against the process's memory-map limit (Linux).

XLA's CPU backend maps each compiled executable into the process as many small
memory regions: about 5,000 mappings for the compiled
functions of one tumbler segment (rollout with gradients, step check, solve). Linux
caps a process at ``vm.max_map_count`` mappings (default 65,530). Past that cap, ``mmap``
fails inside the compiler and the process dies with a segmentation fault, not a Python
error. A long-lived process that compiles many different problems (a parameter sweep
over robots, a notebook, a test-suite worker) gets there after a dozen problems.

`relieve_map_pressure` is called where cstorm is about to compile (`cstorm.solve`,
`cstorm.simulate.simulate`, `cstorm.check_time_step`). Above ``fraction`` of the cap it
drops JAX's compilation caches (``jax.clear_caches()``: compiled functions still in use
are rebuilt on their next call), which returns most of the mappings, and it warns. Elsewhere than Linux it does nothing.
"""

from __future__ import annotations

import gc
import warnings

#: share of ``vm.max_map_count`` above which the compilation caches are dropped
FRACTION = 0.6


def map_usage():
    """``(mappings of this process, vm.max_map_count)``, or None where ``/proc`` does not
    say (not Linux)."""
    try:
        with open("/proc/self/maps", "rb") as f:
            n = sum(1 for _ in f)
        with open("/proc/sys/vm/max_map_count") as f:
            limit = int(f.read().strip())
    except (OSError, ValueError):
        return None
    return n, limit


def relieve_map_pressure(fraction: float = FRACTION, where: str = "cstorm", warn: bool = True) -> bool:
    """Drop JAX's compilation caches if this process uses more than ``fraction`` of its
    memory-map limit; returns whether it did. ``where`` names the caller in the warning
    (``warn=False``: no warning)."""
    usage = map_usage()
    if usage is None or usage[0] < fraction * usage[1]:
        return False
    import jax

    jax.clear_caches()
    gc.collect()
    after = map_usage()
    if not warn:
        return True
    warnings.warn(
        f"{where}: this process held {usage[0]} memory mappings of its limit vm.max_map_count = {usage[1]} "
        f"(compiled JAX code; past the limit XLA's compiler crashes), so JAX's compilation caches were "
        f"cleared ({after[0] if after else '?'} mappings now): functions compiled before are recompiled on "
        "their next call. To avoid the recompiles, call jax.clear_caches() yourself between unrelated "
        "problems, or raise the limit (sysctl vm.max_map_count).", RuntimeWarning, stacklevel=3)
    return True
