"""Keep XLA's large temporary buffers in the heap between calls (glibc, Linux).

Why: XLA's CPU backend gives each call of a compiled function one temporary buffer for
its intermediates. Batched calls make it large: `jax.vmap` of `cstorm.aba` over 4096
configurations of a 38-DoF humanoid needs 59 MB. glibc's ``malloc`` serves blocks above
32 MB (its largest mmap threshold) with a fresh ``mmap`` and returns them with
``munmap`` when freed, and XLA allocates from its worker threads, whose per-thread
arenas cannot hold such a block at all. So every call faults the whole buffer in
again, page by page, and the kernel zeroes each page (about 14,000 minor page faults
per call); with `tune_allocator` batched ABA on that humanoid takes roughly 40 % less
time per configuration. Rollouts inside the solver use buffers of a few MB and are not affected.

What `tune_allocator` changes, for the whole process, through ``mallopt(3)``:

- ``M_ARENA_MAX = 1``: every thread allocates from the main arena (the ``brk`` heap),
  which can grow to any size; threads created afterwards (XLA's worker pool is created
  when JAX starts its CPU backend) do not get arenas of their own;
- ``M_MMAP_MAX = 0``: no block is served by ``mmap``, so large blocks come from the
  heap and are reused by the next call;
- ``M_TRIM_THRESHOLD = retain_bytes``: up to that much free memory at the top of the
  heap is kept instead of being returned to the system.

The cost: the process keeps up to ``retain_bytes`` (default 1 GiB) of freed memory, and
a large block freed below long-lived ones is reused but not returned to the system;
threads share one arena (contention only matters for many threads that allocate often).
It must run before JAX starts its backend (the first computation or ``jax.devices()``):
threads created before then keep their own arenas, and the setting then has no effect
on XLA's buffers.

cstorm does not change the allocator on import. The ``cstorm`` command line and
``python -m benchmarks`` call `tune_allocator` before starting JAX (``CSTORM_MALLOC=system``
leaves glibc's defaults). A program that batches large computations calls it first::

    import cstorm as cs
    cs.tune_allocator()          # before the first JAX computation
    ...

Elsewhere than glibc (macOS, musl) it does nothing and returns False.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import platform
import warnings

# mallopt(3) parameter numbers (glibc's malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_MAX = -4
_M_ARENA_MAX = -8

#: default of ``retain_bytes``: free heap memory kept for reuse (1 GiB)
RETAIN_BYTES = 1 << 30

_tuned = False


def allocator_tuned() -> bool:
    """Whether `tune_allocator` has changed this process's allocator."""
    return _tuned


def _backend_started() -> bool:
    try:
        from jax._src import xla_bridge

        return bool(xla_bridge.backends_are_initialized())
    except Exception:  # pragma: no cover - private API moved: assume not started
        return False


def tune_allocator(retain_bytes: int = RETAIN_BYTES, *, respect_env: bool = True, late: str = "warn") -> bool:
    """Make glibc keep large blocks in the heap for reuse (see the module docstring).

    Args:
      retain_bytes: free memory at the top of the heap that is kept rather than returned
        to the system (bytes, an int >= 0). Blocks larger than this are still returned,
        and fault in again on their next use.
      respect_env: if True (default), ``CSTORM_MALLOC=system`` in the environment leaves
        the allocator unchanged (returns False).
      late: what to do when JAX's backend has started already (XLA's worker threads then
        keep their own arenas, and the change does not reach their buffers): ``"warn"``
        (default: change it anyway and warn, RuntimeWarning) or ``"skip"`` (leave it,
        return False; what the command line does when run inside a host program).
    Returns:
      True if the allocator was changed (now or by an earlier call), False where it was
      not: not glibc, ``CSTORM_MALLOC=system``, ``late="skip"`` after JAX started, or
      ``mallopt`` refused.
    """
    if isinstance(retain_bytes, bool) or not isinstance(retain_bytes, int) or retain_bytes < 0:
        raise ValueError(f"tune_allocator: retain_bytes must be an int >= 0, got {retain_bytes!r}")
    if late not in ("warn", "skip"):
        raise ValueError(f"tune_allocator: late must be 'warn' or 'skip', got {late!r}")
    global _tuned
    if respect_env and os.environ.get("CSTORM_MALLOC", "").strip().lower() == "system":
        return False
    if _tuned:
        return True
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    started = _backend_started()
    if started and late == "skip":
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # pragma: no cover - glibc without mallopt
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    trim = min(retain_bytes, 2**31 - 1)  # mallopt takes a C int
    ok = all(mallopt(p, v) == 1 for p, v in ((_M_ARENA_MAX, 1), (_M_MMAP_MAX, 0), (_M_TRIM_THRESHOLD, trim)))
    if not ok:  # pragma: no cover - glibc refused a parameter
        return False
    _tuned = True
    if started:
        warnings.warn("cstorm.tune_allocator: JAX's backend has already started, so XLA's worker threads keep "
                      "their own malloc arenas and their large buffers are still mapped afresh on every call; "
                      "call it before the first JAX computation", RuntimeWarning, stacklevel=2)
    return True
