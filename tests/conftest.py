import os
import sys

import jax

jax.config.update("jax_enable_x64", True)
# Persistent compilation cache for local re-runs (scripts/test.sh sets CSTORM_JAX_CACHE);
# CI runs on a fresh clone with it empty, where it gains nothing, so it is off there, also
# for the CLI run in-process (cli._setup_jax reads the same variable; empty = off).
_cache = os.environ.get("CSTORM_JAX_CACHE", "")
os.environ["CSTORM_JAX_CACHE"] = _cache
if _cache:
    jax.config.update("jax_compilation_cache_dir", os.path.abspath(_cache))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)

sys.path.insert(0, os.path.dirname(__file__))
