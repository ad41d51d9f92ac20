#!/usr/bin/env bash
# cstorm's main job on a fresh machine: make a virtual environment, install cstorm, solve
# the demo motion (the tumbling robot: start -> handstand -> roll -> standing -> start) and
# write its files to ./cstorm-out/demo (or $1). Further arguments go to `cstorm demo`:
# --resume continues a stopped demo, --force replaces an earlier one.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e .
.venv/bin/cstorm demo --out "${1:-cstorm-out/demo}" "${@:2}"
