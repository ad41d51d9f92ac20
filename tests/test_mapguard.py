"""`cstorm.mapguard`: compiled code's memory mappings are returned when the process
nears vm.max_map_count (Linux; XLA's compiler segfaults past it)."""


import jax
import jax.numpy as jnp
import pytest

from cstorm import mapguard

pytestmark = pytest.mark.skipif(mapguard.map_usage() is None, reason="needs /proc (Linux)")


def test_usage_is_counted():
    n, limit = mapguard.map_usage()
    assert 0 < n < limit


def test_relief_clears_compiled_code():
    fns = [jax.jit(lambda x, k=k: jnp.sin(x) * k + jnp.cos(x) ** 2) for k in range(100)]
    for f in fns:
        f(jnp.ones(3)).block_until_ready()
    before = mapguard.map_usage()[0]
    assert mapguard.relieve_map_pressure(fraction=2.0) is False  # far from the limit: nothing
    with pytest.warns(RuntimeWarning, match=r"max_map_count.*compilation caches were cleared"):
        assert mapguard.relieve_map_pressure(fraction=0.0, where="test") is True
    assert mapguard.relieve_map_pressure(fraction=0.0, warn=False) is True  # quiet variant
    after = mapguard.map_usage()[0]
    assert after < before - 150, (before, after)  # ~3 mappings per small executable
    assert float(fns[7](jnp.ones(3))[0]) == pytest.approx(7 * float(jnp.sin(1.0)) + float(jnp.cos(1.0)) ** 2)
