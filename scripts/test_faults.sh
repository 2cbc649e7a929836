#!/usr/bin/env bash
# The fault family in ./.venv: the tests marked `faults` (pytest -m faults), which the default
# suite leaves out: kill -9 of an evaluator mid-run and its resume, SIGTERM, SIGINT and SIGKILL
# of a platoon-sweep parent (no training outlives it), a store on a full disk (a small tmpfs in
# a mount namespace of its own: as root, or as root of a user namespace; skipped, saying why,
# where none can be mounted). One test at a time: they time and count processes. Extra
# arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export MPLBACKEND=Agg
echo "== pytest (faults)"
.venv/bin/python -m pytest -m faults -rs "$@"
