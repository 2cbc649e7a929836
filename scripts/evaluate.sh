#!/usr/bin/env bash
# Set up ./.venv and run the default benchmark: PPC against the shipped learned models on the
# paper's three studies and the held-out procedural workspaces. Results go to results/.
# Extra arguments go to platoon-evaluate (see `platoon-evaluate --help`).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export MPLBACKEND=Agg
.venv/bin/platoon-evaluate "$@"
