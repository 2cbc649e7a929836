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

Realism (``docs/sensing.md``): ``--sensor-profile NAME`` (a shipped profile such as ``aruco``,
or a profile YAML) and per-field overrides of the ``camera``, ``proximity`` and ``robot``
blocks, ``--camera noise.position=0.01 --camera latency=0.05 --robot accel_max=1
--proximity noise=0.01`` (``KEY[.SUB...]=VALUE``, the value read as a YAML scalar, repeatable,
applied after the profile), are passed to every env. Every row records the profile, the flags
(``realism_label``) and the resolved camera, proximity and robot blocks (``realism``, JSON);
the realism is part of the key a re-run resumes by, and ``summary.md`` has a table per realism,
so runs with different realism never mix.

.. warning::
    Loading a model unpickles code: evaluate only model files you trust.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import re
import time
from collections import defaultdict
from collections.abc import Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from tqdm import tqdm

import platoon_env
from platoon_env.rollout import METRIC_NAMES, Episode, PolicyLike, episode_metrics, run_episode
from platoon_env.scenarios.options import apply_overrides
from platoon_env.scenarios.schema import ScenarioError, config_to_mapping

#: The shipped models live here (a source checkout; see models/README.md).
MODELS_DIR = Path(__file__).resolve().parents[1] / "models"
DEFAULT_SCENARIOS = ("study_a", "study_b", "study_c", "procedural_test")
#: The scenario blocks the realism flags override, and record (resolved) with every row.
REALISM_BLOCKS: tuple[str, ...] = ("camera", "proximity", "robot")
CSV_COLUMNS: tuple[str, ...] = (
    "policy",
    "scenario",
    "seed",
    "sensor_profile",
    "realism_label",
    *METRIC_NAMES,
    "realism",
)
#: Columns a re-run resumes by: a row with the same values is not run again.
KEY_COLUMNS: tuple[str, ...] = ("policy", "scenario", "seed", "realism")
_KEY_PATTERN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*")


def parse_assignment(text: str) -> tuple[tuple[str, ...], Any]:
    """``KEY[.SUB...]=VALUE`` -> (key path, value), the value read as YAML (``0.01`` a float,
    ``null`` None, ``true`` a bool, ``[1, 2]`` a list, else a string).

    Raises :class:`argparse.ArgumentTypeError` (argparse turns it into a usage error) on a
    missing ``=``, a malformed key or a value that is not YAML.
    """
    key, sep, raw = text.partition("=")
    key = key.strip()
    if not sep:
        raise argparse.ArgumentTypeError(f"{text!r}: expected KEY=VALUE, e.g. latency=0.05")
    if not _KEY_PATTERN.fullmatch(key):
        raise argparse.ArgumentTypeError(
            f"{text!r}: bad key {key!r} (expected names joined by dots, e.g. noise.position)"
        )
    try:
        value = yaml.safe_load(raw)
    except yaml.YAMLError as exc:
        detail = str(exc).splitlines()[0]
        raise argparse.ArgumentTypeError(
            f"{text!r}: the value {raw!r} is not YAML ({detail})"
        ) from None
    return tuple(key.split(".")), value


def nest_assignments(items: Iterable[tuple[tuple[str, ...], Any]], flag: str) -> dict[str, Any]:
    """The nested mapping of ``(key path, value)`` assignments (later ones win on the same key).

    ``[(("noise", "position"), 0.01), (("latency",), 0.05)]`` ->
    ``{"noise": {"position": 0.01}, "latency": 0.05}``. A key set both to a value and to a
    mapping of sub-keys (``noise=0`` and ``noise.position=0.01``) is a ``ValueError`` naming
    ``flag``.
    """
    out: dict[str, Any] = {}
    for path, value in items:
        node = out
        for depth, part in enumerate(path[:-1]):
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                where = ".".join(path[: depth + 1])
                raise ValueError(f"{flag} {where} is given both a value and sub-keys")
            node = child
        leaf = path[-1]
        if isinstance(node.get(leaf), dict) and not isinstance(value, dict):
            raise ValueError(f"{flag} {'.'.join(path)} is given both a value and sub-keys")
        node[leaf] = value
    return out


@dataclass(frozen=True)
class Realism:
    """The realism flags of a run: a sensor profile and block overrides (JSON, so that the
    value is hashable and pickles to the workers)."""

    profile: str | None = None
    blocks: str = "{}"  # JSON {block: overrides} for blocks of REALISM_BLOCKS

    def overrides(self) -> dict[str, Any]:
        """The ``platoon_env.make`` keyword arguments of these flags."""
        out: dict[str, Any] = dict(json.loads(self.blocks))
        if self.profile is not None:
            out["sensor_profile"] = self.profile
        return out

    @property
    def label(self) -> str:
        """The flags in short (``aruco; camera.latency=0.05``), ``none`` without any."""

        def flat(prefix: str, value: Any) -> list[str]:
            if isinstance(value, dict) and value:
                return [p for k, v in value.items() for p in flat(f"{prefix}.{k}", v)]
            return [f"{prefix}={json.dumps(value)}"]

        parts = [f"profile {self.profile}"] if self.profile is not None else []
        for block, value in json.loads(self.blocks).items():
            parts += flat(block, value)
        return "; ".join(parts) or "none"


def resolved_realism(env_or_config: Any) -> str:
    """The resolved camera, proximity and robot blocks of an env (or a scenario config), as the
    canonical JSON recorded in the ``realism`` column."""
    cfg = getattr(getattr(env_or_config, "scenario", None), "config", env_or_config)
    mapping = config_to_mapping(cfg)
    blocks = {name: mapping.get(name, {}) for name in REALISM_BLOCKS}
    return json.dumps(blocks, sort_keys=True, separators=(",", ":"))


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


def build(
    spec: PolicySpec, scenario: str, realism: Realism = Realism()
) -> tuple[platoon_env.PlatoonParallelEnv, PolicyLike]:
    """The env (at the policy's control period, with the realism flags) and the policy for one
    scenario."""
    overrides = realism.overrides()
    if spec.kind == "ppc":
        from baselines.ppc import PPCPolicy

        env = platoon_env.make(scenario, **overrides)
        return env, PPCPolicy(env)
    if spec.kind == "last_seen":
        from baselines.last_seen import LastSeenPolicy

        env = platoon_env.make(scenario, **overrides)
        return env, LastSeenPolicy(env)
    from training.policies import LearnedPolicy

    assert spec.path is not None
    learned = LearnedPolicy.load(spec.path)
    env = platoon_env.make(scenario, control_period=learned.control_period, **overrides)
    return env, learned


def run_job(
    spec: PolicySpec, scenario: str, seed: int, keep: bool, realism: Realism = Realism()
) -> tuple[dict[str, Any], Episode | None]:
    """One episode; returns its CSV row and (if ``keep``) the recorded episode for plots.

    The row carries the realism: the profile, the flags and the env's resolved blocks.
    """
    import torch

    torch.set_num_threads(1)
    env, policy = build(spec, scenario, realism)
    ep = run_episode(env, policy, seed=seed, record_signals=keep)
    row = {
        "policy": spec.name,
        "scenario": scenario,
        "seed": seed,
        "sensor_profile": realism.profile or "",
        "realism_label": realism.label,
        **episode_metrics(ep),
        "realism": resolved_realism(env),
    }
    return row, ep if keep else None


def _key(row: dict[str, Any]) -> tuple[str, ...]:
    return tuple(str(row[c]) for c in KEY_COLUMNS)


def _read_rows(path: Path) -> list[dict[str, str]]:
    """The rows of ``results.csv`` ([] if absent). A torn last line (a run killed while
    writing it) is cut off the file; a file of an older version, without the realism columns,
    is rewritten with them (its rows ran without realism flags: the scenario's own blocks)."""
    if not path.is_file():
        return []
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        with path.open("r+b") as f:
            f.truncate(data.rfind(b"\n") + 1)
    with path.open(newline="") as f:
        reader = csv.DictReader(f)
        rows = [r for r in reader if None not in r.values()]
        columns = tuple(reader.fieldnames or ())
    if columns and "realism" not in columns:
        rows = _upgrade(path, rows)
    return rows


def _upgrade(path: Path, rows: list[dict[str, str]]) -> list[dict[str, str]]:
    """Add the realism columns to the rows of an older ``results.csv`` and rewrite it."""
    cache: dict[str, str] = {}
    for r in rows:
        scenario = r["scenario"]
        if scenario not in cache:
            try:
                cache[scenario] = resolved_realism(platoon_env.scenarios.load_config(scenario))
            except (ScenarioError, OSError, TypeError):
                cache[scenario] = "unknown"
        r.update(sensor_profile="", realism_label=Realism().label, realism=cache[scenario])
    tmp = path.with_suffix(".csv.tmp")
    with tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=CSV_COLUMNS, extrasaction="ignore", restval="")
        writer.writeheader()
        writer.writerows(rows)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    print(f"{path}: added the realism columns to {len(rows)} rows of an older version")
    return rows


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
    """The markdown of ``summary.md``: per realism (the ``realism`` column; a heading when
    there are several), a table with one line per scenario × policy."""
    by_realism: dict[str, list[dict[str, str]]] = defaultdict(list)
    for r in rows:
        by_realism[r.get("realism", "")].append(r)
    if len(by_realism) <= 1:
        return _summary_table(next(iter(by_realism.values()), []))
    parts = []
    for realism, rs in sorted(by_realism.items()):
        label = rs[0].get("realism_label", "") or "none"
        parts.append(f"### realism: {label}\n\nresolved: `{realism}`\n\n{_summary_table(rs)}")
    return "\n\n".join(parts)


def _summary_table(rows: Iterable[dict[str, str]]) -> str:
    """One line per scenario × policy."""
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
    realism = parser.add_argument_group(
        "realism", "sensing and actuation realism, passed to every env (docs/sensing.md)"
    )
    realism.add_argument(
        "--sensor-profile",
        metavar="NAME",
        default=None,
        help="a shipped sensor profile (e.g. aruco) or a profile YAML file",
    )
    for block, example in (
        ("camera", "noise.position=0.01"),
        ("proximity", "noise=0.01"),
        ("robot", "accel_max=1"),
    ):
        realism.add_argument(
            f"--{block}",
            action="append",
            type=parse_assignment,
            default=[],
            metavar="KEY=VALUE",
            help=f"override a {block} field, e.g. {example} (YAML value; repeatable)",
        )
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error("--episodes must be >= 1")
    args.policy = args.policy or default_policies()
    args.scenario = args.scenario or list(DEFAULT_SCENARIOS)
    names = [p.name for p in args.policy]
    if len(set(names)) != len(names):
        parser.error(f"policy names must be unique, got {names}")
    blocks: dict[str, Any] = {}
    for block in REALISM_BLOCKS:
        try:
            nested = nest_assignments(getattr(args, block), f"--{block}")
        except ValueError as exc:
            parser.error(str(exc))
        if nested:
            blocks[block] = nested
    args.realism = Realism(args.sensor_profile, json.dumps(blocks))
    args.resolved = {}
    for s in args.scenario:
        try:
            cfg = platoon_env.scenarios.load_config(s)  # fail fast on a bad scenario ...
            # ... or on realism it does not take, at the period of every policy
            for period in {_control_period(spec) for spec in args.policy}:
                period_kw = {} if period is None else {"control_period": period}
                resolved = apply_overrides(
                    cfg, {**args.realism.overrides(), **period_kw}, where="realism flags"
                )
        except (ScenarioError, TypeError, OSError) as exc:
            parser.error(f"scenario {s!r}: {exc}")
        args.resolved[s] = resolved_realism(resolved)
    return args


def _control_period(spec: PolicySpec) -> float | None:
    """The period a policy runs at: None (the scenario's) for ppc and last_seen, a learned
    model's from its ``model.json`` (None if unreadable: the model load will tell)."""
    if spec.kind != "model" or spec.path is None:
        return None
    try:
        meta = json.loads((spec.path.parent / "model.json").read_text())
        return float(meta["control_period"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def main(argv: Sequence[str] | None = None) -> int:
    """Run the evaluation; returns the process exit code (130 when interrupted)."""
    args = parse_args(argv)
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / "results.csv"
    realism: Realism = args.realism
    done = {_key(r) for r in _read_rows(csv_path)}
    seeds = range(args.seed, args.seed + args.episodes)
    jobs = [
        (spec, scenario, seed)
        for scenario in args.scenario
        for spec in args.policy
        for seed in seeds
        if (spec.name, scenario, str(seed), args.resolved[scenario]) not in done
    ]
    if done:
        planned = len(args.scenario) * len(args.policy) * len(seeds)
        print(
            f"resuming {csv_path}: {planned - len(jobs)} of {planned} episodes done "
            f"({len(done)} rows in the file), {len(jobs)} to run"
        )
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
                run_job,
                spec,
                scenario,
                seed,
                keep=seed == args.seed and not args.no_plots,
                realism=realism,
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
        if r["policy"] in {p.name for p in args.policy}
        and r["scenario"] in set(args.scenario)
        and r["realism"] == args.resolved[r["scenario"]]
    )
    elapsed = time.perf_counter() - start
    resolved = "".join(f"- {s}: `{args.resolved[s]}`\n" for s in args.scenario)
    header = (
        f"# platoon-evaluate\n\npolicies: {', '.join(p.name for p in args.policy)}; "
        f"scenarios: {', '.join(args.scenario)}; episodes: {args.episodes} (seeds {args.seed}.."
        f"{args.seed + args.episodes - 1}); wall time of this run: {elapsed:.0f} s; "
        f"platoon_env {platoon_env.__version__}\n\n"
        f"realism flags: {realism.label}; resolved camera, proximity and robot blocks:\n\n"
        f"{resolved}\n"
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
            kept[scenario][spec.name] = run_job(  # type: ignore[assignment]
                spec, scenario, args.seed, keep=True, realism=realism
            )[1]
        for scenario in tqdm(args.scenario, desc="plots", unit="scenario"):
            plot_scenario(scenario, kept[scenario], out / "plots")
    print(
        f"wrote {csv_path}, {out / 'summary.md'}" + ("" if args.no_plots else f", {out / 'plots'}/")
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
