"""Shared benchmark helpers: locating example-robot-data URDFs, timing, tables."""

from __future__ import annotations

import os
import platform
import time

import jax

from cstorm.allocator import allocator_tuned

jax.config.update("jax_enable_x64", True)


def erd_dir() -> str:
    """Directory of example-robot-data's robots (the pip package ships only data)."""
    import site

    for base in site.getsitepackages() + [site.getusersitepackages()]:
        d = os.path.join(base, "cmeel.prefix", "share", "example-robot-data", "robots")
        if os.path.isdir(d):
            return d
    raise RuntimeError("example-robot-data is not installed (pip install example-robot-data)")


def erd_urdf(rel: str) -> str:
    return os.path.join(erd_dir(), rel)


def time_compile(fn, *args):
    """(compiled, seconds) for jit-compiling fn on args."""
    t0 = time.perf_counter()
    compiled = jax.jit(fn).lower(*args).compile()
    return compiled, time.perf_counter() - t0


def best_of(fn, repeat=5, number=1, warmup=0):
    """Best wall time of `number` calls of fn(), over `repeat` trials (seconds per call),
    after `warmup` untimed calls. Batched calls with large outputs need a warm-up: the
    first calls of a compiled function fault their buffers in page by page until the heap
    holds enough freed blocks to reuse (TALOS hybrid derivatives, batch 4096, 370 MB of
    outputs and temporaries: 458, 246, then 92 us per configuration, 163k, 95k, then 0
    minor page faults per call)."""
    for _ in range(warmup):
        jax.block_until_ready(fn())
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            out = fn()
        jax.block_until_ready(out)
        best = min(best, (time.perf_counter() - t0) / number)
    return best


def machine() -> str:
    malloc = "malloc tuned (cstorm.tune_allocator)" if allocator_tuned() else "malloc: system defaults"
    return (f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, {platform.system()}, "
            f"jax {jax.__version__} ({jax.default_backend()}), {malloc}")


def table(rows, headers) -> str:
    out = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    for r in rows:
        out.append("| " + " | ".join(str(x) for x in r) + " |")
    return "\n".join(out)
