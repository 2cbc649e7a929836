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
with the fingerprints), ``OUT/summary.md`` (per scenario × policy, 95 % confidence intervals;
its header counts the rows it summarises and says which code made them) and ``OUT/plots/``
(trajectories, errors against the constraints, velocity commands, a GIF per policy, from the
first seed's episodes).

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
import os
import re
import sys
from collections import defaultdict
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tqdm import tqdm

import platoon_env
from experiments.cli import add_models_option, add_workers_option, count, new_parser, number
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
    default_models_dir,
    shipped_models,
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
)
from experiments.stamp import metadata_stamp, png_metadata
from experiments.store import Store, StoreError
from experiments.suites import SUITES, Condition, suite
from platoon_env.extras import MissingExtraError, require_extra
from platoon_env.rollout import METRIC_NAMES, Episode, PolicyLike
from platoon_env.scenarios.fingerprint import canonical_json
from platoon_env.scenarios.loader import read_yaml
from platoon_env.scenarios.schema import ScenarioError, config_to_mapping

__all__ = [
    "CSV_COLUMNS",
    "DEFAULT_SCENARIOS",
    "PolicySpec",
    "Realism",
    "build",
    "default_policies",
    "main",
    "mean_ci",
    "nest_assignments",
    "parse_args",
    "parse_assignment",
    "plot_scenario",
    "resolved_realism",
    "summarise",
    "wilson",
]

DEFAULT_SCENARIOS = ("study_a", "study_b", "study_c", "procedural_test")
#: Episodes (seeds) per policy and scenario by default: every table on the studies is over at
#: least 20 seeds (each draws its own leader speed factor and start perturbation).
DEFAULT_EPISODES = 20
#: The scenario blocks the realism flags override, and record (resolved) with every row.
REALISM_BLOCKS: tuple[str, ...] = ("camera", "proximity", "robot")
#: Columns of the ``results.csv`` export.
CSV_COLUMNS: tuple[str, ...] = (
    "policy",
    "scenario",
    "seed",
    "status",
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
    """The markdown tables of ``summary.md``: one line per scenario × policy; rows of several
    realism settings (the ``realism_label`` column) get a table each, never mixed."""
    by_realism: dict[str, list[dict[str, str]]] = defaultdict(list)
    for r in rows:
        by_realism[r.get("realism_label", "") or "none"].append(r)
    if len(by_realism) <= 1:
        return _summary_table(next(iter(by_realism.values()), []))
    return "\n\n".join(
        f"### realism: {label}\n\n{_summary_table(rs)}" for label, rs in sorted(by_realism.items())
    )


def _summary_table(rows: Iterable[dict[str, str]]) -> str:
    """One line per scenario × policy over the rows with a result."""
    groups: dict[tuple[str, str], list[dict[str, str]]] = defaultdict(list)
    for r in rows:
        if r.get("status", "done") == "done":
            groups[(r["scenario"], r["policy"])].append(r)
    lines = [
        "| scenario | policy | episodes | seeds | success [95% CI] | violations by cause | "
        "rms e_d [m] | rms e_beta [rad] | min clearance [m] | min robot distance [m] | "
        "peak u [m/s] | peak omega [rad/s] | funnel exits |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
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

        seeds = seed_ranges(int(r["seed"]) for r in rs)
        lines.append(
            f"| {scenario} | {policy} | {n} | {seeds} | {ok}/{n} [{lo:.2f}, {hi:.2f}] | {viol} | "
            f"{mean_ci(f('rms_e_d'))} | {mean_ci(f('rms_e_beta'))} | "
            f"{min(f('min_obstacle_clearance')):.3f} | {min(f('min_inter_robot_distance')):.3f} | "
            f"{max(f('peak_u')):.2f} | {max(f('peak_omega')):.2f} | "
            f"{sum(int(r['funnel_exits']) for r in rs)} |"
        )
    return "\n".join(lines)


def export_rows(result: GridResult, conditions: Mapping[str, Condition]) -> list[dict[str, Any]]:
    """The ``results.csv`` rows of a grid: every cell with a row in the store; ``conditions``
    names each cell's condition by its overrides (JSON)."""
    rows = []
    for rc in result.cells:
        rec = result.records.get(rc.key)
        if rec is None or rec.status == "running":
            continue
        rows.append(
            {
                "policy": rc.cell.policy.name,
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


def plot_scenario(
    scenario: str,
    episodes: dict[str, Episode],
    out: Path,
    slug: str | None = None,
    metadata: dict[str, str] | None = None,
) -> list[Path]:
    """Comparison plots of one scenario (one episode per policy) and a GIF per policy, into
    ``out`` under the file-name stem ``slug`` (default: the scenario's name); ``metadata``
    are the PNG text fields (the run's stamp)."""
    from platoon_env.plots import (
        new_figure,
        plot_commands,
        plot_errors,
        plot_snapshots,
        save_figure,
        save_gif,
    )

    slug = file_stem(slug) if slug else _slug(scenario)
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
    paths = [save_figure(fig, out / f"{slug}_trajectories.png", metadata)]
    n = sc.config.followers
    followers = [1, n] if n > 2 else None
    fig = new_figure(9, 1.2 + 1.4 * (len(followers) if followers else n))
    plot_errors(fig, sc, eps, labels=names, followers=followers)
    fig.suptitle(f"{scenario}, seed {eps[0].seed}: errors and safety limits (dashed)")
    paths.append(save_figure(fig, out / f"{slug}_errors.png", metadata))
    fig = new_figure(9, 1.2 + 1.2 * (len(followers) if followers else n))
    plot_commands(fig, sc, eps, labels=names, followers=followers)
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
    parser.add_argument("--out", type=Path, default=Path("results/benchmark"), help="output folder")
    add_models_option(parser, "the default policies include")
    add_workers_option(parser)
    parser.add_argument("--no-plots", action="store_true", help="skip plots and GIFs")
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
    the_suite = suite(args.suite) if args.suite else None
    if the_suite is not None:
        given = [f for f in ("scenario", *REALISM_BLOCKS) if getattr(args, f)]
        given += ["sensor_profile"] if args.sensor_profile else []
        if given:
            flags = ", ".join("--" + g.replace("_", "-") for g in given)
            parser.error(f"--suite {args.suite} sets the scenarios and conditions; drop {flags}")
    if args.episodes is None:
        args.episodes = the_suite.seeds if the_suite is not None else DEFAULT_EPISODES
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
    if args.policy is None:
        args.policy = default_policies(args.models)
        if not any(p.kind == MODEL for p in args.policy):
            print(
                "note: no trained models found (looked in the source checkout's models/ and "
                "./models); running the analytic policies only: pass --models DIR to add them",
                file=sys.stderr,
            )
    elif args.models is not None:
        parser.error("--models adds models to the default policies; with --policy name each model")
    if any(p.kind == MODEL for p in args.policy):
        try:
            require_extra(
                "train", "stable_baselines3", "torch", purpose="evaluating trained models"
            )
        except MissingExtraError as exc:
            parser.error(str(exc))
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
    args.conditions = conditions
    # Resolve every cell now: a bad scenario, profile or override is a usage error here, and
    # the same scenario given twice (a name, a path to the same content) runs once.
    default = the_suite.scenarios if the_suite is not None else DEFAULT_SCENARIOS
    scenarios = list(dict.fromkeys(args.scenario or default))
    seeds = range(args.seed, args.seed + args.episodes)
    cells = [
        Cell.of(spec, s, seed, cond.overrides)
        for cond in conditions
        for s in scenarios
        for spec in args.policy
        for seed in seeds
    ]
    # each cell's condition by the cell's overrides (the canonical JSON Cell.of writes)
    args.condition_of = {canonical_json(dict(c.overrides)): c for c in conditions}
    try:
        args.cells = resolve_cells(cells)
    except (ScenarioError, TypeError, OSError, ValueError) as exc:
        detail = str(exc) if isinstance(exc, ScenarioError | TypeError) else f"{exc}"
        parser.error(f"{detail}")
    args.scenario = _distinct_scenarios(args.cells, scenarios)
    args.policy = _distinct_policies(args.cells, args.policy)
    args.resolved = {
        (rc.cell.scenario, args.condition_of[rc.cell.overrides].label): resolved_realism(rc.config)
        for rc in args.cells
    }
    return args


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


def _model_notes(args: argparse.Namespace) -> list[str]:
    """What each learned model's ``check_env`` says of each scenario it is evaluated on: the
    legitimate differences from its training (another scenario family, more followers, ...).
    A refusal is not raised here: the episodes record it (status ``refused``)."""
    from training.policies import LearnedPolicy

    notes = []
    for spec in args.policy:
        if spec.kind != "model":
            continue
        try:
            policy = LearnedPolicy.load(spec.path)
        except (OSError, ValueError) as exc:
            notes.append(f"{spec.name}: cannot be loaded ({exc})")
            continue
        for s in args.scenario:
            env = platoon_env.make(s, **merge_overrides(spec, args.overrides))
            try:
                for note in policy.check_env(env):
                    notes.append(f"{spec.name} on {s}: {note}")
            except ValueError as exc:
                notes.append(f"{spec.name} on {s}: refused ({exc})")
    return notes


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
    for note in args.model_notes:
        print(f"note: {note}")
    first_seed = args.seed

    def keep(cell: Cell) -> bool:
        return not args.no_plots and cell.seed == first_seed

    try:
        store = Store(store_path(out))
    except StoreError as exc:
        print(f"{_TOOL}: error: {exc}", file=sys.stderr)
        return 2
    try:
        return _run(args, store, stamp, keep)
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
) -> int:
    """The grid and the exports of :func:`main` (``store`` is closed at the end)."""
    out: Path = args.out
    with store:
        result = run_grid(
            store,
            args.cells,
            tool=_TOOL,
            stamp=stamp,
            workers=args.workers,
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
        rows = export_rows(result, args.condition_of)
        write_csv(out / "results.csv", CSV_COLUMNS, rows)
        records = [result.records[rc.key] for rc in result.cells if rc.key in result.records]
        write_csv_stamp(out / "results.csv", store, records, result.run_id)
        summary = summarise(_csv_strings(rows))
        header = _summary_header(args, result, store, rows)
    (out / "summary.md").write_text(header + summary + "\n" + _failures(result))
    print(summary)
    if not args.no_plots:
        _plots(args, result, out / "plots", png_metadata(stamp))
    print(
        f"wrote {out / 'results.csv'}, {out / 'summary.md'}"
        + ("" if args.no_plots else f", {out / 'plots'}/")
    )
    if result.failed:
        print(f"{len(result.failed)} episode(s) failed (see summary.md); re-run to retry them")
        return 1
    return 0


def _summary_header(
    args: argparse.Namespace, result: GridResult, store: Store, rows: list[dict[str, Any]]
) -> str:
    done = [r for r in rows if r["status"] == "done"]
    policies = ", ".join(f"{p.name} (`{p.fingerprint()[:12]}`)" for p in args.policy)
    scenario_lines = "".join(
        f"- {s} ({label}): resolved camera, proximity and robot blocks `{blocks}`\n"
        for (s, label), blocks in args.resolved.items()
    )
    records = [result.records[rc.key] for rc in result.cells if rc.key in result.records]
    realism_keys = {*REALISM_BLOCKS, "sensor_profile"}
    other = {k: v for k, v in args.overrides.items() if k not in realism_keys}
    if args.suite:
        conditions = ", ".join(c.label for c in args.conditions)
        realism = f"suite {args.suite}: conditions {conditions}"
    else:
        realism = f"realism flags: {args.realism.label}"
    return (
        f"# {_TOOL}\n\n"
        f"{len(done)} episodes summarised (seeds {seed_ranges(int(r['seed']) for r in done)}); "
        f"grid: {len(args.policy)} policies × {len(args.scenario)} scenarios × "
        f"{len(args.conditions)} condition(s) × seeds "
        f"{seed_ranges(range(args.seed, args.seed + args.episodes))} = {len(result.cells)} "
        f"episodes, {result.ran} run now and {result.reused} resumed from the store; "
        f"{len(result.failed)} failed; wall time of this run {result.wall_time:.0f} s.\n\n"
        f"policies (fingerprint): {policies}\n\n"
        f"{realism}; other overrides: {json.dumps(other)}\n\n"
        f"{scenario_lines}\n"
        + "".join(f"- note: {_short(n)}\n" for n in args.model_notes)
        + f"\n{provenance_markdown(store, records, result.run_id)}\n"
    )


def _short(text: str, limit: int = 300) -> str:
    return text if len(text) <= limit else text[: limit - 3] + "..."


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
    """A set of plots per scenario and condition (the condition in the file name when there
    are several)."""
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
    for key in tqdm(list(slugs), desc="plots", unit="plot set"):
        if groups[key]:
            plot_scenario(key[0], groups[key], out, slugs[key], metadata)


if __name__ == "__main__":
    raise SystemExit(main())
