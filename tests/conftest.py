import os
import sys

import jax

jax.config.update("jax_enable_x64", True)
# persistent compilation cache: CI re-runs and local runs reuse compiled XLA programs
_cache = os.environ.get("CSTORM_JAX_CACHE", os.path.join(os.path.dirname(__file__), "..", ".jax_cache"))
jax.config.update("jax_compilation_cache_dir", os.path.abspath(_cache))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)

sys.path.insert(0, os.path.dirname(__file__))
