#!/usr/bin/env bash
# Set up ./.venv-rllib (the [rllib] extra: Ray RLlib 2.60, which pins gymnasium==1.2.2, so it
# gets its own venv) and run the RLlib tests in it. Extra arguments go to pytest.
# torch==2.13.0 is named in the same pip command as ray: any other torch request pulls a
# multi-GB CUDA build.
set -euo pipefail
cd "$(dirname "$0")/.."
PY="${PYTHON:-}"
if [ -z "$PY" ]; then
  if command -v python3.11 >/dev/null 2>&1; then PY=python3.11; else PY=python3; fi
fi
if [ ! -x .venv-rllib/bin/python ]; then
  "$PY" -m venv .venv-rllib
fi
.venv-rllib/bin/python -m pip install -q --upgrade pip
.venv-rllib/bin/python -m pip install -q "torch==2.13.0" -e ".[train,plot,dev,rllib]"
export MPLBACKEND=Agg
# Ray must not join a cluster that happens to run on this machine.
unset RAY_ADDRESS
echo "== pytest (rllib)"
.venv-rllib/bin/python -m pytest -p no:cacheprovider tests/test_rllib.py "$@"
