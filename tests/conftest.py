import os
import sys

import pytest

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


@pytest.fixture(autouse=True, scope="module")
def _free_compiled_code():
    """Drop JAX's compiled executables after a test module once the worker holds 30 % of
    its memory-map limit. On CPU each executable holds memory mappings (~5,000 for one
    tumbler problem; the largest module, test_derivatives, adds ~31,000); a worker that
    kept every module's code passed Linux's vm.max_map_count (65,530) late in the suite,
    and XLA's compiler segfaults (see cstorm.mapguard). Clearing only above 30 % keeps
    the recompiles that clearing after every module would cost."""
    yield
    from cstorm.mapguard import relieve_map_pressure

    relieve_map_pressure(fraction=0.3, where="test-suite", warn=False)


@pytest.fixture(scope="session")
def acrobot_problem():
    """The acrobot swing-up (`cstorm.examples.acrobot`) on a short grid (3 s, 16 control
    points, dt 0.02), shared by the optimize test modules so that its functions compile
    once per test process. Tests that change it restore it (``monkeypatch``)."""
    from cstorm import examples

    return examples.get("acrobot")(t_final=3.0, n_ctrl=16, dt=0.02)


@pytest.fixture(scope="session")
def acrobot_solution(acrobot_problem):
    """`acrobot_problem` solved by SLSQP (at most 300 iterations)."""
    from cstorm.optimize import solve

    return solve(acrobot_problem, max_iter=300)


#: seconds per test module on 2 workers (`pytest -n 2 --dist loadfile --durations=0`;
#: setup + call + teardown, compile included). Only the order matters: the modules are
#: handed to the workers longest first (scripts/test.sh passes ``--no-loadscope-reorder``,
#: so xdist keeps this order instead of sorting by test count), which keeps the two
#: workers finishing together. A module missing here counts as 30 s.
MODULE_SECONDS = {
    "test_derivatives": 368, "test_hopping": 246, "test_geometry": 205, "test_tumbler": 179,
    "test_rollout_tangents": 159, "test_dynamics": 144, "test_walker": 136,
    "test_contact_jacobians": 97, "test_stepcheck": 94, "test_pinocchio": 66, "test_hopper": 55,
    "test_jumper": 52, "test_mujoco": 51, "test_docs": 49, "test_contact": 48, "test_cli": 44,
    "test_ddp": 150, "test_robustness": 120,
    "test_problem": 70, "test_solve": 55, "test_sequence": 25, "test_solution": 15,
}


def pytest_collection_modifyitems(config, items):
    """Order the test modules longest first (stable within a module, so module-scoped
    fixtures and compiled functions are still shared by consecutive tests)."""
    def weight(item):
        return MODULE_SECONDS.get(item.path.stem, 30)

    items.sort(key=lambda item: -weight(item))
