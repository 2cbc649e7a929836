"""``platoon-evaluate``: PPC against learned policies on the same workspaces and seeds.

Every policy × scenario × episode is one row of ``OUT/results.csv`` (written as episodes
finish, so an interrupted run keeps them, and a re-run with the same ``--out`` resumes where it
stopped). Then ``OUT/summary.md`` aggregates them with 95 % confidence intervals, and
``OUT/plots/`` holds per-scenario comparisons (trajectories, errors against the constraints,
velocity commands) and a GIF of one episode per policy and scenario.

With no arguments it runs the default benchmark: PPC against every shipped model
(``models/*/model.zip``) on the paper's three studies and the held-out procedural test set.

Policies (``--policy``, repeatable): ``ppc`` (the paper's law, :class:`baselines.PPCPolicy`),
``last_seen`` (ref. [32]'s last-seen baseline, :class:`baselines.LastSeenPolicy`),
``NAME=PATH`` (a model saved by ``platoon-train``; PATH is ``DIR`` or ``DIR/model.zip``).
Each policy runs at its own control period: PPC at the env's default, a learned model at the
period it was trained with (recorded in its ``model.json``); metrics are in seconds and metres,
so they compare across periods.

.. warning::
    Loading a model unpickles code: evaluate only model files you trust.
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import time
from collections import defaultdict
from collections.abc import Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

import platoon_env
from platoon_env.rollout import METRIC_NAMES, Episode, PolicyLike, episode_metrics, run_episode

#: The shipped models live here (a source checkout; see models/README.md).
MODELS_DIR = Path(__file__).resolve().parents[1] / "models"
DEFAULT_SCENARIOS = ("study_a", "study_b", "study_c", "procedural_test")
CSV_COLUMNS: tuple[str, ...] = ("policy", "scenario", "seed", *METRIC_NAMES)


@dataclass(frozen=True)
class PolicySpec:
    """A policy to evaluate: its display name and how to build it (``ppc`` or a model path)."""

    name: str
    kind: str  # "ppc" | "model"
    path: Path | None = None

    @classmethod
    def parse(cls, text: str) -> PolicySpec:
        """``ppc`` or ``NAME=PATH`` (or a bare PATH, named after its folder)."""
        if text == "ppc":
            return cls("ppc", "ppc")
        if text == "last_seen":
            return cls("last_seen", "last_seen")
        name, sep, path = text.partition("=")
        if not sep:
            path, name = (
                text,
                Path(text).resolve().parent.name if text.endswith(".zip") else Path(text).name,
            )
        p = Path(path)
        model = p if p.suffix == ".zip" else p / "model.zip"
        if not model.is_file():
            raise argparse.ArgumentTypeError(f"--policy {text!r}: no model file at {model}")
        return cls(name, "model", model)


def build(spec: PolicySpec, scenario: str) -> tuple[platoon_env.PlatoonParallelEnv, PolicyLike]:
    """The env (at the policy's control period) and the policy for one scenario."""
    if spec.kind == "ppc":
        from baselines.ppc import PPCPolicy

        env = platoon_env.make(scenario)
        return env, PPCPolicy(env)
    if spec.kind == "last_seen":
        from baselines.last_seen import LastSeenPolicy

        env = platoon_env.make(scenario)
        return env, LastSeenPolicy(env)
    from training.policies import LearnedPolicy

    assert spec.path is not None
    learned = LearnedPolicy.load(spec.path)
    env = platoon_env.make(scenario, control_period=learned.control_period)
    return env, learned


def run_job(
    spec: PolicySpec, scenario: str, seed: int, keep: bool
) -> tuple[dict[str, Any], Episode | None]:
    """One episode; returns its CSV row and (if ``keep``) the recorded episode for plots."""
    import torch

    torch.set_num_threads(1)
    env, policy = build(spec, scenario)
    ep = run_episode(env, policy, seed=seed, record_signals=keep)
    row = {"policy": spec.name, "scenario": scenario, "seed": seed, **episode_metrics(ep)}
    return row, ep if keep else None


def _read_rows(path: Path) -> list[dict[str, str]]:
    if not path.is_file():
        return []
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def _format(value: Any) -> str:
    if isinstance(value, float):
        return "inf" if math.isinf(value) else f"{value:.6g}"
    return str(value)


def wilson(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score interval of a proportion (95 % by default)."""
    if n == 0:
        return (math.nan, math.nan)
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return (max(0.0, centre - half), min(1.0, centre + half))


def mean_ci(values: Sequence[float], z: float = 1.96) -> str:
    """``mean ± half-width`` of a normal-approximation 95 % interval (finite values only)."""
    vals = np.array([v for v in values if math.isfinite(v)], dtype=float)
    if vals.size == 0:
        return "–"
    if vals.size == 1:
        return f"{vals[0]:.3f}"
    half = z * float(np.std(vals, ddof=1)) / math.sqrt(vals.size)
    return f"{np.mean(vals):.3f} ± {half:.3f}"


def summarise(rows: Iterable[dict[str, str]]) -> str:
    """The markdown table of ``summary.md``: one line per scenario × policy."""
    groups: dict[tuple[str, str], list[dict[str, str]]] = defaultdict(list)
    for r in rows:
        groups[(r["scenario"], r["policy"])].append(r)
    lines = [
        "| scenario | policy | episodes | success [95% CI] | violations by cause | "
        "rms e_d [m] | rms e_beta [rad] | min clearance [m] | min robot distance [m] | "
        "peak u [m/s] | peak omega [rad/s] | funnel exits |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for (scenario, policy), rs in sorted(groups.items()):
        n = len(rs)
        ok = sum(r["success"] == "True" for r in rs)
        lo, hi = wilson(ok, n)
        causes: dict[str, int] = defaultdict(int)
        for r in rs:
            if r["violation"]:
                causes[r["violation"]] += 1
        viol = ", ".join(f"{c} {k}" for c, k in sorted(causes.items())) or "none"

        def f(key: str, rs: list[dict[str, str]] = rs) -> list[float]:
            return [float(r[key]) for r in rs]

        lines.append(
            f"| {scenario} | {policy} | {n} | {ok}/{n} [{lo:.2f}, {hi:.2f}] | {viol} | "
            f"{mean_ci(f('rms_e_d'))} | {mean_ci(f('rms_e_beta'))} | "
            f"{min(f('min_obstacle_clearance')):.3f} | {min(f('min_inter_robot_distance')):.3f} | "
            f"{max(f('peak_u')):.2f} | {max(f('peak_omega')):.2f} | "
            f"{sum(int(r['funnel_exits']) for r in rs)} |"
        )
    return "\n".join(lines)


def plot_scenario(scenario: str, episodes: dict[str, Episode], out: Path) -> list[Path]:
    """Comparison plots of one scenario (one episode per policy) and a GIF per policy."""
    from platoon_env.plots import (
        new_figure,
        plot_commands,
        plot_errors,
        plot_snapshots,
        save_figure,
        save_gif,
    )

    names = sorted(episodes)
    eps = [episodes[k] for k in names]
    # The workspace the plotted episodes ran on: reset with their seed draws it as they did
    # (a procedural source's layout of that seed; a fixed source's one scenario, no draw).
    env = platoon_env.make(scenario)
    env.reset(seed=eps[0].seed)
    sc = env.scenario
    xmin, ymin, xmax, ymax = sc.workspace.bounds
    aspect = (ymax - ymin) / max(xmax - xmin, 1e-9)
    width = 7.0
    fig = new_figure(width, len(names) * max(2.5, width * aspect) + 0.5)
    for k, (name, ep) in enumerate(zip(names, eps, strict=True)):
        plot_snapshots(
            fig.add_subplot(len(names), 1, k + 1),
            sc,
            ep,
            n_snapshots=5,
            title=f"{scenario}, seed {ep.seed}: {name}",
        )
    paths = [save_figure(fig, out / f"{scenario}_trajectories.png")]
    n = sc.config.followers
    followers = [1, n] if n > 2 else None
    fig = new_figure(9, 1.2 + 1.4 * (len(followers) if followers else n))
    plot_errors(fig, sc, eps, labels=names, followers=followers)
    fig.suptitle(f"{scenario}, seed {eps[0].seed}: errors and safety limits (dashed)")
    paths.append(save_figure(fig, out / f"{scenario}_errors.png"))
    fig = new_figure(9, 1.2 + 1.2 * (len(followers) if followers else n))
    plot_commands(fig, sc, eps, labels=names, followers=followers)
    fig.suptitle(f"{scenario}, seed {eps[0].seed}: velocity commands")
    paths.append(save_figure(fig, out / f"{scenario}_commands.png"))
    for name, ep in zip(names, eps, strict=True):
        paths.append(save_gif(sc, ep, out / f"{scenario}_{name}.gif", frame_every=1.0, size_px=360))
    return paths


def default_policies() -> list[PolicySpec]:
    """PPC and every shipped model."""
    specs = [PolicySpec("ppc", "ppc")]
    for model in sorted(MODELS_DIR.glob("*/model.zip")):
        specs.append(PolicySpec(model.parent.name, "model", model))
    return specs


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="platoon-evaluate",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--policy",
        action="append",
        type=PolicySpec.parse,
        default=None,
        help="ppc or NAME=PATH (repeatable); default: ppc and every shipped model",
    )
    parser.add_argument(
        "--scenario",
        action="append",
        default=None,
        help=f"name or YAML path (repeatable); default: {', '.join(DEFAULT_SCENARIOS)}",
    )
    parser.add_argument("--episodes", type=int, default=5, help="episodes per policy and scenario")
    parser.add_argument(
        "--seed", type=int, default=0, help="first seed; episodes use seed..seed+K-1"
    )
    parser.add_argument("--out", type=Path, default=Path("results/benchmark"), help="output folder")
    parser.add_argument(
        "--workers", type=int, default=min(2, os.cpu_count() or 1), help="parallel worker processes"
    )
    parser.add_argument("--no-plots", action="store_true", help="skip plots and GIFs")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error("--episodes must be >= 1")
    args.policy = args.policy or default_policies()
    args.scenario = args.scenario or list(DEFAULT_SCENARIOS)
    names = [p.name for p in args.policy]
    if len(set(names)) != len(names):
        parser.error(f"policy names must be unique, got {names}")
    for s in args.scenario:
        platoon_env.scenarios.load_config(s)  # fail fast on a bad scenario
    return args


def main(argv: Sequence[str] | None = None) -> int:
    """Run the evaluation; returns the process exit code (130 when interrupted)."""
    args = parse_args(argv)
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / "results.csv"
    done = {(r["policy"], r["scenario"], int(r["seed"])) for r in _read_rows(csv_path)}
    seeds = range(args.seed, args.seed + args.episodes)
    jobs = [
        (spec, scenario, seed)
        for scenario in args.scenario
        for spec in args.policy
        for seed in seeds
        if (spec.name, scenario, seed) not in done
    ]
    if done:
        print(f"resuming {csv_path}: {len(done)} episodes done, {len(jobs)} to run")
    kept: dict[str, dict[str, Episode]] = defaultdict(dict)
    start = time.perf_counter()
    new_file = not csv_path.is_file() or csv_path.stat().st_size == 0
    interrupted = False
    with csv_path.open("a", newline="") as f, ProcessPoolExecutor(max_workers=args.workers) as pool:
        writer = csv.DictWriter(f, fieldnames=CSV_COLUMNS)
        if new_file:
            writer.writeheader()
        futures = {
            pool.submit(
                run_job, spec, scenario, seed, keep=seed == args.seed and not args.no_plots
            ): (spec.name, scenario)
            for spec, scenario, seed in jobs
        }
        try:
            for fut in tqdm(as_completed(futures), total=len(futures), desc="episodes", unit="ep"):
                row, ep = fut.result()
                writer.writerow({k: _format(row[k]) for k in CSV_COLUMNS})
                f.flush()
                os.fsync(f.fileno())
                if ep is not None:
                    kept[row["scenario"]][row["policy"]] = ep
        except KeyboardInterrupt:
            interrupted = True
            for fut in futures:
                fut.cancel()
            print(f"\ninterrupted: finished episodes are in {csv_path}; re-run to resume")
    if interrupted:
        return 130
    rows = _read_rows(csv_path)
    summary = summarise(
        r
        for r in rows
        if r["policy"] in {p.name for p in args.policy} and r["scenario"] in set(args.scenario)
    )
    elapsed = time.perf_counter() - start
    header = (
        f"# platoon-evaluate\n\npolicies: {', '.join(p.name for p in args.policy)}; "
        f"scenarios: {', '.join(args.scenario)}; episodes: {args.episodes} (seeds {args.seed}.."
        f"{args.seed + args.episodes - 1}); wall time of this run: {elapsed:.0f} s; "
        f"platoon_env {platoon_env.__version__}\n\n"
    )
    (out / "summary.md").write_text(header + summary + "\n")
    print(summary)
    if not args.no_plots:
        missing = [
            (spec, scenario)
            for scenario in args.scenario
            for spec in args.policy
            if spec.name not in kept[scenario]
        ]
        for spec, scenario in tqdm(
            missing, desc="episodes for plots", unit="ep", disable=not missing
        ):
            kept[scenario][spec.name] = run_job(spec, scenario, args.seed, keep=True)[1]  # type: ignore[assignment]
        for scenario in tqdm(args.scenario, desc="plots", unit="scenario"):
            plot_scenario(scenario, kept[scenario], out / "plots")
    print(
        f"wrote {csv_path}, {out / 'summary.md'}" + ("" if args.no_plots else f", {out / 'plots'}/")
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
