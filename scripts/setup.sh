#!/usr/bin/env bash
# Create ./.venv (Python 3.11) and install platoon_env with its extras (all but rllib and bench).
# torch==2.13.0 is named with them: any other torch request pulls a multi-GB CUDA build.
set -euo pipefail
cd "$(dirname "$0")/.."
PY="${PYTHON:-}"
if [ -z "$PY" ]; then
  if command -v python3.11 >/dev/null 2>&1; then PY=python3.11; else PY=python3; fi
fi
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip
# torch is named in the same command as the packages that depend on it (see README).
.venv/bin/python -m pip install -q "torch==2.13.0" -e ".[train,plot,stats,tune,dev]"
