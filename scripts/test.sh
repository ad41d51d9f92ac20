#!/usr/bin/env bash
# Install cstorm with its test extras (Pinocchio, MuJoCo, Gymnasium, coal, example-robot-data)
# into ./.venv and run the test-suite on all cores (slow full-length solves excluded; run
# them with `scripts/test.sh -m slow`).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e ".[test]"
if [ -z "${CI:-}" ]; then export CSTORM_JAX_CACHE="${CSTORM_JAX_CACHE:-$PWD/.jax_cache}"; fi
if [ "$#" -eq 0 ]; then set -- -m "not slow"; fi
exec .venv/bin/python -m pytest -q -n "${CSTORM_TEST_WORKERS:-auto}" --dist loadfile --no-loadscope-reorder --durations=20 "$@"
