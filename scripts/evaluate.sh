#!/usr/bin/env bash
# Set up ./.venv and run the default benchmark: PPC against the shipped learned models on the
# paper's three studies and the held-out procedural workspaces. Results go to results/.
# Extra arguments go to platoon-evaluate (see `platoon-evaluate --help`).
# platoon-evaluate prints its own wall time and writes it in results/benchmark/summary.md; this
# script adds the set-up's (creating .venv and installing the packages: minutes from a fresh
# clone, seconds after).
set -euo pipefail
cd "$(dirname "$0")/.."
start=$SECONDS
bash scripts/setup.sh
setup=$((SECONDS - start))
export MPLBACKEND=Agg
status=0
.venv/bin/platoon-evaluate "$@" || status=$?
echo "scripts/evaluate.sh: $((SECONDS - start)) s in all, of which ${setup} s of set-up (scripts/setup.sh)"
exit "$status"
