"""The paper's figures for the shipped studies, and PPC's record over several seeds.

Usage::

    python -m baselines.paper_figures [--out docs/figures] [--seeds 5] [--study study_c ...]

For each study: the platoon's snapshots with fields of view (Fig. 5, 12), the distance and
angle errors inside their performance functions with the safety limits (Fig. 6, 13, 14), and
the velocity commands (Fig. 7, 10, 11), from the seed-0 episode at the env's default settings.
Then every study is run for ``--seeds`` seeds and a markdown table of violations, funnel exits
and errors is written to ``OUT/ppc_record.md`` (and printed).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from tqdm import tqdm

import platoon_env
from baselines.ppc import PPCPolicy
from platoon_env.plots import new_figure, plot_commands, plot_errors, plot_snapshots, save_figure
from platoon_env.rollout import Episode, episode_metrics, run_episode

STUDIES = ("study_a", "study_b", "study_c")


def figures(study: str, out: Path) -> list[Path]:
    """Draw the three figures of ``study`` from its seed-0 PPC episode; return their paths."""
    env = platoon_env.make(study)
    ep = run_episode(env, PPCPolicy(env), seed=0)
    sc = env.scenario
    xmin, ymin, xmax, ymax = sc.workspace.bounds
    aspect = (ymax - ymin) / (xmax - xmin)
    fig = new_figure(9, max(3.0, 9 * aspect + 0.6))
    plot_snapshots(fig.add_subplot(), sc, ep, n_snapshots=8)
    paths = [save_figure(fig, out / f"{study}_snapshots.png")]
    n = sc.config.followers
    fig = new_figure(9, 1.0 + 1.3 * n)
    plot_errors(fig, sc, [ep], labels=["PPC"])
    fig.suptitle(f"{study}: errors (blue), performance functions (red), safety limits (dashed)")
    paths.append(save_figure(fig, out / f"{study}_errors.png"))
    fig = new_figure(9, 1.0 + 1.1 * n)
    plot_commands(fig, sc, [ep])
    fig.suptitle(f"{study}: PPC velocity commands")
    paths.append(save_figure(fig, out / f"{study}_commands.png"))
    return paths


def record(studies: list[str], seeds: int) -> str:
    """Run PPC on every study for ``seeds`` seeds; return a markdown table of the outcome."""
    rows = []
    jobs = [(s, k) for s in studies for k in range(seeds)]
    per_study: dict[str, list[dict[str, object]]] = {s: [] for s in studies}
    for study, seed in tqdm(jobs, desc="PPC episodes", unit="ep"):
        env = platoon_env.make(study)
        ep: Episode = run_episode(env, PPCPolicy(env), seed=seed, record_signals=False)
        per_study[study].append(episode_metrics(ep))
    header = (
        "| study | control period [s] | seeds | successes | violations | funnel exits | "
        "max rms e_d [m] | max rms e_beta [rad] | min clearance [m] | peak u [m/s] | "
        "peak omega [rad/s] |"
    )
    rows.append(header)
    rows.append("|" + "---|" * (header.count("|") - 1))
    for study in studies:
        ms = per_study[study]
        period = platoon_env.make(study).control_period
        rows.append(
            f"| {study} | {period:g} | {len(ms)} | {sum(bool(m['success']) for m in ms)} | "
            f"{sum(1 for m in ms if m['violation'])} | {sum(int(m['funnel_exits']) for m in ms)} | "  # type: ignore[call-overload]
            f"{max(float(m['rms_e_d']) for m in ms):.3f} | "  # type: ignore[arg-type]
            f"{max(float(m['rms_e_beta']) for m in ms):.3f} | "  # type: ignore[arg-type]
            f"{min(float(m['min_obstacle_clearance']) for m in ms):.3f} | "  # type: ignore[arg-type]
            f"{max(float(m['peak_u']) for m in ms):.2f} | "  # type: ignore[arg-type]
            f"{max(float(m['peak_omega']) for m in ms):.2f} |"  # type: ignore[arg-type]
        )
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--out", type=Path, default=Path("docs/figures"), help="output folder")
    parser.add_argument("--seeds", type=int, default=5, help="seeds per study for the record")
    parser.add_argument("--study", action="append", choices=STUDIES, help="default: all three")
    args = parser.parse_args(argv)
    studies = args.study or list(STUDIES)
    for study in tqdm(studies, desc="figures", unit="study"):
        for path in figures(study, args.out):
            tqdm.write(f"wrote {path}")
    table = record(studies, args.seeds)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "ppc_record.md").write_text(table + "\n")
    print(table)


if __name__ == "__main__":
    main()
