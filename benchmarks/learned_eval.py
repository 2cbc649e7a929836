"""Episodes per second of evaluation entries in the batched evaluator, one process, one core.

Times :func:`experiments.batched_eval.run_cells` (what ``platoon-evaluate --batch`` runs) for
each ``--policy`` on ``--scenario``, over ``--episodes`` seeds in chunks of ``--batch``, after
a warm-up chunk of two episodes (numba compiles on first use), and prints a markdown table:
episodes/s and policy steps/s (one step of one copy). The episodes are run for real: the table
also gives the successes, so two versions compared on the same seeds show they ran the same
episodes.

Before/after a change, run it with each version on the path, e.g. a worktree of the older
commit: ``PYTHONPATH=/path/to/old python benchmarks/learned_eval.py`` beside
``python benchmarks/learned_eval.py`` (or both under ``farm-bench``).

    python benchmarks/learned_eval.py --policy ppc \\
        --policy r=models/residual_drive_aruco_s0 --scenario study_c --episodes 20
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Sequence


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--policy", action="append", required=True, help="as platoon-evaluate's")
    parser.add_argument("--scenario", default="study_c")
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--batch", type=int, default=20)
    args = parser.parse_args(argv)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    # Here, after OMP_NUM_THREADS is set: torch reads it at import (experiments imports torch).
    import torch

    from experiments.batched_eval import run_cells
    from experiments.grid import Cell, resolve_cells
    from experiments.policies import PolicySpec

    torch.set_num_threads(1)
    print(f"scenario {args.scenario}, {args.episodes} episodes in chunks of {args.batch}\n")
    print("| policy | episodes/s | policy steps/s | successes | seconds |")
    print("|---|---:|---:|---:|---:|")
    for text in args.policy:
        spec = PolicySpec.parse(text)
        cells = resolve_cells(
            [Cell.of(spec, args.scenario, s, ()) for s in range(args.episodes + 2)]
        )
        run_cells(cells[:2])  # warm-up: compile, load
        timed = cells[2:]
        start = time.perf_counter()
        results = []
        for k in range(0, len(timed), args.batch):
            results += run_cells(timed[k : k + args.batch])
        seconds = time.perf_counter() - start
        steps = sum(int(r.metrics.get("steps", 0) or 0) for r in results)
        wins = sum(1 for r in results if r.metrics.get("success"))
        print(
            f"| {spec.name} | {len(timed) / seconds:.2f} | {steps / seconds:,.0f} | "
            f"{wins}/{len(timed)} | {seconds:.1f} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
