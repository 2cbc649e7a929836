"""The leaderboard's data: its entries (policies and their training seeds), its tasks (a
scenario under a condition, in a suite) and the board (every episode's metrics by entry, run
and task), built from the evaluation store's grid.

:mod:`experiments.studies.leaderboard` computes the statistics and writes the tables from a
:class:`Board`; :mod:`experiments.cards` writes the model cards from one. Both import
this module, and it imports neither.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from experiments.grid import Cell, GridResult, ResolvedCell, resolve_cells
from experiments.policies import PolicySpec, analytic_policies, configurations, shipped_models
from experiments.suites import LEADERBOARD_SUITES, Condition, suite
from platoon_env.scenarios.schema import ScenarioError

__all__ = [
    "ANALYTIC",
    "ORACLE_LABEL",
    "ORACLE_SUMMARY_FORMAT",
    "PARTITIONED_SUITES",
    "SPLIT_SUITES",
    "SUITES",
    "Board",
    "Entry",
    "Task",
    "TooFewLayoutsError",
    "build_board",
    "cells",
    "entries",
    "episode_seeds",
    "load_oracle",
    "span",
    "task_counts",
    "task_outcome",
    "tasks",
]

#: The analytic laws on the board (registry names).
ANALYTIC: tuple[str, ...] = tuple(analytic_policies("leaderboard"))
#: The suites on the board.
SUITES = LEADERBOARD_SUITES
#: The suites on which a configuration's runs **split** the episode seeds (:func:`episode_seeds`):
#: the paper's studies, where an episode seed draws a start perturbation and the sensing noise.
#: There run ``k`` plays seeds ``k·n … k·n + n − 1`` and an analytic law all of them, so that a
#: configuration's pooled episodes and an analytic law's are as many, on the same seeds, none
#: repeated. On the held-out tiers a seed draws a layout, the test item: see
#: :data:`PARTITIONED_SUITES`.
SPLIT_SUITES: tuple[str, ...] = ("paper",)
#: The suites whose ``n`` layouts every entry plays **once**, its runs sharing them out
#: (:func:`episode_seeds`): the held-out tiers, where a seed draws a layout, the test item. A
#: configuration's run ``k`` of ``R`` plays layouts ``⌊k·n/R⌋ … ⌊(k+1)·n/R⌋ − 1`` and an
#: analytic law all ``n``. Every entry's pooled episodes are then the same ``n`` layouts, none
#: counted twice in a pooled test (five runs on the same layouts would be 5n episodes of n
#: items), and a configuration costs n episodes per task, not R·n.
PARTITIONED_SUITES: tuple[str, ...] = ("heldout",)


@dataclass(frozen=True)
class Entry:
    """One row group of the board: a policy configuration and its runs (training seeds)."""

    name: str
    runs: tuple[PolicySpec, ...]
    learned: bool


@dataclass(frozen=True)
class Task:
    """A scenario under a condition, in a suite, with ``seeds`` episodes per run (which seeds:
    :func:`episode_seeds`)."""

    suite: str
    scenario: str
    condition_label: str
    seeds: int
    #: The condition itself (its overrides are a dict: the label stands for it in comparisons).
    condition: Condition = field(compare=False, default=Condition("ideal"))

    @property
    def label(self) -> str:
        short = self.scenario.removeprefix("procedural_").removesuffix("_test")
        return f"{short}/{self.condition.label}"

    @property
    def split(self) -> bool:
        """Whether a configuration's runs split this task's seeds (:data:`SPLIT_SUITES`)."""
        return self.suite in SPLIT_SUITES

    @property
    def partitioned(self) -> bool:
        """Whether an entry's runs share out this task's layouts (:data:`PARTITIONED_SUITES`)."""
        return self.suite in PARTITIONED_SUITES


def span(board_entries: Sequence[Entry]) -> int:
    """The most runs of any entry: on a split task an analytic law plays that many runs'
    seeds."""
    return max((len(e.runs) for e in board_entries), default=1)


def episode_seeds(task: Task, entry: Entry, run: int, runs: int) -> range:
    """The episode seeds of ``entry``'s run number ``run`` (its index in ``entry.runs``) on
    ``task``, ``runs`` being :func:`span` of the board: on a split task (:data:`SPLIT_SUITES`)
    ``run·seeds …`` for a configuration's run and ``0 … runs·seeds − 1`` for an analytic law; on
    a partitioned one (:data:`PARTITIONED_SUITES`) the ``run``-th of ``len(entry.runs)`` slices
    of ``0 … seeds − 1`` (a one-run entry: all of them); else ``0 … seeds − 1``."""
    n = task.seeds
    if task.partitioned:
        r = len(entry.runs)
        return range(run * n // r, (run + 1) * n // r)
    if not task.split:
        return range(n)
    if entry.learned:
        return range(run * n, (run + 1) * n)
    return range(runs * n)


def entries(models_dir: Path) -> list[Entry]:
    """The analytic laws, then the configurations of ``models_dir`` (its ``*_s<seed>``
    folders grouped by the name before the suffix; a folder without one is a configuration of
    one run)."""
    out = [Entry(name, (PolicySpec.of(name),), False) for name in ANALYTIC]
    groups: dict[str, list[PolicySpec]] = {}
    models = shipped_models(Path(models_dir))
    configs = configurations(models)
    for spec in models:
        groups.setdefault(configs[spec.name][0], []).append(spec)
    out += [Entry(name, tuple(specs), True) for name, specs in sorted(groups.items())]
    return out


def tasks(paper_seeds: int | None = None, heldout_seeds: int | None = None) -> list[Task]:
    """Every task of the board's suites (``None``: the suite's own number of seeds)."""
    counts = {"paper": paper_seeds, "heldout": heldout_seeds}
    out = []
    for name in SUITES:
        s = suite(name)
        given = counts[name]
        n = s.seeds if given is None else given
        if n < 1:
            raise ValueError(f"{name} seeds must be >= 1, got {n}")
        for scenario in s.scenarios:
            for condition in s.conditions:
                out.append(Task(name, scenario, condition.label, n, condition))
    return out


class TooFewLayoutsError(ValueError):
    """A partitioned task (:data:`PARTITIONED_SUITES`) has fewer layouts than a configuration
    has runs to share them out among: some run would play none."""


def cells(
    board_entries: Sequence[Entry], board_tasks: Sequence[Task]
) -> tuple[list[ResolvedCell], dict[tuple[str, Task], str]]:
    """The resolved cells of every entry run × task × seed, and the (entry, task) pairs that
    cannot run at all, with the reason (a model whose control period the condition's sensors
    refuse, e.g. a 20 Hz policy with a 30 Hz camera). :class:`TooFewLayoutsError` if a
    partitioned task has fewer layouts than the board's most runs."""
    out: list[ResolvedCell] = []
    refused: dict[tuple[str, Task], str] = {}
    runs = span(board_entries)
    short = [t for t in board_tasks if t.partitioned and t.seeds < runs]
    if short:
        raise TooFewLayoutsError(
            f"{short[0].suite} has {short[0].seeds} layouts per task, fewer than the {runs} runs "
            "of a configuration that share them out: every run needs at least one"
        )
    for e in board_entries:
        for k, spec in enumerate(e.runs):
            for t in board_tasks:
                group = [
                    Cell.of(spec, t.scenario, seed, t.condition.overrides)
                    for seed in episode_seeds(t, e, k, runs)
                ]
                try:
                    out += resolve_cells(group, unique=True)
                except ScenarioError as exc:
                    refused[(e.name, t)] = f"{spec.name}: {exc}"
    return list({rc.key: rc for rc in out}.values()), refused


# ----------------------------------------------------------------------------------------------
# The board: per-episode metrics arranged by entry, run and task
# ----------------------------------------------------------------------------------------------


@dataclass
class Board:
    """The metrics of every episode, ``metrics[entry][run][task]`` = a list over seeds (each
    with its ``seed``: the comparisons pair episodes by it), and the cells that were refused
    (the policy cannot run there) or failed."""

    entries: list[Entry]
    tasks: list[Task]
    metrics: dict[str, list[dict[Task, list[dict[str, Any]]]]]
    refused: dict[tuple[str, Task], str] = field(default_factory=dict)
    missing: int = 0

    def suite_tasks(self, name: str) -> list[Task]:
        return [t for t in self.tasks if t.suite == name]

    def episodes(self, entry: str, suite_name: str) -> list[dict[str, Any]]:
        """Every episode of ``entry`` on ``suite_name`` (all runs, tasks and seeds)."""
        return [
            m
            for run in self.metrics[entry]
            for t in self.suite_tasks(suite_name)
            for m in run.get(t, [])
        ]

    def success_matrix(self, entry: str, task_list: Sequence[Task]) -> NDArray[np.float64]:
        """``(runs, tasks)`` success rates of ``entry`` (NaN for a task it has no episode of)."""
        out = np.full((len(self.metrics[entry]), len(task_list)), math.nan)
        for i, run in enumerate(self.metrics[entry]):
            for j, t in enumerate(task_list):
                eps = run.get(t, [])
                if eps:
                    out[i, j] = np.mean([bool(m["success"]) for m in eps])
        return out

    def counts(self, entry: str, task_list: Sequence[Task]) -> NDArray[np.int64]:
        """``(runs, tasks, 2)``: per run and task, (successes, episodes); episodes 0 for a
        task the run has no episode of."""
        out = np.zeros((len(self.metrics[entry]), len(task_list), 2), dtype=np.int64)
        for i, run in enumerate(self.metrics[entry]):
            for j, t in enumerate(task_list):
                eps = run.get(t, [])
                out[i, j] = (sum(bool(m["success"]) for m in eps), len(eps))
        return out

    def episode_matrix(self, entry: str, task_list: Sequence[Task]) -> NDArray[np.float64]:
        """``(episodes, tasks)`` 0/1 successes of a one-run entry (seed ``s`` is row ``s``)."""
        run = self.metrics[entry][0]
        n = max((len(run.get(t, [])) for t in task_list), default=0)
        out = np.full((n, len(task_list)), math.nan)
        for j, t in enumerate(task_list):
            for s, m in enumerate(run.get(t, [])):
                out[s, j] = float(bool(m["success"]))
        return out


def build_board(
    board_entries: Sequence[Entry],
    board_tasks: Sequence[Task],
    result: GridResult,
    refused: Mapping[tuple[str, Task], str] | None = None,
) -> Board:
    """Arrange a grid's records by entry, run and task (in seed order); ``refused``: the pairs
    :func:`cells` could not resolve."""
    records = result.records
    by_cell = {rc.cell: rc for rc in result.cells}
    metrics: dict[str, list[dict[Task, list[dict[str, Any]]]]] = {}
    refused = dict(refused or {})
    missing = 0
    n_runs = span(board_entries)
    for e in board_entries:
        runs = []
        for k, spec in enumerate(e.runs):
            per_task: dict[Task, list[dict[str, Any]]] = {}
            for t in board_tasks:
                eps = []
                if (e.name, t) in refused:
                    continue
                for seed in episode_seeds(t, e, k, n_runs):
                    rc = by_cell.get(Cell.of(spec, t.scenario, seed, t.condition.overrides))
                    rec = None if rc is None else records.get(rc.key)
                    if rec is None or rec.status == "failed":
                        missing += 1
                    elif rec.status == "refused":
                        refused[(e.name, t)] = rec.error.strip().splitlines()[-1][:200]
                    else:
                        eps.append({**rec.metrics, "seed": seed})
                if eps:
                    per_task[t] = eps
            runs.append(per_task)
        metrics[e.name] = runs
    return Board(list(board_entries), list(board_tasks), metrics, refused, missing)


def task_counts(board: Board, entry: str, task: Task) -> tuple[int, int]:
    """(successes, episodes) of ``entry`` on ``task``, its runs' episodes pooled."""
    eps = [m for run in board.metrics[entry] for m in run.get(task, [])]
    return sum(bool(m["success"]) for m in eps), len(eps)


def task_outcome(board: Board, entry: str, task: Task) -> tuple[float, str] | None:
    """``entry``'s success rate on ``task`` over all its runs' episodes, and the most frequent
    violation cause ("" if none); None without an episode (refused or not run)."""
    eps = [m for run in board.metrics[entry] for m in run.get(task, [])]
    if not eps:
        return None
    worst = Counter(m["violation"] for m in eps if m["violation"]).most_common(1)
    return float(np.mean([bool(m["success"]) for m in eps])), worst[0][0] if worst else ""


# ----------------------------------------------------------------------------------------------
# The privileged oracle's results (written by the feasibility driver)
# ----------------------------------------------------------------------------------------------
#: How the privileged oracle is named in the board's tables and figures.
ORACLE_LABEL = "oracle (privileged)"
#: The ``format`` of the oracle's summary file (``python -m experiments.studies.feasibility``
#: writes it as ``feasibility.json``; the leaderboard marks the oracle from it).
ORACLE_SUMMARY_FORMAT = "platoon_env feasibility summary 1"


def load_oracle(path: Path) -> dict[str, tuple[int, int]]:
    """The privileged oracle's ``(successes, episodes)`` per task label (``study_b/aruco``)
    from a feasibility summary; a ``ValueError`` naming the file and the field otherwise."""
    import json

    try:
        data = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: cannot read the oracle's results ({exc})") from None
    if not isinstance(data, dict) or data.get("format") != ORACLE_SUMMARY_FORMAT:
        raise ValueError(f"{path}: not a feasibility summary (format {ORACLE_SUMMARY_FORMAT!r})")
    tasks_ = data.get("tasks")
    if not isinstance(tasks_, dict):
        raise ValueError(f"{path}: its tasks must be a mapping")
    out: dict[str, tuple[int, int]] = {}
    for task, row in tasks_.items():
        k = row.get("successes") if isinstance(row, dict) else None
        n = row.get("episodes") if isinstance(row, dict) else None
        if (
            not isinstance(k, int)
            or not isinstance(n, int)
            or isinstance(k, bool)
            or isinstance(n, bool)
            or not 0 <= k <= n
            or n < 1
        ):
            raise ValueError(f"{path}: tasks.{task} must hold successes <= episodes (>= 1)")
        out[str(task)] = (k, n)
    return out
