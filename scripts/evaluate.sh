#!/usr/bin/env bash
# Set up ./.venv and run the default benchmark: PPC against the shipped learned models on the
# paper's three studies and the held-out procedural workspaces. Results go to results/.
# Extra arguments go to platoon-evaluate (see `platoon-evaluate --help`).
# platoon-evaluate prints its own wall time and writes it in results/benchmark/summary.md; this
# script adds the set-up's (creating .venv and installing the packages: minutes from a fresh
# clone, seconds after) and, when the run succeeded with the default output folder, writes both
# to results/benchmark/evaluate_sh.md.
set -euo pipefail
cd "$(dirname "$0")/.."
start=$SECONDS
bash scripts/setup.sh
setup=$((SECONDS - start))
export MPLBACKEND=Agg
status=0
.venv/bin/platoon-evaluate "$@" || status=$?
line="$((SECONDS - start)) s in all, of which ${setup} s of set-up (scripts/setup.sh)"
echo "scripts/evaluate.sh: $line"
# The README quotes this file (a block naming this script): the runtime of the whole command.
if [ "$status" = 0 ] && [ $# -eq 0 ] && [ -d results/benchmark ]; then
  printf -- '- `bash scripts/evaluate.sh`: %s, at commit %s%s\n' "$line" \
    "$(git rev-parse --short=12 HEAD 2>/dev/null || echo unknown)" \
    "$([ -n "$(git status --porcelain 2>/dev/null)" ] && echo ' + uncommitted changes')" \
    > results/benchmark/evaluate_sh.md
fi
exit "$status"
