"""``platoon-evaluate``: PPC against learned policies on the same workspaces and seeds.

Every policy × scenario × seed is one episode of the evaluation store ``OUT/results.sqlite``
(:mod:`experiments.store`; ``docs/results.md``), written as each episode finishes. A re-run
with the same ``--out`` runs only what the store does not hold yet, matched by content, not
by name: the policy's fingerprint (a model's file hash and ``model.json``; an analytic law's
parameters), the resolved scenario's (after the YAML, the sensor profile and every override),
the overrides' and the seed. So an edited YAML or a retrained model under the same name runs
again, ``./x.yaml`` and ``x.yaml`` are one scenario, and two evaluators into one ``--out``
share the work (each episode once). A killed run loses only the episodes in flight.

At the end, from the store's rows of this run's grid: ``OUT/results.csv`` (one row per episode,
with its policy's ``configuration`` and ``training_seed`` and the fingerprints),
``OUT/summary.md`` (one line per scenario × configuration: the models ``<configuration>_s<seed>``
are the training seeds of one configuration, an analytic law is one on its own
(:func:`experiments.policies.configurations`); 95 % confidence intervals, for several training
seeds a hierarchical bootstrap over them; its header counts the rows it summarises, gives the
run's wall time and says which code made them; every ``check_env`` note of the learned models
in full at the end) and ``OUT/plots/`` (from the first seed's episodes: ``trajectories.png``,
a grid of a column per scenario and a row per analytic law and configuration (its first
training seed); per scenario, every policy's trajectories in a grid, the errors against the
constraints and the velocity commands of each analytic law and configuration (its first
training seed), and a GIF per policy). The console gets one note line per
configuration and scenario and, at the end, the wall time.

With no arguments it runs the default benchmark: PPC against every shipped model
(``models/*/model.zip``) on the paper's three studies and the held-out procedural test set.

Policies (``--policy``, repeatable): a registered kind (:data:`experiments.policies.REGISTRY`,
listed with their descriptions by ``--help``: the paper's PPC law, the filtered PPC, ref. [32]'s
last-seen baseline and its field-of-view variant), ``NAME=KIND`` (one of those under another
name) or ``NAME=PATH`` (a model saved by ``platoon-train``; PATH is ``DIR``
or ``DIR/model.zip``). Each policy runs at its own control period: the analytic laws at the
env's default, a learned model at the period it was trained with (its ``model.json``);
metrics are in seconds and metres, so they compare across periods.

Realism (``docs/sensing.md``): ``--sensor-profile NAME`` (a shipped profile such as ``aruco``,
or a profile YAML) and per-field overrides of the ``camera``, ``proximity`` and ``robot``
blocks, ``--camera noise.position=0.01 --camera latency=0.05 --robot accel_max=1
--proximity noise=0.01`` (``KEY[.SUB...]=VALUE``, the value read as a YAML scalar, repeatable,
applied after the profile); ``--set KEY=VALUE`` overrides any other option of
``platoon_env.make`` (``--set max_episode_steps=500 --set formation.d_des=1.5``). Every row
records the profile, the flags (``realism_label``) and the resolved camera, proximity and
robot blocks (``realism``, JSON).

Exit status: 0, 1 if an episode failed (the others are kept; a re-run retries the failed
ones), 2 on a usage error (nothing written), 130 when interrupted.

.. warning::
    Loading a model unpickles code: evaluate only model files you trust.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
import time
from collections import defaultdict
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tqdm import tqdm

import platoon_env
from experiments.cli import (
    INT64_MAX,
    add_batch_option,
    add_models_option,
    add_workers_option,
    count,
    new_parser,
    number,
)
from experiments.grid import (
    DEFAULT_CLAIM_TIMEOUT,
    Cell,
    GridResult,
    ResolvedCell,
    merge_overrides,
    resolve_cells,
    run_grid,
    store_path,
)
from experiments.policies import (
    MODEL,
    REGISTRY,
    PolicySpec,
    analytic_policies,
    build_policy,
    configurations,
    default_models_dir,
    shipped_models,
)
from experiments.published import (
    PUBLISHED,
    PublishedError,
    PublishedRows,
    check_compatible,
    comparison_markdown,
    load_published,
    write_published,
)
from experiments.report import (
    file_stem,
    format_value,
    mean_ci,
    provenance_markdown,
    seed_ranges,
    wilson,
    write_csv,
    write_csv_stamp,
    write_text_atomic,
)
from experiments.significance import mean_success
from experiments.stamp import code_version, metadata_stamp, png_metadata
from experiments.store import Store, StoreError
from experiments.suites import SUITES, Condition, Suite, suite
from platoon_env.extras import MissingExtraError, require_extra
from platoon_env.rollout import METRIC_NAMES, Episode, PolicyLike
from platoon_env.scenarios.fingerprint import canonical_json
from platoon_env.scenarios.loader import read_yaml
from platoon_env.scenarios.schema import ScenarioError, config_to_mapping

__all__ = [
    "CSV_COLUMNS",
    "DEFAULT_SCENARIOS",
    "SUMMARY_LEGEND",
    "ModelNotes",
    "PolicySpec",
    "Realism",
    "build",
    "default_policies",
    "episode_seeds",
    "export_rows",
    "headline",
    "main",
    "mean_ci",
    "nest_assignments",
    "parse_args",
    "parse_assignment",
    "plot_overview",
    "plot_scenario",
    "resolved_realism",
    "summarise",
    "wilson",
]

DEFAULT_SCENARIOS = ("study_a", "study_b", "study_c")
#: Episodes (seeds) per policy and scenario by default: every table on the studies is over at
#: least 20 seeds (each draws its own leader speed factor and start perturbation).
DEFAULT_EPISODES = 20
#: The most episodes one run plans (every cell is resolved before the first episode runs).
MAX_GRID_EPISODES = 1_000_000
#: The scenario blocks the realism flags override, and record (resolved) with every row.
REALISM_BLOCKS: tuple[str, ...] = ("camera", "proximity", "robot")
#: Columns of the ``results.csv`` export.
CSV_COLUMNS: tuple[str, ...] = (
    "policy",
    "scenario",
    "seed",
    "status",
    # the policy's configuration and training seed (experiments.policies.configurations)
    "configuration",
    "training_seed",
    "sensor_profile",
    "realism_label",
    *METRIC_NAMES,
    "realism",
    "policy_fingerprint",
    "scenario_fingerprint",
    "overrides_fingerprint",
    "run_id",
    "wall_time",
    "error",
)
_KEY_PATTERN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*")
_TOOL = "platoon-evaluate"


def parse_assignment(text: str) -> tuple[tuple[str, ...], Any]:
    """``KEY[.SUB...]=VALUE`` -> (key path, value), the value read as a scenario file reads YAML
    (:func:`platoon_env.scenarios.loader.read_yaml`: ``0.01`` a float, ``null`` None, ``true``
    a bool, ``[1, 2]`` a list, else a string).

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
        # the scenario files' reader: the value means what it would in a scenario file (YAML 1.2
        # scalars, no tags, no aliases), and every error is a ScenarioError
        value = read_yaml(raw, "the value")
    except ScenarioError as exc:
        detail = str(exc).splitlines()[0].removeprefix("the value: ")
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
    """The resolved camera, proximity and robot blocks of an env, a scenario config or a
    config mapping, as the canonical JSON recorded in the ``realism`` column."""
    if isinstance(env_or_config, dict):
        mapping = env_or_config
    else:
        source = getattr(env_or_config, "source", None)
        mapping = config_to_mapping(getattr(source, "config", env_or_config))
    blocks = {name: mapping.get(name, {}) for name in REALISM_BLOCKS}
    return json.dumps(blocks, sort_keys=True, separators=(",", ":"))


def build(
    spec: PolicySpec, scenario: str, realism: Realism = Realism()
) -> tuple[platoon_env.PlatoonParallelEnv, PolicyLike]:
    """The env (at the policy's control period, with the realism flags) and the policy for one
    scenario, as an evaluation episode runs them."""
    env = platoon_env.make(scenario, **merge_overrides(spec, realism.overrides()))
    policy: PolicyLike = build_policy(spec, env)
    return env, policy


def default_policies(models: Path | None = None) -> list[PolicySpec]:
    """The registered policies the default benchmark runs (PPC) and every model in ``models``
    (default: :func:`experiments.policies.default_models_dir`; none when it finds none)."""
    analytic = [PolicySpec.of(name) for name in analytic_policies("evaluate")]
    folder = models if models is not None else default_models_dir()
    return [*analytic, *(shipped_models(folder) if folder is not None else [])]


# ----------------------------------------------------------------------------------------------
# Exports
# ----------------------------------------------------------------------------------------------


def summarise(rows: Iterable[dict[str, str]]) -> str:
    """The markdown tables of ``summary.md``: one line per scenario × configuration (the
    training seeds of a learned configuration together, :func:`experiments.policies.configurations`;
    an analytic law on its own); rows of several realism settings (the ``realism_label``
    column) get a table each, never mixed."""
    by_realism: dict[str, list[dict[str, str]]] = defaultdict(list)
    for r in rows:
        by_realism[r.get("realism_label", "") or "none"].append(r)
    if len(by_realism) <= 1:
        return _summary_table(next(iter(by_realism.values()), []))
    return "\n\n".join(
        f"### realism: {label}\n\n{_summary_table(rs)}" for label, rs in sorted(by_realism.items())
    )


def headline(rows: Iterable[dict[str, str]]) -> str:
    """``headline.md``: one markdown table, a row per analytic law and learned configuration
    (training seeds pooled) and a column per scenario (and realism label, when there are
    several), each cell the successes ``k/n``; the last column the mean success rate over the
    columns. Rows in the order they first appear (the laws first, by default), failed episodes
    left out (as in ``summary.md``)."""
    done = [r for r in rows if r.get("status") == "done"]
    labels = sorted({r.get("realism_label", "") or "none" for r in done})
    counts: dict[tuple[str, str], list[int]] = defaultdict(lambda: [0, 0])
    columns: list[str] = []
    entries: list[str] = []
    for r in done:
        label = r.get("realism_label", "") or "none"
        column = r["scenario"] + (f" ({label})" if len(labels) > 1 else "")
        columns += [] if column in columns else [column]
        entries += [] if r["configuration"] in entries else [r["configuration"]]
        cell = counts[(r["configuration"], column)]
        cell[0] += str(r["success"]).lower() == "true"
        cell[1] += 1
    lines = [
        "| policy | " + " | ".join(columns) + " | mean success |",
        "|---|" + "---:|" * (len(columns) + 1),
    ]
    for entry in entries:
        cells = [counts.get((entry, c)) for c in columns]
        rates = [k / n for k, n in (c for c in cells if c and c[1])]
        shown = [f"{c[0]}/{c[1]}" if c and c[1] else "–" for c in cells]
        mean = f"{sum(rates) / len(rates):.2f}" if rates else "–"
        lines.append(f"| {entry} | " + " | ".join(shown) + f" | {mean} |")
    return "\n".join(lines) + "\n"


#: What the columns of :func:`summarise` hold (written under the tables of ``summary.md``).
SUMMARY_LEGEND = (
    "One line per scenario × configuration: a learned configuration's training seeds (models "
    "`<configuration>_s<seed>`, one row each in results.csv) are one line, their episodes "
    "pooled. **success [95% CI]**: k/n with, for several training seeds, the interval of a "
    "hierarchical bootstrap (the seeds resampled, then each seed's rate drawn from its Jeffreys "
    "posterior: `experiments.significance.mean_success`), otherwise the Wilson score interval; "
    "**by training seed**: each seed's successes. The other columns are over the pooled "
    "episodes (docs/metrics.md)."
)


def _summary_table(rows: Iterable[dict[str, str]]) -> str:
    """One line per scenario × configuration over the rows with a result."""
    groups: dict[tuple[str, str], list[dict[str, str]]] = defaultdict(list)
    for r in rows:
        if r.get("status", "done") == "done":
            groups[(r["scenario"], r.get("configuration") or r["policy"])].append(r)
    lines = [
        "| scenario | policy | training seeds | episodes | seeds | success [95% CI] | "
        "by training seed | violations by cause | rms e_d [m] | rms e_beta [rad] | "
        "min clearance [m] | min robot distance [m] | peak u [m/s] | peak omega [rad/s] | "
        "command rate u [m/s²] | command rate omega [rad/s²] | funnel exits |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for (scenario, policy), rs in sorted(groups.items()):
        n = len(rs)
        ok = sum(r["success"] == "True" for r in rs)
        runs: dict[str, list[int]] = defaultdict(lambda: [0, 0])
        for r in rs:
            run = runs[r.get("training_seed") or r["policy"]]
            run[0] += r["success"] == "True"
            run[1] += 1
        trained = sorted(int(k) for k in runs if k.isdigit())
        if len(runs) > 1:
            interval = mean_success([[tuple(c)] for c in runs.values()])
            lo, hi = interval.low, interval.high
        else:
            lo, hi = wilson(ok, n)
        causes: dict[str, int] = defaultdict(int)
        for r in rs:
            if r["violation"]:
                causes[r["violation"]] += 1
        viol = ", ".join(f"{c} {k}" for c, k in sorted(causes.items())) or "none"

        def f(key: str, rs: list[dict[str, str]] = rs) -> list[float]:
            return [float(r[key]) for r in rs]

        seeds = seed_ranges(int(r["seed"]) for r in rs)
        lines.append(
            f"| {scenario} | {policy} | {seed_ranges(trained) if trained else '–'} | {n} | "
            f"{seeds} | {ok}/{n} [{lo:.2f}, {hi:.2f}] | {_by_seed(runs, trained)} | {viol} | "
            f"{mean_ci(f('rms_e_d'))} | {mean_ci(f('rms_e_beta'))} | "
            f"{min(f('min_obstacle_clearance')):.3f} | {min(f('min_inter_robot_distance')):.3f} | "
            f"{max(f('peak_u')):.2f} | {max(f('peak_omega')):.2f} | "
            f"{_mean_of(rs, 'command_rate_u')} | {_mean_of(rs, 'command_rate_omega')} | "
            f"{sum(int(r['funnel_exits']) for r in rs)} |"
        )
    return "\n".join(lines)


def _mean_of(rows: Sequence[dict[str, str]], key: str) -> str:
    """The mean of column ``key`` over the rows that have it (``–`` if none: episodes stored
    before the column existed)."""
    values = [float(r[key]) for r in rows if r.get(key) not in (None, "")]
    return f"{sum(values) / len(values):.2f}" if values else "–"


def _by_seed(runs: Mapping[str, list[int]], trained: Sequence[int]) -> str:
    """Each training seed's successes (``15, 17, 16 of 20``; ``–`` for one run)."""
    if len(runs) < 2:
        return "–"
    order = [str(t) for t in trained] + sorted(k for k in runs if not k.isdigit())
    counts = [runs[k] for k in order]
    if len({n for _, n in counts}) == 1:
        return ", ".join(str(k) for k, _ in counts) + f" of {counts[0][1]}"
    return ", ".join(f"{k}/{n}" for k, n in counts)


def export_rows(
    result: GridResult,
    conditions: Mapping[str, Condition],
    configs: Mapping[str, tuple[str, int | None]] | None = None,
) -> list[dict[str, Any]]:
    """The ``results.csv`` rows of a grid: every cell with a row in the store; ``conditions``
    names each cell's condition by its overrides (JSON), ``configs`` each policy's
    configuration and training seed (default: :func:`experiments.policies.configurations` of
    the grid's policies)."""
    if configs is None:
        specs = {rc.cell.policy.name: rc.cell.policy for rc in result.cells}
        configs = configurations(list(specs.values()))
    rows = []
    for rc in result.cells:
        rec = result.records.get(rc.key)
        if rec is None or rec.status == "running":
            continue
        configuration, training_seed = configs[rc.cell.policy.name]
        rows.append(
            {
                "policy": rc.cell.policy.name,
                "configuration": configuration,
                "training_seed": training_seed,
                "scenario": rc.cell.scenario,
                "seed": rc.cell.seed,
                "status": rec.status,
                "sensor_profile": conditions[rc.cell.overrides].overrides.get("sensor_profile", ""),
                "realism_label": conditions[rc.cell.overrides].label,
                **{k: rec.metrics.get(k) for k in METRIC_NAMES},
                "realism": resolved_realism(rc.config),
                "policy_fingerprint": rc.key.policy,
                "scenario_fingerprint": rc.key.scenario,
                "overrides_fingerprint": rc.key.overrides,
                "run_id": rec.run_id,
                "wall_time": rec.wall_time,
                "error": rec.error.strip().splitlines()[-1] if rec.error.strip() else "",
            }
        )
    return rows


def _csv_strings(rows: Iterable[dict[str, Any]]) -> list[dict[str, str]]:
    return [{k: format_value(v) for k, v in r.items()} for r in rows]


def _slug(scenario: str) -> str:
    """A file-name stem for a scenario given by name or path (never a path itself)."""
    return file_stem(Path(scenario).stem if scenario.endswith((".yaml", ".yml")) else scenario)


#: [in²] the area of one workspace panel of a scenario's trajectory grid (a wide workspace
#: gets a wide panel, a tall one a narrow panel).
_PANEL_AREA = 12.0
#: The height / width a trajectory grid aims at (a landscape page).
_GRID_SHAPE = 0.7


def _workspace(scenario: str, seed: int | None) -> Any:
    """The workspace an episode of ``seed`` ran on: reset with its seed draws it as the episode
    did (a procedural source's layout of that seed; a fixed source's one scenario, no draw)."""
    env = platoon_env.make(scenario)
    env.reset(seed=seed)
    return env.scenario


def _aspect(sc: Any) -> float:
    """Height / width of a scenario's workspace (its drawn extent)."""
    xmin, ymin, xmax, ymax = sc.workspace.bounds
    return float(min(max((ymax - ymin) / max(xmax - xmin, 1e-9), 0.2), 3.0))


def _grid_columns(n: int, aspect: float) -> int:
    """The number of columns of a grid of ``n`` panels of height / width ``aspect`` whose
    shape is nearest :data:`_GRID_SHAPE` (an empty cell counts against it)."""

    def cost(cols: int) -> float:
        rows = -(-n // cols)
        return abs(math.log(rows * aspect / cols / _GRID_SHAPE)) + 0.1 * (rows * cols - n)

    return min(range(1, n + 1), key=cost)


def _outcome(ep: Episode) -> str:
    """How an episode ended, for a panel's title."""
    if ep.first_violation is not None:
        step, cause, follower = ep.first_violation
        return f"R{follower} {cause} at {ep.times[min(step + 1, ep.times.size - 1)]:.1f} s"
    if ep.leader_arrived:
        return f"completed in {ep.times[-1]:.1f} s"
    return f"stopped at {ep.times[-1]:.1f} s"


def plot_overview(
    scenarios: Sequence[tuple[str, Mapping[str, Episode]]],
    path: Path,
    title: str = "",
    metadata: dict[str, str] | None = None,
) -> Path:
    """The benchmark at a glance: a grid of trajectory panels, a column per scenario (the
    workspace of its episodes' seed; the columns' widths follow the workspaces' shapes) and a
    row per policy (``scenarios``: the episodes of each scenario by policy label, in the rows'
    order), each panel titled with its scenario, policy and outcome, under one legend."""
    from platoon_env.plots import new_figure, plot_snapshots, save_figure
    from platoon_env.rendering import legend_handles

    labels = list(dict.fromkeys(name for _, eps in scenarios for name in eps))
    shown = [(s, eps, _workspace(s, next(iter(eps.values())).seed)) for s, eps in scenarios if eps]
    # a column's width follows its workspace's, but leaves room for the panels' titles
    widths = [max(1 / _aspect(sc), 0.95) for _, _, sc in shown]
    height = 2.4  # [in] a row's panels
    fig = new_figure(height * sum(widths) + 0.4, len(labels) * (height + 0.75) + 1.2)
    grid = fig.add_gridspec(len(labels), len(shown), width_ratios=widths)
    for col, (scenario, eps, sc) in enumerate(shown):
        for row, name in enumerate(labels):
            ax = fig.add_subplot(grid[row, col])
            ep = eps.get(name)
            if ep is None:
                ax.set_axis_off()
                ax.set_title(f"{scenario}\n{name}\nnot run", fontsize=8.5)
                continue
            plot_snapshots(ax, sc, ep, n_snapshots=5)
            ax.set_title(f"{scenario}, seed {ep.seed}\n{name}\n{_outcome(ep)}", fontsize=8.5)
            ax.tick_params(labelsize=7)
    if title:
        fig.suptitle(title)
    fig.legend(handles=legend_handles(), loc="outside lower center", ncols=5, fontsize=8)
    return save_figure(fig, path, metadata)


def plot_scenario(
    scenario: str,
    episodes: dict[str, Episode],
    out: Path,
    slug: str | None = None,
    metadata: dict[str, str] | None = None,
    overlaid: Sequence[str] | None = None,
) -> list[Path]:
    """Comparison plots of one scenario (one episode per policy) and a GIF per policy, into
    ``out`` under the file-name stem ``slug`` (default: the scenario's name); ``metadata``
    are the PNG text fields (the run's stamp). The trajectories are a grid of panels, one per
    policy, in as many columns as give the figure a landscape shape (:func:`_grid_columns`),
    each titled with the policy and the episode's outcome, under one legend. The errors and
    commands figures overlay the episodes of ``overlaid`` (default: every policy; the
    evaluator passes each configuration's first training seed, so that the lines stay
    apart), with the legend beside the axes."""
    from platoon_env.plots import (
        new_figure,
        plot_commands,
        plot_errors,
        plot_snapshots,
        save_figure,
        save_gif,
    )
    from platoon_env.rendering import legend_handles

    slug = file_stem(slug) if slug else _slug(scenario)
    names = list(episodes)  # the policies' order (the analytic laws first, by default)
    eps = [episodes[k] for k in names]
    sc = _workspace(scenario, eps[0].seed)
    aspect = _aspect(sc)
    cols = _grid_columns(len(names), aspect)
    rows = -(-len(names) // cols)
    width = min(max(math.sqrt(_PANEL_AREA / aspect), 2.8), 6.0)  # [in] a panel's
    fig = new_figure(cols * width, rows * (width * aspect + 0.45) + 1.1)
    grid = fig.add_gridspec(rows, cols)
    for k, (name, ep) in enumerate(zip(names, eps, strict=True)):
        ax = fig.add_subplot(grid[k // cols, k % cols])
        plot_snapshots(ax, sc, ep, n_snapshots=5, title=f"{name}: {_outcome(ep)}")
        ax.title.set_fontsize(10)
    fig.suptitle(f"{scenario}, seed {eps[0].seed}: the platoon at five instants, with its traces")
    fig.legend(handles=legend_handles(), loc="outside lower center", ncols=5, fontsize=8)
    paths = [save_figure(fig, out / f"{slug}_trajectories.png", metadata)]
    n = sc.config.followers
    followers = [1, n] if n > 2 else None
    lines = [k for k in names if overlaid is None or k in overlaid] or names
    line_eps = [episodes[k] for k in lines]
    fig = new_figure(11, 1.2 + 1.4 * (len(followers) if followers else n))
    plot_errors(fig, sc, line_eps, labels=lines, followers=followers)
    fig.suptitle(f"{scenario}, seed {eps[0].seed}: errors and safety limits (dashed)")
    paths.append(save_figure(fig, out / f"{slug}_errors.png", metadata))
    fig = new_figure(11, 1.2 + 1.2 * (len(followers) if followers else n))
    plot_commands(fig, sc, line_eps, labels=lines, followers=followers)
    fig.suptitle(f"{scenario}, seed {eps[0].seed}: velocity commands")
    paths.append(save_figure(fig, out / f"{slug}_commands.png", metadata))
    for name, ep in zip(names, eps, strict=True):
        paths.append(
            save_gif(sc, ep, out / f"{slug}_{file_stem(name)}.gif", frame_every=1.0, size_px=360)
        )
    return paths


# ----------------------------------------------------------------------------------------------
# Command line
# ----------------------------------------------------------------------------------------------


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """Parse and validate the command line; every error is an argparse usage error (exit 2)
    raised before anything is written."""
    parser = build_parser()
    args = parser.parse_args(argv)
    the_suite = suite(args.suite) if args.suite else None
    if the_suite is not None:
        given = [f for f in ("scenario", *REALISM_BLOCKS) if getattr(args, f)]
        given += ["sensor_profile"] if args.sensor_profile else []
        if given:
            flags = ", ".join("--" + g.replace("_", "-") for g in given)
            parser.error(f"--suite {args.suite} sets the scenarios and conditions; drop {flags}")
    if args.episodes is None:
        args.episodes = the_suite.seeds if the_suite is not None else DEFAULT_EPISODES
    _check_output(parser, args)
    args.published = None
    if args.compare_to is not None:
        args.published = _compare_to(parser, args)
    if args.publish:
        _check_publish(parser, args)
    _choose_policies(parser, args)
    args.conditions = _conditions(parser, args, the_suite)
    _resolve_grid(parser, args, the_suite)
    return args


def build_parser() -> argparse.ArgumentParser:
    """The command line's options (checked and completed by :func:`parse_args`)."""
    parser = new_parser(_TOOL, __doc__)
    parser.add_argument(
        "--policy",
        action="append",
        type=PolicySpec.parse,
        default=None,
        help=f"a registered kind ({', '.join(REGISTRY)}), NAME=KIND or NAME=PATH (repeatable); "
        f"default: {', '.join(analytic_policies('evaluate'))} and every shipped model",
    )
    parser.add_argument(
        "--scenario",
        action="append",
        default=None,
        help=f"name or YAML path (repeatable); default: {', '.join(DEFAULT_SCENARIOS)}",
    )
    parser.add_argument(
        "--suite",
        choices=SUITES,
        default=None,
        help="a named benchmark suite (experiments/suites.py): its scenarios, conditions "
        "(ideal, aruco, realism levels) and seeds; replaces --scenario and the realism flags",
    )
    parser.add_argument(
        "--episodes",
        type=count(1, "count"),
        default=None,
        help="episodes (seeds) per policy, scenario and condition (default 20, or the suite's)",
    )
    parser.add_argument(
        "--seed",
        type=count(0, "seed"),
        default=0,
        help="first seed (>= 0); episodes use seed..seed+K-1",
    )
    parser.add_argument(
        "--every-seed",
        action="store_true",
        help="every training seed of a learned configuration plays every episode (R seeds: R "
        "times the learned episodes); default: a configuration's seeds share the episodes out",
    )
    parser.add_argument("--out", type=Path, default=Path("results/benchmark"), help="output folder")
    add_models_option(parser, "the default policies include")
    add_workers_option(parser)
    add_batch_option(parser)
    parser.add_argument("--no-plots", action="store_true", help="skip plots and GIFs")
    parser.add_argument(
        "--compare-to",
        metavar="published|FILE",
        default=None,
        help="rank the --policy entries against the published per-episode rows of the default "
        "benchmark (experiments/data/published_benchmark.json, or FILE) on their scenarios and "
        "seeds, without re-running the baselines: writes OUT/comparison.md",
    )
    parser.add_argument(
        "--publish",
        action="store_true",
        help="(maintainers) after the default benchmark at a clean commit, write its rows to "
        "experiments/data/published_benchmark.json for --compare-to",
    )
    parser.add_argument(
        "--claim-timeout",
        type=number,
        default=DEFAULT_CLAIM_TIMEOUT,
        metavar="SECONDS",
        help="how long to wait for episodes another run holds while none of them finishes, "
        "then fail naming that run and how to release it (default: %(default)s)",
    )
    parser.add_argument(
        "--set",
        action="append",
        type=parse_assignment,
        default=[],
        metavar="KEY=VALUE",
        dest="set_options",
        help="override any make() option for every env, e.g. max_episode_steps=500 or "
        "formation.d_des=1.5 (YAML value; repeatable)",
    )
    _add_realism_options(parser)
    return parser


def _add_realism_options(parser: argparse.ArgumentParser) -> None:
    """``--sensor-profile`` and the per-field overrides ``--camera``, ``--proximity``,
    ``--robot``."""
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


def _check_output(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Usage errors of ``--out``, ``--claim-timeout`` and ``--models``."""
    if args.out.exists() and not args.out.is_dir():
        parser.error(f"--out {args.out}: exists and is not a folder")
    unwritable = _unwritable(args.out)
    if unwritable:
        parser.error(f"--out {args.out}: {unwritable}")
    if args.claim_timeout <= 0:
        parser.error(f"--claim-timeout must be > 0 s, got {args.claim_timeout}")
    if str(args.out) in ("", "."):
        parser.error("--out must name an output folder, not the working directory")
    if args.models is not None and not args.models.is_dir():
        parser.error(f"--models {args.models}: no such folder")


def _check_publish(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """``--publish`` writes the default benchmark's rows: no option that changes the grid, and
    a clean checkout of a commit."""
    given = [f for f in ("policy", "scenario", "suite", "models", "sensor_profile",
                         "set_options", *REALISM_BLOCKS) if getattr(args, f)]  # fmt: skip
    if given or args.episodes != DEFAULT_EPISODES or args.seed or args.every_seed:
        parser.error("--publish writes the default benchmark's rows: give no other option "
                     "than --out, --workers, --batch and --no-plots")  # fmt: skip
    version = code_version()
    if not version or version["modified"]:
        changed = ", ".join(version.get("modified", [])) or "not a git checkout"
        parser.error(f"--publish needs a clean checkout of a commit (changed: {changed})")


def _choose_policies(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """``args.policy`` (the default ones unless given), the extras they need, and whether the
    plots are drawn (``args.no_plots``, ``args.no_plots_reason``)."""
    if args.policy is None:
        args.policy = default_policies(args.models)
        if not any(p.kind == MODEL for p in args.policy):
            print(
                "note: no trained models found (looked in the source checkout's models/; the "
                "working directory's is never read unasked); running the analytic policies "
                "only: pass --models DIR to add them",
                file=sys.stderr,
            )
    elif args.models is not None:
        parser.error("--models adds models to the default policies; with --policy name each model")
    if any(p.kind == MODEL for p in args.policy):
        try:
            require_extra("train", purpose="evaluating trained models")
        except MissingExtraError as exc:
            parser.error(str(exc))
    args.no_plots_reason = "--no-plots"
    if not args.no_plots:
        try:
            require_extra("plot", purpose="drawing the plots and GIFs")
        except MissingExtraError as exc:  # the episodes and tables need no plotting library
            print(f"note: {exc}; running without them (--no-plots)", file=sys.stderr)
            args.no_plots = True
            args.no_plots_reason = "the [plot] extra is not installed"
    names = [p.name for p in args.policy]
    if len(set(names)) != len(names):
        parser.error(f"policy names must be unique, got {names}")


def _conditions(
    parser: argparse.ArgumentParser, args: argparse.Namespace, the_suite: Suite | None
) -> list[Condition]:
    """The conditions of the grid: the suite's, else the one of the realism flags; with the
    ``--set`` options on top (``args.realism``, ``args.overrides``)."""
    blocks: dict[str, Any] = {}
    for block in REALISM_BLOCKS:
        try:
            nested = nest_assignments(getattr(args, block), f"--{block}")
        except ValueError as exc:
            parser.error(str(exc))
        if nested:
            blocks[block] = nested
    args.realism = Realism(args.sensor_profile, json.dumps(blocks))
    try:
        extra = nest_assignments(args.set_options, "--set")
    except ValueError as exc:
        parser.error(str(exc))
    for key in sorted(set(extra) & {*REALISM_BLOCKS, "sensor_profile"}):
        flag = key.replace("_", "-")
        parser.error(f"--set {key}: use the realism flag (--{flag}) instead")
    args.overrides = {**args.realism.overrides(), **extra}
    for key in ("render_mode", "diagnostics"):
        if key in args.overrides:
            parser.error(f"--set {key}: not an option of an evaluation episode")
    if the_suite is not None:
        conditions = [Condition(c.label, {**c.overrides, **extra}) for c in the_suite.conditions]
    else:
        conditions = [Condition(args.realism.label, args.overrides)]
    return conditions


def _resolve_grid(
    parser: argparse.ArgumentParser, args: argparse.Namespace, the_suite: Suite | None
) -> None:
    """Resolve every cell now (``args.cells``): a bad scenario, profile or override is a usage
    error here, and the same scenario given twice (a name, a path to the same content) runs
    once. Fills ``args.scenario``, ``args.policy``, ``args.configurations``,
    ``args.condition_of`` and ``args.resolved``."""
    conditions = args.conditions
    default = the_suite.scenarios if the_suite is not None else DEFAULT_SCENARIOS
    scenarios = list(dict.fromkeys(args.scenario or default))
    if args.seed + args.episodes - 1 > INT64_MAX:
        parser.error(f"--seed {args.seed} + --episodes {args.episodes} pass the largest seed "
                     f"the store holds ({INT64_MAX})")  # fmt: skip
    seeds = range(args.seed, args.seed + args.episodes)
    played = episode_seeds(configurations(args.policy), seeds, every_seed=args.every_seed)
    planned = len(conditions) * len(scenarios) * sum(len(played[p.name]) for p in args.policy)
    if planned > MAX_GRID_EPISODES:
        parser.error(f"the grid has {planned:,} episodes, more than the {MAX_GRID_EPISODES:,} "
                     "one run plans: lower --episodes, or split the run (--seed)")  # fmt: skip
    cells = [
        Cell.of(spec, s, seed, cond.overrides)
        for cond in conditions
        for s in scenarios
        for spec in args.policy
        for seed in played[spec.name]
    ]
    # each cell's condition by the cell's overrides (the canonical JSON Cell.of writes)
    args.condition_of = {canonical_json(dict(c.overrides)): c for c in conditions}
    try:
        args.cells = resolve_cells(cells)
    except (ScenarioError, TypeError, OSError, ValueError) as exc:
        detail = str(exc) if isinstance(exc, ScenarioError | TypeError) else f"{exc}"
        parser.error(f"{detail}")
    if args.published is not None:
        fingerprints = {rc.cell.scenario: rc.key.scenario for rc in args.cells}
        try:
            check_compatible(args.published, fingerprints, seeds)
        except PublishedError as exc:
            parser.error(f"--compare-to {args.compare_to}: {exc}")
    args.scenario = _distinct_scenarios(args.cells, scenarios)
    args.policy = _distinct_policies(args.cells, args.policy)
    args.configurations = configurations(args.policy)
    args.resolved = {
        (rc.cell.scenario, args.condition_of[rc.cell.overrides].label): resolved_realism(rc.config)
        for rc in args.cells
    }


def episode_seeds(
    configs: Mapping[str, tuple[str, int | None]], seeds: range, every_seed: bool = False
) -> dict[str, range | list[int]]:
    """The episode seeds each policy plays, by name (``configs``: each policy's configuration
    and training seed, :func:`experiments.policies.configurations`).

    An analytic law, a model on its own and, with ``every_seed``, every training seed play all
    of ``seeds``. Otherwise the R training seeds of a configuration share them out, as the
    leaderboard's held-out tasks do: its k-th run (by training seed) plays the k-th of R
    contiguous slices of ``seeds`` (``n // R`` or ``n // R + 1`` each), so the configuration
    plays each episode once and costs what one run on all seeds costs; with fewer seeds than
    runs (n < R) run k plays seed ``k mod n``. The summary pools a configuration's runs
    (its hierarchical bootstrap resamples the runs, then their episodes)."""
    runs: dict[str, list[tuple[int, str]]] = defaultdict(list)
    for name, (configuration, trained) in configs.items():
        if trained is not None:
            runs[configuration].append((trained, name))
    out: dict[str, range | list[int]] = {name: seeds for name in configs}
    if every_seed:
        return out
    n = len(seeds)
    for members in runs.values():
        r = len(members)
        for k, (_, name) in enumerate(sorted(members)):
            out[name] = seeds[k * n // r : (k + 1) * n // r] if n >= r else [seeds[k % n]]
    return out


def _compare_to(parser: argparse.ArgumentParser, args: argparse.Namespace) -> PublishedRows:
    """The published rows ``--compare-to`` names, read and checked against the options: the
    user's own policies (``--policy``) on the published scenarios and seeds (the defaults when
    not given) with no realism flags (the published run had none)."""
    source = args.compare_to
    try:
        published = load_published(PUBLISHED if source == "published" else Path(source))
    except PublishedError as exc:
        parser.error(f"--compare-to {source}: {exc}")
    if args.policy is None:
        parser.error("--compare-to ranks the policies you name: give --policy NAME=module:Class "
                     "(or a model, or a law)")  # fmt: skip
    flags = [f for f in ("suite", "sensor_profile", "set_options", *REALISM_BLOCKS)
             if getattr(args, f)]  # fmt: skip
    if flags:
        parser.error(f"--compare-to: the published rows have no such condition: drop "
                     f"{', '.join('--' + f.replace('_', '-') for f in flags)}")  # fmt: skip
    if args.scenario is None:
        args.scenario = list(published.scenarios)
    if args.episodes == DEFAULT_EPISODES and args.seed == 0:
        args.episodes = len(published.seeds)
    return published


def _distinct_scenarios(cells: Sequence[ResolvedCell], given: Sequence[str]) -> list[str]:
    """The given scenarios with a distinct content, in order; says which were duplicates."""
    kept = {rc.cell.scenario for rc in cells}
    for s in given:
        if s not in kept:
            print(f"note: --scenario {s} has the content of another one given: run once")
    return [s for s in given if s in kept]


def _distinct_policies(
    cells: Sequence[ResolvedCell], given: Sequence[PolicySpec]
) -> list[PolicySpec]:
    """The given policies with a distinct fingerprint, in order; says which were another name
    for one given before (the same law and parameters, or the same model files): their
    episodes are the same rows, run once and reported under the first name."""
    kept = {rc.cell.policy.name for rc in cells}
    first: dict[str, str] = {}
    for spec in given:
        first.setdefault(spec.fingerprint(), spec.name)
        if spec.name not in kept:
            print(
                f"note: --policy {spec.name} is the same policy as {first[spec.fingerprint()]} "
                f"(fingerprint {spec.fingerprint()[:12]}): run once, reported as "
                f"{first[spec.fingerprint()]}"
            )
    return [spec for spec in given if spec.name in kept]


def _unwritable(out: Path) -> str | None:
    """Why nothing can be written under ``out`` (its nearest existing folder is a file or not
    writable), or None."""
    folder = out
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        return f"{folder} is not a folder"
    if not os.access(folder, os.W_OK | os.X_OK):
        return f"{folder} is not writable"
    return None


#: Short forms of :meth:`training.policies.LearnedPolicy.check_env`'s notes, by how a note
#: begins, for the one console line per configuration and scenario (None: said otherwise
#: there, by the training scenario and followers); a note not listed here is shown by its
#: first words.
_NOTE_TAGS: tuple[tuple[str, str | None], ...] = (
    ("followers:", None),
    ("scenario: trained on", None),
    ("scenario: the env draws from the training layouts", "its training layouts (not held out)"),
    ("observations can exceed", "observations beyond its training normalisation (extrapolates)"),
    ("the action range", "commands beyond the actuator limits (clipped)"),
    ("control period", "another control period"),
    ("model.json records no training scenario", "training scenario not recorded"),
    ("refused", "refused"),
    ("cannot be loaded", "cannot be loaded"),
)


@dataclass
class ModelNotes:
    """What ``check_env`` says of one learned configuration on one scenario, over its training
    seeds: each note with the policies (seeds) it holds for."""

    configuration: str
    scenario: str
    policies: list[str]
    trained_on: list[str]
    followers: int | None
    notes: dict[str, list[str]]  # note text -> the policies it holds for

    def line(self) -> str:
        """The one console line: the training scenario, the followers, the notes in short."""
        n = len(self.policies)
        parts = [f"{n} seed{'s' if n > 1 else ''} trained on {', '.join(self.trained_on) or '?'}"]
        # check_env's followers note decides (a formation drawn per episode that covers this
        # scenario's count is no note); its words, shortened
        said = [t for t in self.notes if t.startswith("followers:")]
        if self.followers is not None and said:
            shown = sorted({t.removeprefix("followers: ").split(" (allowed")[0] for t in said})
            parts.append(f"followers {' / '.join(shown)} (allowed)")
        tags: dict[str, set[str]] = defaultdict(set)
        for text, policies in self.notes.items():
            tag = _note_tag(text)
            if tag is None and text.startswith("scenario:") and self.scenario in self.trained_on:
                tag = "its content differs from the training scenario's"
            if tag is not None:
                tags[tag].update(policies)
        for tag, holders in tags.items():
            parts.append(tag + ("" if len(holders) == n else f" ({len(holders)} of {n} seeds)"))
        return f"{self.configuration} on {self.scenario}: {'; '.join(parts)}"

    def markdown(self, seeds: Mapping[str, int | None]) -> str:
        """A bullet with every note in full, each with the seeds it holds for."""

        def which(policies: list[str]) -> str:
            numbers = [seeds.get(p) for p in policies]
            if len(policies) > 1 and all(k is not None for k in numbers):
                return f"seeds {seed_ranges(k for k in numbers if k is not None)}"
            return ", ".join(policies)

        lines = [f"- **{self.line()}**"]
        lines += [f"  - {which(ps)}: {text}" for text, ps in self.notes.items()]
        return "\n".join(lines)


def _note_tag(text: str) -> str | None:
    for prefix, tag in _NOTE_TAGS:
        if text.startswith(prefix):
            return tag
    head = text.split(":")[0].split(";")[0]
    return head if len(head) <= 60 else head[:57] + "..."


def _model_notes(args: argparse.Namespace) -> list[ModelNotes]:
    """What each learned model's ``check_env`` says of each scenario it is evaluated on (the
    legitimate differences from its training: another scenario family, more followers, ...),
    a :class:`ModelNotes` per configuration and scenario that has any. A refusal is not raised
    here: the episodes record it (status ``refused``). Without a model it imports nothing of
    the ``[train]`` extra, so the analytic laws run on a plain install."""
    if not any(spec.kind == MODEL for spec in args.policy):
        return []
    from training.policies import LearnedPolicy

    by_pair: dict[tuple[str, str], ModelNotes] = {}
    envs: dict[tuple[str, str], Any] = {}  # the seeds of a configuration share their envs
    for spec in args.policy:
        if spec.kind != MODEL:
            continue
        configuration = args.configurations[spec.name][0]
        try:
            policy = LearnedPolicy.load(spec.path)
            loaded: list[str] | None = None
        except (OSError, ValueError) as exc:
            loaded = [f"cannot be loaded ({exc})"]
        meta = spec.model_metadata()
        for s in args.scenario:
            entry = by_pair.setdefault(
                (configuration, s), ModelNotes(configuration, s, [], [], None, {})
            )
            entry.policies.append(spec.name)
            if meta.get("scenario") and meta["scenario"] not in entry.trained_on:
                entry.trained_on.append(str(meta["scenario"]))
            texts = loaded
            if texts is None:
                overrides = merge_overrides(spec, args.overrides)
                key = (s, canonical_json(overrides))
                if key not in envs:
                    envs[key] = platoon_env.make(s, **overrides)
                env = envs[key]
                entry.followers = len(env.possible_agents)
                try:
                    texts = policy.check_env(env)
                except ValueError as exc:
                    texts = [f"refused ({exc})"]
            for text in texts:
                entry.notes.setdefault(text, []).append(spec.name)
    return [e for e in by_pair.values() if e.notes]


def _legacy_csv(out: Path) -> str | None:
    """Why ``out`` cannot be used: a results.csv of the CSV-era platoon-evaluate, no store."""
    if (out / "results.csv").is_file() and not store_path(out).is_file():
        return (
            f"{out / 'results.csv'} was written by an older platoon-evaluate (without the "
            f"evaluation store {store_path(out).name}); its rows cannot be matched to the "
            "policies and scenarios they ran, so they are not resumed: move it away or use "
            "another --out"
        )
    return None


def main(argv: Sequence[str] | None = None) -> int:
    """Run the evaluation; returns the process exit code (see the module docstring)."""
    started = time.perf_counter()
    args = parse_args(argv)
    out: Path = args.out
    legacy = _legacy_csv(out)
    if legacy:
        print(f"{_TOOL}: error: {legacy}", file=sys.stderr)
        return 2
    stamp = metadata_stamp(
        _TOOL,
        {
            "policies": {p.name: p.description() for p in args.policy},
            "scenarios": list(args.scenario),
            "seeds": [args.seed, args.seed + args.episodes - 1],
            "suite": args.suite,
            "conditions": {c.label: dict(c.overrides) for c in args.conditions},
        },
        argv,
    )
    args.model_notes = _model_notes(args)
    for notes in args.model_notes:
        print(f"note: {notes.line()}")
    if args.model_notes:
        print(f"  (every note in full: {out / 'summary.md'})")
    first_seed = args.seed

    def keep(cell: Cell) -> bool:
        return not args.no_plots and cell.seed == first_seed

    try:
        store = Store(store_path(out))
    except StoreError as exc:
        print(f"{_TOOL}: error: {exc}", file=sys.stderr)
        return 2
    try:
        return _run(args, store, stamp, keep, started)
    except StoreError as exc:  # held cells that never finished, a store damaged mid-run
        print(f"{_TOOL}: error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:  # an export that cannot be written (a full disk, a file in the way)
        print(
            f"{_TOOL}: error: cannot write {exc.filename or out}: {exc.strerror}", file=sys.stderr
        )
        return 1


def _run(
    args: argparse.Namespace,
    store: Store,
    stamp: dict[str, Any],
    keep: Callable[[Cell], bool],
    started: float,
) -> int:
    """The grid and the exports of :func:`main` (``store`` is closed at the end); ``started``:
    :func:`time.perf_counter` when the command began (its wall time is in summary.md)."""
    out: Path = args.out
    with store:
        args.setup_time = time.perf_counter() - started
        result = run_grid(
            store,
            args.cells,
            tool=_TOOL,
            stamp=stamp,
            workers=args.workers,
            batch=args.batch,
            keep=keep,
            claim_timeout=args.claim_timeout,
        )
        print(
            f"{store.path}: {result.ran} episode(s) run, {result.reused} already in the store "
            f"(of {len(result.cells)} in this grid)"
        )
        if result.interrupted:
            print(f"\ninterrupted: finished episodes are in {store.path}; re-run to resume")
            return 130
        rows = export_rows(result, args.condition_of, args.configurations)
        write_csv(out / "results.csv", CSV_COLUMNS, rows)
        records = [result.records[rc.key] for rc in result.cells if rc.key in result.records]
        write_csv_stamp(out / "results.csv", store, records, result.run_id)
        summary = summarise(_csv_strings(rows))
        provenance = provenance_markdown(store, records, result.run_id)

    def write_summary(plots: float | None) -> float:
        """summary.md with the wall time so far (``plots``: their share, None: not drawn)."""
        wall = time.perf_counter() - started
        header = _summary_header(args, result, rows, wall, plots, provenance)
        body = f"{header}{summary}\n\n{SUMMARY_LEGEND}\n{_notes_markdown(args)}{_failures(result)}"
        _write_text(out / "summary.md", body)
        return wall

    write_summary(None)  # the results are there even if a plot fails
    _write_text(out / "headline.md", headline(_csv_strings(rows)))
    print(summary)
    if args.published is not None:
        text, ranks = comparison_markdown(_csv_strings(rows), args.published)
        _write_text(out / "comparison.md", text)
        for name, rank in ranks.items():
            print(f"{name}: rank {rank} against the published benchmark (see "
                  f"{out / 'comparison.md'})")  # fmt: skip
    if args.publish and not result.failed:
        commit = str(code_version().get("commit", "unknown"))[:12]
        made = {"commit": commit, "date": time.strftime("%Y-%m-%d"), "by": f"{_TOOL} --publish"}
        print(f"wrote {write_published(_csv_strings(rows), PUBLISHED, made)}")
    if not args.no_plots:
        before = time.perf_counter()
        _plots(args, result, out / "plots", png_metadata(stamp))
        plots: float | None = time.perf_counter() - before
    else:
        plots = None
    wall = write_summary(plots)
    print(
        f"wrote {out / 'results.csv'}, {out / 'summary.md'}"
        + ("" if args.no_plots else f", {out / 'plots'}/")
    )
    print(f"wall time: {_wall_time(args, result, wall, plots)}")
    if result.failed:
        print(f"{len(result.failed)} episode(s) failed (see summary.md); re-run to retry them")
        return 1
    return 0


def _summary_header(
    args: argparse.Namespace,
    result: GridResult,
    rows: list[dict[str, Any]],
    wall: float,
    plots: float | None,
    provenance: str,
) -> str:
    """summary.md's header: a first list with what the run ran and its wall time (the
    README's benchmark block quotes it), then the policies, realism and provenance."""
    done = [r for r in rows if r["status"] == "done"]
    policies = ", ".join(f"{p.name} (`{p.fingerprint()[:12]}`)" for p in args.policy)
    scenario_lines = "".join(
        f"- {s} ({label}): resolved camera, proximity and robot blocks `{blocks}`\n"
        for (s, label), blocks in args.resolved.items()
    )
    realism_keys = {*REALISM_BLOCKS, "sensor_profile"}
    other = {k: v for k, v in args.overrides.items() if k not in realism_keys}
    if args.suite:
        conditions = ", ".join(c.label for c in args.conditions)
        realism = f"suite {args.suite}: conditions {conditions}"
    else:
        realism = f"realism flags: {args.realism.label}"
    groups: dict[str, list[int]] = defaultdict(list)
    for configuration, seed in args.configurations.values():
        if seed is not None:
            groups[configuration].append(seed)
    analytic = sum(1 for _, seed in args.configurations.values() if seed is None)
    policy_count = f"{len(args.policy)} policies" + (
        f" ({analytic} on their own and {len(groups)} configuration(s) of "
        f"{', '.join(str(len(v)) for v in groups.values())} training seeds)"
        if groups
        else ""
    )
    shared = " (a configuration's training seeds share them out)"
    return (
        f"# {_TOOL}\n\n"
        f"- {len(done)} episodes summarised (seeds {seed_ranges(int(r['seed']) for r in done)}); "
        f"grid: {policy_count} × {len(args.scenario)} scenarios × "
        f"{len(args.conditions)} condition(s) × seeds "
        f"{seed_ranges(range(args.seed, args.seed + args.episodes))}"
        f"{'' if args.every_seed or not groups else shared}"
        f" = {len(result.cells)} "
        f"episodes, {result.ran} run now and {result.reused} resumed from the store; "
        f"{len(result.failed)} failed\n"
        f"- wall time of this run: {_wall_time(args, result, wall, plots)}\n\n"
        f"policies (fingerprint): {policies}\n\n"
        f"{realism}; other overrides: {json.dumps(other)}\n\n"
        f"{scenario_lines}\n"
        f"{provenance}\n"
    )


def _wall_time(
    args: argparse.Namespace, result: GridResult, wall: float, plots: float | None
) -> str:
    """The run's wall time and its parts."""
    drawn = (
        f"no plots ({getattr(args, 'no_plots_reason', '--no-plots')})"
        if args.no_plots
        else "plots not drawn yet"
        if plots is None
        else f"{plots:.0f} s of plots and GIFs"
    )
    return (
        f"{wall:.0f} s: {args.setup_time:.0f} s before the episodes (loading and checking the "
        f"policies and scenarios, compiling the kernels), {result.wall_time:.0f} s of episodes "
        f"in {args.workers} worker process(es) on {os.cpu_count()} CPUs, {drawn}"
    )


def _notes_markdown(args: argparse.Namespace) -> str:
    """summary.md's section of every note of the learned models, in full."""
    if not args.model_notes:
        return ""
    seeds = {name: seed for name, (_, seed) in args.configurations.items()}
    return (
        "\n## Notes on the learned models (`check_env`: how each run differs from its "
        "training)\n\n" + "\n".join(n.markdown(seeds) for n in args.model_notes) + "\n"
    )


def _write_text(path: Path, text: str) -> None:
    """Write ``path`` atomically (a reader never sees half a file): :func:`write_text_atomic`."""
    write_text_atomic(path, text)


def _failures(result: GridResult) -> str:
    if not result.failed:
        return ""
    lines = ["", "## failed episodes (retried by the next run)", ""]
    for rec in result.failed:
        last = rec.error.strip().splitlines()[-1] if rec.error.strip() else "?"
        lines.append(f"- {rec.policy_name} on {rec.scenario_name}, seed {rec.key.seed}: {last}")
    return "\n".join(lines) + "\n"


def _plots(
    args: argparse.Namespace, result: GridResult, out: Path, metadata: dict[str, str]
) -> None:
    """A set of plots per scenario and condition, and the overview ``trajectories.png`` per
    condition (:func:`plot_overview`; the condition in the file names when there are
    several)."""
    groups: dict[tuple[str, str], dict[str, Episode]] = defaultdict(dict)
    for rc in result.cells:
        ep = result.episodes.get(rc.key)
        if ep is not None:
            label = args.condition_of[rc.cell.overrides].label
            groups[(rc.cell.scenario, label)][rc.cell.policy.name] = ep
    slugs: dict[tuple[str, str], str] = {}
    for s in args.scenario:
        for c in args.conditions:
            slug = _slug(s) + (f"_{file_stem(c.label)}" if len(args.conditions) > 1 else "")
            while slug in slugs.values():
                slug += "_"
            slugs[(s, c.label)] = slug
    shown = _representatives(args.configurations)
    sets = [key for key in slugs if groups[key]]
    jobs = [(key[0], groups[key], out, slugs[key], metadata, shown) for key in sets]
    workers = min(int(getattr(args, "workers", 1) or 1), len(jobs))
    bar = tqdm(total=len(jobs), desc="plots", unit="plot set")
    if workers <= 1:
        for job in jobs:
            _plot_set(job)
            bar.update()
    else:  # each scenario's figures and GIFs in its own process (matplotlib is serial)
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor, as_completed

        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(workers, mp_context=context) as pool:
            for future in as_completed([pool.submit(_plot_set, job) for job in jobs]):
                future.result()
                bar.update()
    bar.close()
    for c in args.conditions:
        several = len(args.conditions) > 1
        panels = [
            (
                s,
                {
                    name: groups[(s, c.label)][name]
                    for name in shown
                    if name in groups[(s, c.label)]
                },
            )
            for s in args.scenario
        ]
        title = "The platoon at five instants, with its traces: " + ", ".join(shown)
        if several:
            title += f" ({c.label})"
        stem = "trajectories" + (f"_{file_stem(c.label)}" if several else "")
        if any(eps for _, eps in panels):
            plot_overview(panels, out / f"{stem}.png", title, metadata)


def _plot_set(job: tuple[str, dict[str, Episode], Path, str, dict[str, str], list[str]]) -> None:
    """One scenario's plots and GIFs (:func:`plot_scenario`), in a worker process of
    :func:`_plots` or in this one."""
    scenario, episodes, out, slug, metadata, shown = job
    os.environ.setdefault("MPLBACKEND", "Agg")
    plot_scenario(scenario, episodes, out, slug, metadata, overlaid=shown)


def _representatives(configs: Mapping[str, tuple[str, int | None]]) -> list[str]:
    """The policies of the overview figure: each analytic law, and a configuration's first
    training seed (its lowest)."""
    first: dict[str, tuple[int, str]] = {}
    for name, (configuration, seed) in configs.items():
        rank = -1 if seed is None else seed
        if configuration not in first or rank < first[configuration][0]:
            first[configuration] = (rank, name)
    return [name for _, name in first.values()]


if __name__ == "__main__":
    raise SystemExit(main())
