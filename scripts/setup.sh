#!/usr/bin/env bash
# Create a venv (Python 3.11) and install platoon_env (editable) with extras into it.
#   bash scripts/setup.sh                      # ./.venv with every extra but rllib, torchrl, bench
#   bash scripts/setup.sh VENV EXTRAS          # e.g. .venv-rllib train,plot,dev,rllib
# torch==2.13.0 is named in the same pip command as the extras: any other torch request pulls a
# multi-GB CUDA build (see README). PYTHON names the interpreter (default python3.11, python3).
set -euo pipefail
cd "$(dirname "$0")/.."
VENV="${1:-.venv}"
EXTRAS="${2:-train,plot,stats,tune,dev}"
PY="${PYTHON:-}"
if [ -z "$PY" ]; then
  if command -v python3.11 >/dev/null 2>&1; then PY=python3.11; else PY=python3; fi
fi
if [ ! -x "$VENV/bin/python" ]; then
  "$PY" -m venv "$VENV"
fi
"$VENV/bin/python" -m pip install -q --upgrade pip
"$VENV/bin/python" -m pip install -q "torch==2.13.0" -e ".[$EXTRAS]"
# Compile the kernels the default benchmark calls now (about a minute in a fresh clone, seconds
# once cached): the first run of the main job then starts at once.
"$VENV/bin/python" scripts/compile_kernels.py
