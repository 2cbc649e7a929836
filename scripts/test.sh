#!/usr/bin/env bash
# Set up ./.venv and run the checks: ruff, mypy, then the default (fast) test suite.
# Extra arguments go to pytest, e.g. `bash scripts/test.sh -m slow` for the long checks.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export MPLBACKEND=Agg
echo "== ruff"
.venv/bin/ruff check platoon_env baselines training experiments tests benchmarks scripts examples docs/conf.py docs/gen_env_pages.py
.venv/bin/ruff format --check platoon_env baselines training experiments tests benchmarks scripts examples docs/conf.py docs/gen_env_pages.py
echo "== mypy"
.venv/bin/mypy platoon_env baselines training experiments examples
echo "== pytest"
.venv/bin/python -m pytest -n 2 "$@"
