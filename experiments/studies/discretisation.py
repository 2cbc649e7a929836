"""Discretisation study: the largest control period at which PPC keeps every constraint.

The PPC law is continuous-time; held for a control period it can push an error out of its
funnel. For each study and control period this runs PPC over several seeds (with the env's
seeded initial perturbation) and counts violations and funnel exits; the largest period with
none, over all seeds, is reported. The env's default control period is chosen from this table.

Usage::

    python -m experiments.studies.discretisation [--seeds 5] [--periods 0.005 0.01 0.02 ...]
        [--substeps 2] [--study study_a ...] [--out docs/discretisation.md] [--workers 2]
"""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from tqdm import tqdm

import platoon_env
from baselines.ppc import PPCPolicy
from experiments.cli import add_grid_options, count, new_parser, number
from experiments.report import write_text_atomic
from experiments.suites import STUDIES
from platoon_env.rollout import episode_metrics, run_episode

DEFAULT_PERIODS = (0.005, 0.01, 0.015, 0.02, 0.03, 0.04, 0.05)


def run_one(study: str, period: float, substeps: int, seed: int) -> dict[str, object]:
    """One PPC episode of ``study`` at ``period`` with ``substeps``; returns its metrics."""
    env = platoon_env.make(study, control_period=period, physics_substeps=substeps)
    m = episode_metrics(run_episode(env, PPCPolicy(env), seed=seed, record_signals=False))
    m.update(study=study, period=period, substeps=substeps, seed=seed)
    return m


def main(argv: list[str] | None = None) -> None:
    parser = new_parser("python -m experiments.studies.discretisation", __doc__)
    parser.add_argument("--study", action="append", choices=STUDIES, help="default: all")
    parser.add_argument("--periods", type=number, nargs="+", default=list(DEFAULT_PERIODS))
    parser.add_argument("--substeps", type=count(1, "substeps"), nargs="+", default=[2])
    add_grid_options(parser, seeds=5, seeds_help="seeds per study and period", store=None)
    parser.add_argument("--out", type=Path, default=None, help="also write the table here")
    args = parser.parse_args(argv)
    studies = args.study or list(STUDIES)
    jobs = [
        (s, p, k, seed)
        for s in studies
        for p in args.periods
        for k in args.substeps
        for seed in range(args.seeds)
    ]
    results: list[dict[str, object]] = []
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        futures = [pool.submit(run_one, *job) for job in jobs]
        for fut in tqdm(futures, desc="PPC episodes", unit="ep"):
            results.append(fut.result())
    lines = [
        "| study | control period [s] | substeps | seeds | violations (causes) | funnel exits "
        "| successes |",
        "|---|---|---|---|---|---|---|",
    ]
    best: dict[tuple[str, int], float] = {}
    for s in studies:
        for k in args.substeps:
            clean_so_far = True
            for p in sorted(args.periods):
                rs = [
                    r
                    for r in results
                    if r["study"] == s and r["period"] == p and r["substeps"] == k
                ]
                causes = sorted({str(r["violation"]) for r in rs if r["violation"]})
                n_viol = sum(1 for r in rs if r["violation"])
                exits = sum(int(r["funnel_exits"]) for r in rs)  # type: ignore[call-overload]
                ok = sum(bool(r["success"]) for r in rs)
                lines.append(
                    f"| {s} | {p:g} | {k} | {len(rs)} | {n_viol}"
                    f"{' (' + ', '.join(causes) + ')' if causes else ''} | {exits} | {ok} |"
                )
                if n_viol == 0 and exits == 0 and ok == len(rs) and clean_so_far:
                    best[(s, k)] = p
                else:
                    clean_so_far = False
    lines.append("")
    for (s, k), p in best.items():
        lines.append(f"- {s}, {k} substeps: largest clean control period {p:g} s")
    table = "\n".join(lines)
    print(table)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(args.out, table + "\n")


if __name__ == "__main__":
    main()
