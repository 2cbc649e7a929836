#!/usr/bin/env bash
# The residual configurations (residual_ppc, residual_filtered_aruco, residual_drive_aruco;
# docs/training.md) beside the PPC law, the filtered PPC and the drive-aware filtered PPC on the
# paper's studies A, B and C, 20 episodes per task:
#   bash scripts/evaluate_residual.sh [ideal] [aruco]      # default: both conditions
#   bash scripts/evaluate_residual.sh --shipped [...]      # the shipped models/ runs
# Trains what runs/sweep lacks first (platoon-sweep: five seeds each, finished runs kept; about
# 80 minutes on 2 cores), draws their learning curves (docs/figures/learning_curves_residual.png),
# then evaluates (with --shipped: no training, the runs the README's tables evaluated, as
# shipped in models/<config>_s<seed>): results/residual_paper_<condition>/summary.md (one row
# per configuration, the successes of each training seed in its "by training seed" column) and
# results.csv.
# PYTHON names the interpreter (default: python).
set -euo pipefail
cd "$(dirname "$0")/.."
PY="${PYTHON:-python}"
CONFIGS=(residual_ppc residual_filtered_aruco residual_drive_aruco)
SHIPPED_RUNS=0
if [ "${1:-}" = --shipped ]; then SHIPPED_RUNS=1; shift; fi
CONDITIONS=("$@")
[ ${#CONDITIONS[@]} -eq 0 ] && CONDITIONS=(ideal aruco)
for c in "${CONDITIONS[@]}"; do
  case "$c" in ideal | aruco) ;; *) echo "unknown condition '$c' (ideal, aruco)" >&2; exit 2 ;; esac
done
if [ $SHIPPED_RUNS = 0 ]; then
  "$PY" -m experiments.studies.sweep --config "${CONFIGS[@]}" --runs runs/sweep
  "$PY" -m experiments.studies.sweep --config "${CONFIGS[@]}" --runs runs/sweep \
    --curves docs/figures/learning_curves_residual.png
fi
POLICIES=()
for config in "${CONFIGS[@]}"; do
  for seed in 0 1 2 3 4; do
    run="runs/sweep/${config}/s${seed}"
    [ $SHIPPED_RUNS = 1 ] && run="models/${config}_s${seed}"
    POLICIES+=(--policy "${config}_s${seed}=${run}")
  done
done
POLICIES+=(--policy ppc --policy filtered_ppc --policy filtered_ppc_drive)
for c in "${CONDITIONS[@]}"; do
  realism=()
  [ "$c" = aruco ] && realism=(--sensor-profile aruco)
  "$PY" -m experiments.studies.evaluate "${POLICIES[@]}" "${realism[@]}" \
    --scenario study_a --scenario study_b --scenario study_c --episodes 20 \
    --out "results/residual_paper_$c" --no-plots --workers 2 --batch 20
done
