"""`cstorm.tune_allocator`: with it, a compiled function whose temporary buffer is larger
than glibc's mmap threshold (32 MB) stops faulting that buffer in afresh on every call;
the switches that leave the allocator alone. Each case runs in a fresh interpreter (the
setting is process-wide and must precede JAX's backend), so the test worker's own
allocator is never changed."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys

import pytest

import cstorm as cs

GLIBC = platform.system() == "Linux" and platform.libc_ver()[0] == "glibc"

# A jitted function with a ~65 MB input and intermediates of the same size, called in four
# rounds of 5 after a warm-up; prints the tuning result and the minor page faults per call
# (the fewest of the rounds) as JSON.
_PROBE = r"""
import json, resource, sys, warnings
import cstorm
mode = sys.argv[1]
tuned = None
with warnings.catch_warnings(record=True) as w:
    warnings.simplefilter("always")
    if mode == "tune":
        tuned = cstorm.tune_allocator()
    import jax, jax.numpy as jnp
    x = jnp.ones((4096, 2000))
    if mode == "late":
        tuned = cstorm.tune_allocator()
    if mode == "late-skip":
        tuned = cstorm.tune_allocator(late="skip")
f = jax.jit(lambda x: jnp.sum(jnp.sin(x) * jnp.cos(x)[::-1], axis=1) + jnp.sum(jnp.exp(x) * jnp.tanh(x)[:, ::-1], axis=1))
jax.block_until_ready(f(x))
rounds = []  # the heap settles within a few calls: the quietest of four rounds
for _ in range(4):
    r0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(5):
        jax.block_until_ready(f(x))
    rounds.append((resource.getrusage(resource.RUSAGE_SELF).ru_minflt - r0) / 5)
faults = min(rounds)
print(json.dumps(dict(tuned=tuned, faults=faults, state=cstorm.allocator.allocator_tuned(),
                      warned=[str(m.message) for m in w if issubclass(m.category, RuntimeWarning)])))
"""


def _python(code, *args, **env):
    """The last line that a fresh interpreter running ``code`` prints (environment:
    this one's without ``CSTORM_MALLOC``, plus ``env``)."""
    e = {k: v for k, v in os.environ.items() if k != "CSTORM_MALLOC"}
    e.update(env)
    out = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, env=e, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout.strip().splitlines()[-1]


def _probe(mode, **env):
    return json.loads(_python(_PROBE, mode, **env))


@pytest.mark.skipif(not GLIBC, reason="tune_allocator acts on glibc only")
def test_large_temporary_buffer_is_reused_once_tuned():
    default = _probe("none")
    assert default["tuned"] is None and not default["state"]
    # glibc's defaults: the ~65 MB buffer is mapped afresh per call (16,000 4 KB pages)
    assert default["faults"] > 5000, default
    # page faults also count the machine's memory pressure: on a loaded machine one
    # interpreter of three may fault some pages in again, so the quietest of up to three
    # decides (a tuning without effect faults ~16,000 pages a call in all three)
    for _ in range(3):
        tuned = _probe("tune")
        assert tuned["tuned"] is True and tuned["state"] and not tuned["warned"]
        if tuned["faults"] < 0.05 * default["faults"]:
            break
    assert tuned["faults"] < 0.05 * default["faults"], (tuned, default)


@pytest.mark.skipif(not GLIBC, reason="tune_allocator acts on glibc only")
def test_switches_that_leave_the_allocator_alone():
    off = _probe("tune", CSTORM_MALLOC="system")
    assert off["tuned"] is False and not off["state"]
    skipped = _probe("late-skip")  # after JAX started, as the CLI inside a host program
    assert skipped["tuned"] is False and not skipped["state"] and not skipped["warned"]
    late = _probe("late")
    assert late["tuned"] is True and any("before the first JAX computation" in m for m in late["warned"])
    # too late to reach XLA's worker threads: the faults stay
    assert late["faults"] > 5000, late


def test_bad_arguments():
    with pytest.raises(ValueError, match="retain_bytes"):
        cs.tune_allocator(-1)
    with pytest.raises(ValueError, match="retain_bytes"):
        cs.tune_allocator(True)
    with pytest.raises(ValueError, match="late"):
        cs.tune_allocator(late="never")


def test_import_does_not_start_jax():
    """Importing cstorm (and its CLI and examples) computes nothing with JAX, so a
    program can still tune the allocator (or choose JAX's platform) after the import."""
    code = ("import cstorm, cstorm.cli, cstorm.examples.tumbler, cstorm.viz\n"
            "from jax._src import xla_bridge\nprint(xla_bridge.backends_are_initialized())")
    assert _python(code) == "False"
