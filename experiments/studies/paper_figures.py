"""The paper's figures for the shipped studies, and PPC's record over several seeds.

Usage::

    python -m experiments.studies.paper_figures [--out docs/figures] [--seeds 20] [--workers 2]
                                      [--study study_c ...]

For each study: the platoon's snapshots with fields of view (Fig. 5, 12), the distance and
angle errors inside their performance functions with the safety limits (Fig. 6, 13, 14), and
the velocity commands (Fig. 7, 10, 11), from the seed-0 episode at the env's default settings.
Then every study is run for ``--seeds`` seeds through the shared grid runner
(:func:`experiments.grid.run_grid`, episodes stored in ``--store`` so a re-run resumes), and a
markdown table of violations, funnel exits and errors, under the run's metadata stamp, is
written to ``OUT/ppc_record.md`` (and printed).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from tqdm import tqdm

import platoon_env
from baselines.ppc import PPCPolicy
from experiments.cli import add_grid_options, new_parser, open_store
from experiments.grid import Cell, run_grid
from experiments.policies import PolicySpec
from experiments.report import provenance_markdown, seed_ranges, wilson, write_text_atomic
from experiments.stamp import metadata_stamp, png_metadata
from experiments.store import Store
from experiments.suites import STUDIES
from platoon_env.plots import new_figure, plot_commands, plot_errors, plot_snapshots, save_figure
from platoon_env.rollout import run_episode

PPC = PolicySpec.of("ppc", "PPC")
_TOOL = "python -m experiments.studies.paper_figures"
#: The default ``--store``: the episodes of every run, so that a re-run resumes.
_STORE = Path("results/paper_figures/results.sqlite")


def figures(study: str, out: Path, metadata: dict[str, str] | None = None) -> list[Path]:
    """Draw the three figures of ``study`` from its seed-0 PPC episode; return their paths
    (``metadata``: the PNG text fields, e.g. the run's stamp)."""
    env = platoon_env.make(study)
    ep = run_episode(env, PPCPolicy(env), seed=0)
    sc = env.scenario
    xmin, ymin, xmax, ymax = sc.workspace.bounds
    aspect = (ymax - ymin) / (xmax - xmin)
    fig = new_figure(9, max(3.0, 9 * aspect + 0.6))
    plot_snapshots(fig.add_subplot(), sc, ep, n_snapshots=8)
    paths = [save_figure(fig, out / f"{study}_snapshots.png", metadata)]
    n = sc.config.followers
    fig = new_figure(9, 1.0 + 1.3 * n)
    plot_errors(fig, sc, [ep], labels=["PPC"])
    fig.suptitle(f"{study}: errors (blue), performance functions (red), safety limits (dashed)")
    paths.append(save_figure(fig, out / f"{study}_errors.png", metadata))
    fig = new_figure(9, 1.0 + 1.1 * n)
    plot_commands(fig, sc, [ep])
    fig.suptitle(f"{study}: PPC velocity commands")
    paths.append(save_figure(fig, out / f"{study}_commands.png", metadata))
    return paths


def record(studies: list[str], seeds: int, store: Store, workers: int = 1, argv: Any = None) -> str:
    """Run PPC on every study for ``seeds`` seeds (into ``store``); return a markdown table
    of the outcome under the run's stamp."""
    cells = [Cell.of(PPC, s, k) for s in studies for k in range(seeds)]
    stamp = metadata_stamp(_TOOL, {"seeds": seeds, "studies": studies}, argv)
    result = run_grid(store, cells, tool=_TOOL, stamp=stamp, workers=workers)
    if result.interrupted:
        raise SystemExit(130)
    provenance = provenance_markdown(store, result.records.values(), result.run_id)
    per_study: dict[str, list[dict[str, Any]]] = {s: [] for s in studies}
    for rc, rec in result.finished():
        per_study[rc.cell.scenario].append(rec.metrics)
    rows = [
        "# PPC on the paper's studies\n",
        f"{len(result.finished())} episodes ({result.ran} run now, {result.reused} from the "
        f"store); {len(result.failed)} failed.\n",
        provenance,
    ]
    header = (
        "| study | control period [s] | seeds | successes [95% CI] | violations | funnel exits | "
        "max rms e_d [m] | max rms e_beta [rad] | min clearance [m] | peak u [m/s] | "
        "peak omega [rad/s] |"
    )
    rows.append(header)
    rows.append("|" + "---|" * (header.count("|") - 1))
    for study in studies:
        ms = per_study[study]
        if not ms:
            continue
        period = platoon_env.make(study).control_period
        ok = sum(bool(m["success"]) for m in ms)
        lo, hi = wilson(ok, len(ms))
        rows.append(
            f"| {study} | {period:g} | {seed_ranges(range(seeds))} | "
            f"{ok}/{len(ms)} [{lo:.2f}, {hi:.2f}] | "
            f"{sum(1 for m in ms if m['violation'])} | {sum(int(m['funnel_exits']) for m in ms)} | "
            f"{max(float(m['rms_e_d']) for m in ms):.3f} | "
            f"{max(float(m['rms_e_beta']) for m in ms):.3f} | "
            f"{min(float(m['min_obstacle_clearance']) for m in ms):.3f} | "
            f"{max(float(m['peak_u']) for m in ms):.2f} | "
            f"{max(float(m['peak_omega']) for m in ms):.2f} |"
        )
    if result.failed:
        rows.append(f"\n{len(result.failed)} episode(s) failed; re-run to retry them.")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> None:
    parser = new_parser(_TOOL, __doc__, out=Path("docs/figures"))
    add_grid_options(parser, seeds=20, seeds_help="seeds per study for the record", store=_STORE)
    parser.add_argument("--study", action="append", choices=STUDIES, help="default: all three")
    args = parser.parse_args(argv)
    studies = args.study or list(STUDIES)
    stamp = png_metadata(metadata_stamp(_TOOL, {"seeds": 0, "studies": studies}, argv))
    with open_store(_TOOL, args.store) as store:  # a store that is not ours: refused first
        for study in tqdm(studies, desc="figures", unit="study"):
            for path in figures(study, args.out, stamp):
                tqdm.write(f"wrote {path}")
        table = record(studies, args.seeds, store, args.workers, argv)
    args.out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(args.out / "ppc_record.md", table + "\n")
    print(table)


if __name__ == "__main__":
    main()
