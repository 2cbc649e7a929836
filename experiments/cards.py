"""Model cards: ``models/<run>/README.md`` and the index ``models/README.md``, from the leaderboard.

A card states what a shipped model is (its configuration, seed and training options, read from
its ``model.json``), what it cost to train (timesteps, wall time on the machine that trained it),
how training ended (the last rows of its ``progress.csv``) and how it does on every leaderboard
task (this run's episodes, from the leaderboard's store). :func:`write_cards` is called by
``python -m experiments.studies.leaderboard``, which also draws the learning curves of every
configuration (:func:`training.curves.plot_learning_curves`).
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from experiments.configs import CONFIGS
from experiments.report import wilson, write_text_atomic
from experiments.suites import LEADERBOARD_SUITES as SUITES
from platoon_env.observation import OBS_NAMES_SCALE_FREE, OBS_NAMES_TASK
from training.algorithms import has_multiplier
from training.curves import plot_learning_curves, read_progress

if TYPE_CHECKING:
    from experiments.board import Board, Entry

__all__ = [
    "card_markdown",
    "core_hours",
    "cost_budget",
    "end_cost",
    "index_markdown",
    "training_cores",
    "write_cards",
]


#: What every card says about loading its model (``docs/security.md``).
LOADING_NOTE = (
    "`LearnedPolicy.load` reads `model.zip`'s weights only (nothing is unpickled); "
    "`LearnedPolicy.load_pickled` and SB3's own loader unpickle code: use them only on "
    "files you trust."
)


def training_cores(cfg: Mapping[str, Any]) -> int:
    """The CPU cores a recorded training run occupied, from its ``model.json`` ``config``.

    The trainer's process alternates the simulator (``env_threads`` numba threads) and torch
    (``torch_threads``), so it occupies the larger of the two; an RLlib run adds one process per
    env runner (``num_env_runners``) and per learner beyond the first (``num_learners``).
    """

    def count(key: str, default: int) -> int:
        return int(cfg.get(key) or default)

    cores = max(count("env_threads", 1), count("torch_threads", 1))
    if cfg.get("engine") == "rllib":
        cores += count("num_env_runners", 0) + max(count("num_learners", 0) - 1, 0)
    return cores


def core_hours(meta: Mapping[str, Any]) -> float:
    """A run's compute: its wall time (all segments) times :func:`training_cores`, in hours.

    NaN when ``model.json`` records no wall time.
    """
    wall = float(meta.get("wall_time_s") or math.nan)  # as _training_summary reads it
    return wall * training_cores(meta.get("config") or {}) / 3600.0


def _training_summary(meta: Mapping[str, Any]) -> list[str]:
    cfg = meta.get("config", {})
    layout = meta.get("observation_layout") or []
    wall = float(meta.get("wall_time_s") or math.nan)
    sb3 = meta.get("versions", {}).get("stable_baselines3", "?")
    net = cfg.get("net_arch") or [64, 64]
    trainer = meta.get("trainer")
    residual = meta.get("residual")
    return [
        f"- algorithm: `{meta.get('algo')}` "
        + (
            f"(trained by `{trainer}`, saved in Stable-Baselines3 {sb3}'s format)"
            if trainer
            else f"(Stable-Baselines3 {sb3})"
        )
        + (
            f", a residual on the `{residual}` law (`LearnedPolicy.bind(env)` builds the law)"
            if residual
            else ""
        )
        + (
            f", cost budget {cfg.get('cost_budget')} per follower episode, multiplier step "
            f"{cfg.get('lagrangian_lr')}"
            if has_multiplier(str(meta.get("algo")))
            else ""
        ),
        f"- trained on `{meta.get('scenario')}` with sensor profile "
        f"`{cfg.get('sensor_profile') or 'ideal'}`, control period {meta.get('control_period')} s, "
        f"{len(layout)}-value observation"
        + (" (task-aware)" if cfg.get("task_aware_observations") else ""),
        f"- seed {meta.get('seed')}; {meta.get('timesteps'):,} follower transitions in "
        f"{wall / 60:.1f} min ({meta.get('timesteps_per_s', math.nan):.0f} transitions/s, "
        f"{cfg.get('n_envs', '?')} env copies; {core_hours(meta):.2f} core-hours on "
        f"{training_cores(cfg)} core(s)); code "
        f"`{str(meta.get('git_commit') or '?')[:12]}`"
        + (" (dirty)" if meta.get("git_dirty") else ""),
        f"- network: {net} MLP; learning rate {cfg.get('learning_rate')}, "
        f"γ {cfg.get('gamma')}, PPO rollout {cfg.get('n_steps')} × slots, {cfg.get('n_epochs')} "
        "epochs",
    ]


def _curve_end(progress: Path, budget: float | None = None, rows: int = 5) -> str:
    """The end of a run's learning curve: its last ``rows`` logged windows' means, and with a
    cost ``budget`` (``ppo_lagrangian``) :func:`end_cost`'s verdict."""
    if not progress.is_file():
        return "no `progress.csv` (trained before learning curves were logged)"
    p = read_progress(progress)
    last = slice(-rows, None)
    return (
        f"over the last {min(rows, len(p['timesteps']))} logged windows (up to "
        f"{int(p['timesteps'][-1]):,} transitions): team success rate "
        f"{np.nanmean(p['success_rate'][last]):.2f}, follower episode cost "
        f"{np.nanmean(p['cost_mean'][last]):.3f}, return {np.nanmean(p['return_mean'][last]):.1f}"
        + (f", multiplier λ {p['lambda'][-1]:.3f}" if not math.isnan(p["lambda"][-1]) else "")
        + ("" if budget is None else f"; cost at the end of training {_end_cost(p, budget)}")
    )


#: The share of a run's transitions, at its end, over which :func:`end_cost` averages.
END_SHARE = 0.1


def end_cost(progress: Path, budget: float | None = None) -> str:
    """The follower episode cost at the end of training: over the logged windows of the last
    :data:`END_SHARE` of the run's transitions, the mean cost of the follower episodes that
    ended in them (weighted by their count) with a 95 % Wilson interval (the episodes counted
    as independent; a copy's followers end together, so it is somewhat narrow), and with a
    ``budget`` the verdict: **within** (mean at most the budget), **not significantly above**
    (the interval holds the budget: a multiplier holding the cost at its budget ends there
    about half the time), or **above**. ``–`` without ``progress.csv`` or episodes."""
    return _end_cost(read_progress(progress), budget) if progress.is_file() else "–"


def _end_cost(p: Mapping[str, NDArray[np.float64]], budget: float | None) -> str:
    """:func:`end_cost` of the learning curve ``p`` (:func:`read_progress`'s columns)."""
    steps = p["timesteps"]
    keep = (steps > (1.0 - END_SHARE) * steps[-1]) & (p["episodes"] > 0)
    n = int(p["episodes"][keep].sum())
    if n == 0:
        return "–"
    k = min(round(float((p["cost_mean"][keep] * p["episodes"][keep]).sum())), n)
    lo, hi = wilson(k, n)
    text = f"{k / n:.3f} [{lo:.3f}, {hi:.3f}] over {n:,} follower episodes"
    if budget is None:
        return text
    if k / n <= budget:
        verdict = "within"
    elif lo <= budget:
        verdict = "not significantly above"
    else:
        verdict = "above"
    return f"{text}, {verdict} its budget {budget:g}"


def cost_budget(meta: Mapping[str, Any]) -> float | None:
    """The cost budget of a ``ppo_lagrangian`` model's ``model.json`` (else None)."""
    if not has_multiplier(str(meta.get("algo"))):
        return None
    budget = (meta.get("config") or {}).get("cost_budget")
    return None if budget is None else float(budget)


def _task_lines(board: Board, entry: Entry, run: int) -> list[str]:
    lines = [
        "| task | episodes | success | violations by cause | rms e_d [m] | rms e_β [rad] |",
        "|---|---|---|---|---|---|",
    ]
    for t in board.tasks:
        eps = board.metrics[entry.name][run].get(t, [])
        if not eps:
            state = "refused" if (entry.name, t) in board.refused else "not run"
            lines.append(f"| {t.suite}: {t.label} | 0 | {state} | | | |")
            continue
        ok = sum(bool(m["success"]) for m in eps)
        causes = Counter(m["violation"] for m in eps if m["violation"])
        vio = ", ".join(f"{c} {n}" for c, n in causes.most_common()) or "0"
        rms = [m["rms_e_d"] for m in eps if math.isfinite(m["rms_e_d"])]
        rmb = [m["rms_e_beta"] for m in eps if math.isfinite(m["rms_e_beta"])]
        lines.append(
            f"| {t.suite}: {t.label} | {len(eps)} | {ok}/{len(eps)} | {vio} | "
            f"{np.mean(rms) if rms else math.nan:.3f} | {np.mean(rmb) if rmb else math.nan:.3f} |"
        )
    return lines


def _observation_option(meta: Mapping[str, Any]) -> str:
    """The ``observation=`` option of ``make`` for the layout the model reads."""
    layout = tuple(meta.get("observation_layout") or ())
    if layout == OBS_NAMES_SCALE_FREE:
        return '{"task_aware": True, "scale_free": True}'
    return '{"task_aware": True}' if layout == OBS_NAMES_TASK else "{}"


def _profile(meta: Mapping[str, Any]) -> str:
    """The ``sensor_profile=`` value (Python source) of the profile the model was trained under:
    its quoted name, or None (ideal sensing)."""
    config = meta.get("config") or {}
    profile = config.get("sensor_profile") if isinstance(config, Mapping) else None
    return "None" if profile is None else f'"{profile}"'


def card_markdown(board: Board, entry: Entry, run: int, summary: str = "") -> str:
    """The card of ``entry``'s run ``run``."""
    spec = entry.runs[run]
    meta = spec.model_metadata()
    folder = spec.path.parent if spec.path is not None else Path(".")
    lines = [
        f"# `{spec.name}`",
        "",
        f"Configuration **`{entry.name}`**, training seed {meta.get('seed')}"
        + (f": {summary}." if summary else "."),
        "Made by `platoon-leaderboard`; the numbers are this seed's episodes in its "
        "store. Train it again with `python -m experiments.studies.sweep --config "
        f"{entry.name} --seeds {meta.get('seed')}`.",
        "",
        "## Training",
        "",
        *_training_summary(meta),
        f"- learning curve: {_curve_end(folder / 'progress.csv', cost_budget(meta))}",
        "",
        "## Evaluation (every leaderboard task)",
        "",
        *_task_lines(board, entry, run),
        "",
        "## Use",
        "",
        "```python",
        "import platoon_env",
        "from training.policies import LearnedPolicy",
        f'policy = LearnedPolicy.load("models/{spec.name}/model.zip")',
        'env = platoon_env.make("study_c", control_period=policy.control_period,',
        f"                       observation={_observation_option(meta)}, "
        f"sensor_profile={_profile(meta)})",
        "policy.check_env(env)  # refuses another observation layout or control period",
        *(
            ["policy.bind(env)  # builds the law the residual policy adds to"]
            if meta.get("residual")
            else []
        ),
        "```",
        "",
        LOADING_NOTE,
        "",
    ]
    return "\n".join(lines)


def index_markdown(board: Board, summaries: Mapping[str, str]) -> str:
    """``models/README.md``: what is shipped and how each run does."""

    lines = [
        "# Shipped models",
        "",
        "Each folder holds `model.zip` (Stable-Baselines3), `model.json` (what `platoon-train` "
        "recorded: scenario and its resolved config, control period, observation and action "
        "layout, action range, every option, commit, versions, training segments and wall time), "
        "`progress.csv` (the learning curve, `training.curves`) and its card `README.md`. "
        "`LearnedPolicy.load(path)` loads one (it refuses a zip that is not the one its "
        "`model.json` describes); `policy.check_env(env)` says whether an env suits it.",
        "",
        "The folders `<configuration>_s<seed>` are the training seeds of one configuration, "
        "trained by `platoon-sweep` (`--list` prints each configuration's options). "
        "The cards, this table and the learning curves are written by "
        "`python -m experiments.studies.leaderboard`.",
        "",
        "The training cost is the follower episode cost (the share of follower episodes with a "
        "violation) at the end of training: over the last 10 % of the run's transitions, with "
        "a 95 % Wilson interval and, for PPO-Lagrangian runs, the verdict against the run's "
        "budget (`experiments.cards.end_cost`).",
        "",
        "| model | configuration | seed | transitions | wall time | core-hours | training cost | "
        + " | ".join(f"{s} success" for s in SUITES)
        + " |",
        "|---|---|---|---|---|---|---|" + "---|" * len(SUITES),
    ]
    for e in board.entries:
        if not e.learned:
            continue
        for i, spec in enumerate(e.runs):
            meta = spec.model_metadata()
            folder = spec.path.parent if spec.path is not None else Path(".")
            wall_min = float(meta.get("wall_time_s") or 0) / 60
            rates = []
            for s in SUITES:
                eps = [m for t in board.suite_tasks(s) for m in board.metrics[e.name][i].get(t, [])]
                ok = sum(bool(m["success"]) for m in eps)
                rates.append(f"{ok}/{len(eps)}" if eps else "–")
            lines.append(
                f"| [`{spec.name}`]({spec.name}/README.md) | `{e.name}` | {meta.get('seed')} | "
                f"{meta.get('timesteps', 0):,} | {wall_min:.1f} min | {core_hours(meta):.2f} | "
                f"{end_cost(folder / 'progress.csv', cost_budget(meta))} | "
                + " | ".join(rates)
                + " |"
            )
    lines += ["", "Configurations:", ""]
    lines += [f"- `{k}`: {v}" for k, v in summaries.items()]
    lines += [
        "",
        LOADING_NOTE,
        "",
    ]
    return "\n".join(lines)


def write_cards(board: Board, models: Path, curves: Path, metadata: Mapping[str, str]) -> None:
    """Every learned run's card, the index and the learning-curve figure."""

    summaries = {
        e.name: CONFIGS[e.name].summary if e.name in CONFIGS else ""
        for e in board.entries
        if e.learned
    }
    progress: dict[str, list[Path]] = {}
    for e in board.entries:
        if not e.learned:
            continue
        for i, spec in enumerate(e.runs):
            assert spec.path is not None
            folder = spec.path.parent
            write_text_atomic(folder / "README.md", card_markdown(board, e, i, summaries[e.name]))
            if (folder / "progress.csv").is_file():
                progress.setdefault(e.name, []).append(folder / "progress.csv")
    write_text_atomic(Path(models) / "README.md", index_markdown(board, summaries))
    if progress:
        plot_learning_curves(progress, curves, metadata=metadata)
