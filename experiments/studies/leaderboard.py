"""The leaderboard: every policy on the ``paper`` and ``heldout`` suites, with their statistics.

Usage::

    python -m experiments.studies.leaderboard                    # the README's leaderboard
    python -m experiments.studies.leaderboard --paper-seeds 5 --heldout-seeds 10 --no-readme

It runs, through the evaluation store (``--store``, default ``results/leaderboard``; an
interrupted run resumes, and episodes already stored are not run again):

* the analytic laws of the policy registry (:data:`ANALYTIC`: those whose
  ``experiments.policies`` entry names the leaderboard);
* every shipped model ``models/<config>_s<seed>/``: the folders whose names differ only in
  the ``_s<seed>`` suffix are the training seeds (**runs**) of one **configuration**;

on every **task** of the two suites (:mod:`experiments.suites`): a scenario under a
condition — ``paper``: studies A, B, C × {ideal, aruco}; ``heldout``: the test split of every
procedural tier × {ideal, aruco}. The episode seeds (:func:`~experiments.board.
episode_seeds`): on a held-out task every policy plays each of the ``n`` layouts (seeds
``0 … n − 1``) once, a configuration's runs sharing them out (run ``k`` of ``R``: the ``k``-th of
``R`` near-equal slices); on a paper study a configuration's runs split the seeds (run ``k``:
``k·n … k·n + n − 1``) and an analytic law plays all of them. Either way a configuration's
pooled episodes and an analytic law's are as many, on the same seeds, and no layout or start is
counted twice in a pooled test.

Statistics (:mod:`experiments.significance`, :mod:`experiments.stats`), per policy, suite and
condition (ideal and aruco are reported apart: they share layouts, so they are not
independent tasks):

* **mean success**: the mean over tasks of the task success rates (every task weighs the same),
  with a 95 % hierarchical-bootstrap interval (training seeds, then each seed's episodes; an
  analytic law is one seed, so only its episode noise); an **IQM** beside it only where the
  entry has at least :data:`IQM_MIN_SCORES` run × task scores;
* **violations per 1,000 steps**, by cause: episodes ending with that cause, per 1,000 control
  steps of 10 ms (the policies run at different control periods: the analytic laws at the
  scenario's 10 ms, the models at the 25 ms they were trained at, so a raw step count would
  favour the slower period);
* **rms e_d**, **rms e_β** and **effort** (``platoon_env.rollout.episode_metrics``): the mean over
  episodes of the episode values (those with a finite value: a follower that never saw its
  predecessor has none);
* per task: the successes with a 95 % Wilson interval, floor (⊥) and ceiling (⊤) flagged, and
  the most frequent violation; beside them the graded outcome (:func:`task_graded`): the mean
  fraction of the leader's path done before the first violation and the median smallest
  distance or bearing margin, so that an unsolved task shows progress;
* **pairwise comparisons**, in two families each Holm-adjusted on its own: the
  **confirmatory** one fixed in code (:func:`confirmatory`: each learned configuration
  against each analytic law on each goal task; the goal reads it) and the **exploratory** one
  (:func:`comparisons`: every pair of entries on every task both ran). Each comparison pairs
  the two entries' episodes of the same seed (:func:`paired_outcomes`) and is an exact
  McNemar test with Newcombe's paired interval of the difference
  (:func:`experiments.significance.compare_paired`); ties at the floor or the ceiling are
  flagged, not tested; the confirmatory family as a win/loss grid and every entry's success
  per task with its interval as a forest figure (:mod:`experiments.board_figures`);
* the **probability of improvement** of each learned configuration over PPC and the filtered
  PPC, on the success rates of all tasks of both suites, with its interval;
* **performance profiles** (the fraction of run × task success rates above each threshold);
* the learned side's **goal** for each configuration (:func:`goal`): every training seed
  completes each of studies A, B and C under ideal sensing in at least 95 % of its episodes,
  and under aruco the configuration beats the filtered PPC on at least one study and loses on
  none, by the Holm-adjusted comparisons.

Outputs: ``docs/leaderboard.md`` (every table, with the provenance of its rows), the figures
``docs/figures/leaderboard_*.png``, the learning curves ``docs/figures/learning_curves.png``,
each model's card ``models/<run>/README.md`` and the index ``models/README.md``
(:mod:`experiments.cards`), and, unless ``--no-readme``, the README's table between the
``<!-- leaderboard:start -->`` and ``<!-- leaderboard:end -->`` markers.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from experiments.board import (
    ANALYTIC,
    ORACLE_LABEL,
    SUITES,
    Board,
    Entry,
    Task,
    TooFewLayoutsError,
    build_board,
    cells,
    entries,
    load_oracle,
    span,
    task_counts,
    task_outcome,
    tasks,
)
from experiments.board_figures import plot_confirmatory, plot_forest, plot_profiles, plot_tasks
from experiments.cards import write_cards
from experiments.cli import add_batch_option, add_models_option, add_workers_option, count
from experiments.grid import run_grid, store_file
from experiments.policies import default_models_dir
from experiments.report import markdown_table, provenance_markdown, write_text_atomic
from experiments.significance import Comparison, compare_paired, mean_success, task_rate
from experiments.stamp import metadata_stamp, png_metadata
from experiments.stats import (
    Aggregate,
    aggregate,
    bootstrap_episodes,
    probability_of_improvement,
)
from experiments.store import Store, StoreError
from experiments.suites import suite
from platoon_env.violations import VIOLATION_CAUSES

__all__ = [
    "ANALYTIC",
    "Board",
    "Entry",
    "Task",
    "build_board",
    "entries",
    "main",
    "tasks",
]

_TOOL = "platoon-leaderboard"
#: The step a violation rate is counted per (the analytic laws' control period) [s].
RATE_STEP = 0.01
#: README markers between which the table is written: a generated block of
#: ``scripts/docs_blocks.py`` (the first table of ``docs/leaderboard.md``, which this writes).
MARKERS = (
    "<!-- begin: python -m experiments.studies.leaderboard ; file docs/leaderboard.md ; "
    "table 1 -->",
    "<!-- end -->",
)


# ----------------------------------------------------------------------------------------------
# Statistics
# ----------------------------------------------------------------------------------------------


#: An IQM is reported only for an entry with at least this many run × task scores: below it
#: the 25 % trimming drops whole tasks (6 tasks × 1 run keeps 3).
IQM_MIN_SCORES = 8


def success_aggregate(board: Board, entry: Entry, task_list: Sequence[Task]) -> Aggregate | None:
    """The mean success rate of ``entry`` over ``task_list`` (every task weighs the same) with
    its 95 % hierarchical-bootstrap interval (:func:`experiments.significance.mean_success`:
    training seeds, then each seed's episodes); None when the entry lacks a task."""
    counts = board.counts(entry.name, task_list)
    if counts.size == 0 or np.any(counts[..., 1] == 0):
        return None
    return mean_success(counts)


def success_iqm(board: Board, entry: Entry, task_list: Sequence[Task]) -> Aggregate | None:
    """The IQM over runs × tasks of the task success rates with rliable's stratified bootstrap,
    only where the entry has at least :data:`IQM_MIN_SCORES` scores (else None)."""
    m = board.success_matrix(entry.name, task_list)
    if m.size < IQM_MIN_SCORES or np.isnan(m).any():
        return None
    if m.shape[0] > 1:
        return aggregate({entry.name: m}, "iqm")[entry.name]
    e = board.episode_matrix(entry.name, task_list)
    return None if np.isnan(e).any() else bootstrap_episodes(e)


def _finite_mean(values: Sequence[float]) -> float:
    v = [x for x in values if x is not None and math.isfinite(x)]
    return float(np.mean(v)) if v else math.nan


def suite_row(
    board: Board, entry: Entry, suite_name: str, condition: str | None = None
) -> dict[str, Any]:
    """The leaderboard's numbers for ``entry`` on ``suite_name``, on the tasks of one
    ``condition`` (``ideal``, ``aruco``) or all of them (None) (module doc)."""
    task_list = [
        t
        for t in board.suite_tasks(suite_name)
        if condition is None or t.condition.label == condition
    ]
    eps = [m for run in board.metrics[entry.name] for t in task_list for m in run.get(t, [])]
    steps = sum(float(m["sim_time"]) for m in eps) / RATE_STEP
    causes = Counter(m["violation"] for m in eps if m["violation"])
    return {
        "policy": entry.name,
        "suite": suite_name,
        "condition": condition or "all",
        "runs": len(entry.runs),
        "episodes": len(eps),
        "success": success_aggregate(board, entry, task_list),
        "iqm": success_iqm(board, entry, task_list),
        "success_mean": float(np.mean([bool(m["success"]) for m in eps])) if eps else math.nan,
        "violations_per_1k": {
            c: 1000.0 * causes.get(c, 0) / steps if steps else math.nan for c in VIOLATION_CAUSES
        },
        "rms_e_d": _finite_mean([m["rms_e_d"] for m in eps]),
        "rms_e_beta": _finite_mean([m["rms_e_beta"] for m in eps]),
        "effort": _finite_mean([m["control_effort"] for m in eps]),
        "refused": [
            t.label for (name, t) in board.refused if name == entry.name and t in task_list
        ],
    }


def improvement(board: Board, entry: Entry, other: Entry) -> Aggregate | None:
    """``P(entry > other)`` on the success rates of every task of the board."""
    x = board.success_matrix(entry.name, board.tasks)
    y = board.success_matrix(other.name, board.tasks)
    if np.isnan(x).any() or np.isnan(y).any():
        return None
    return probability_of_improvement(x, y)


#: The analytic law the goal's aruco comparison is against.
GOAL_REFERENCE = "filtered_ppc"
#: The success rate each training seed needs on each of studies A, B and C under ideal sensing.
GOAL_IDEAL_RATE = 0.95


def goal(board: Board, entry: Entry, found: Sequence[Comparison]) -> dict[str, Any]:
    """Whether ``entry`` reaches the learned side's goal (module doc): every run completes
    each paper study under ideal sensing in at least :data:`GOAL_IDEAL_RATE` of its episodes,
    and under aruco the configuration beats :data:`GOAL_REFERENCE` on at least one paper task
    and loses on none, by the Holm-adjusted comparisons ``found`` (the board's confirmatory
    family, :func:`confirmatory`)."""
    ideal = [t for t in board.suite_tasks("paper") if t.condition.label == "ideal"]
    # (runs, tasks) success rates; a task a run has no episode of (NaN) counts as 0
    matrix = np.nan_to_num(board.success_matrix(entry.name, ideal), nan=0.0)
    per_run = []
    for spec, row in zip(entry.runs, matrix, strict=True):
        rates = {t.scenario: float(r) for t, r in zip(ideal, row, strict=True)}
        ok = bool(rates) and all(r >= GOAL_IDEAL_RATE for r in rates.values())
        per_run.append({"run": spec.name, "ideal_rates": rates, "ideal": ok})
    aruco = {t.label for t in goal_tasks(board)}
    versus = [c for c in found if c.task in aruco and {c.a, c.b} == {entry.name, GOAL_REFERENCE}]
    wins = sorted(c.task for c in versus if c.verdict == entry.name)
    losses = sorted(c.task for c in versus if c.verdict == GOAL_REFERENCE)
    ideal_runs = sum(bool(r["ideal"]) for r in per_run)
    return {
        "policy": entry.name,
        "runs": per_run,
        "ideal_runs": ideal_runs,
        "wins": wins,
        "losses": losses,
        "met": bool(per_run) and ideal_runs == len(per_run) and bool(wins) and not losses,
    }


# ----------------------------------------------------------------------------------------------
# Markdown and figures
# ----------------------------------------------------------------------------------------------


def _f(x: float, digits: int = 3) -> str:
    return "–" if x is None or not math.isfinite(x) else f"{x:.{digits}f}"


def _agg(a: Aggregate | None) -> str:
    return "–" if a is None else f"{a.value:.2f} [{a.low:.2f}, {a.high:.2f}]"


def _rate(x: float) -> str:
    return "<0.001" if 0 < x < 0.0005 else f"{x:.3f}"


def _violations(v: Mapping[str, float]) -> str:
    parts = [f"{c.replace('collision_', 'coll. ')} {_rate(x)}" for c, x in v.items() if x > 0]
    return ", ".join(parts) if parts else "0"


def table_markdown(rows: Sequence[Mapping[str, Any]]) -> str:
    """The main table: a row per policy, suite and condition."""
    lines = [
        "| policy | suite | condition | runs × episodes per run | mean success [95 % CI] | "
        f"IQM (≥ {IQM_MIN_SCORES} scores) | violations / 1,000 steps (10 ms) by cause | "
        "rms e_d [m] | rms e_β [rad] | effort |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        per_run = r["episodes"] // max(r["runs"], 1)
        refused = f" (refused: {', '.join(r['refused'])})" if r["refused"] else ""
        lines.append(
            f"| {r['policy']} | {r['suite']} | {r['condition']} | {r['runs']} × {per_run} | "
            f"{_agg(r['success'])}{refused} | {_agg(r['iqm'])} | "
            f"{_violations(r['violations_per_1k'])} | {_f(r['rms_e_d'])} | "
            f"{_f(r['rms_e_beta'])} | {_f(r['effort'], 2)} |"
        )
    return "\n".join(lines) + "\n"


def task_table_markdown(board: Board, oracle: Mapping[str, tuple[int, int]] | None = None) -> str:
    """Per policy and task: successes/episodes (runs pooled) with the 95 % Wilson interval, a
    floor (⊥: none succeeded) or ceiling (⊤: all did) mark, and the most frequent failure; a
    last row for the privileged oracle's ``(successes, episodes)`` per task label where
    ``oracle`` has them (:func:`experiments.board.load_oracle`; outside every comparison)."""
    rows = [[e.name, *(_task_cell(board, e.name, t) for t in board.tasks)] for e in board.entries]
    if oracle:
        rates = {label: str(task_rate(k, n)) for label, (k, n) in oracle.items()}
        rows.append([f"*{ORACLE_LABEL}*", *(rates.get(t.label, "–") for t in board.tasks)])
    return markdown_table(["policy", *(t.label for t in board.tasks)], rows) + "\n"


def _task_cell(board: Board, entry: str, task: Task) -> str:
    """One cell of :func:`task_table_markdown`."""
    outcome = task_outcome(board, entry, task)
    if outcome is None:
        return "refused" if (entry, task) in board.refused else "–"
    rate = task_rate(*task_counts(board, entry, task))
    worst = outcome[1]
    mark = " ⊥" if rate.floor else " ⊤" if rate.ceiling else ""
    note = f" ({worst.replace('collision_', 'coll. ')})" if worst else ""
    return f"{rate}{mark}{note}"


#: The normalised margins of the graded table (``platoon_env.rollout.episode_metrics``).
GRADED_MARGINS: tuple[str, ...] = ("min_margin_distance", "min_margin_bearing")


def task_graded(board: Board, entry: str, task: Task) -> tuple[float, float] | None:
    """``entry``'s graded outcome on ``task`` (runs pooled): the mean ``path_fraction`` and the
    median over episodes of each one's smallest distance or bearing margin; None without an
    episode that holds them (not run, or rows written before the graded metrics)."""
    eps = [m for run in board.metrics[entry] for m in run.get(task, []) if "path_fraction" in m]
    if not eps:
        return None
    path = _finite_mean([m["path_fraction"] for m in eps])
    margin = [min(float(m[k]) for k in GRADED_MARGINS) for m in eps]
    return path, float(np.median(margin))


def task_graded_markdown(board: Board) -> str:
    """Per policy and task: the mean fraction of the leader's path done before the first
    violation, and the median smallest distance or bearing margin (:func:`task_graded`)."""

    def cell(entry: str, task: Task) -> str:
        graded = task_graded(board, entry, task)
        return "–" if graded is None else f"{_f(graded[0], 2)} / {_f(graded[1], 2)}"

    rows = [[e.name, *(cell(e.name, t) for t in board.tasks)] for e in board.entries]
    return markdown_table(["policy", *(t.label for t in board.tasks)], rows) + "\n"


def paired_outcomes(board: Board, a: str, b: str, task: Task) -> list[tuple[bool, bool]]:
    """The pairs ``(a succeeded, b succeeded)`` of the episodes ``a`` and ``b`` played on
    ``task`` with the same seed (an episode's ``seed``; a board made without seeds: its place
    in its run). A seed that several runs of both entries played pairs run by run; a seed one
    entry played once pairs that episode with each of the other's on it."""

    def by_seed(entry: str) -> dict[int, list[bool]]:
        out: dict[int, list[bool]] = {}
        for run in board.metrics[entry]:
            for i, m in enumerate(run.get(task, [])):
                out.setdefault(int(m.get("seed", i)), []).append(bool(m["success"]))
        return out

    mine, theirs = by_seed(a), by_seed(b)
    pairs: list[tuple[bool, bool]] = []
    for seed in sorted(set(mine) & set(theirs)):
        x, y = mine[seed], theirs[seed]
        if len(x) == 1:
            x = x * len(y)
        elif len(y) == 1:
            y = y * len(x)
        pairs.extend(zip(x, y, strict=False))
    return pairs


def _family(
    board: Board, pairs: Sequence[tuple[str, str]], tasks_: Sequence[Task]
) -> list[Comparison]:
    outcomes = {
        (a, b): {t.label: paired_outcomes(board, a, b, t) for t in tasks_} for a, b in pairs
    }
    return compare_paired(outcomes)


def comparisons(board: Board) -> list[Comparison]:
    """The **exploratory** family: every pair of board entries on every task both ran, paired
    by episode seed (exact McNemar, Newcombe's paired interval), Holm-adjusted together
    (:func:`experiments.significance.compare_paired`)."""
    names = [e.name for e in board.entries]
    pairs = [(a, b) for i, a in enumerate(names) for b in names[i + 1 :]]
    return _family(board, pairs, board.tasks)


def goal_tasks(board: Board) -> list[Task]:
    """The tasks of the goal's comparisons: the paper studies under aruco."""
    return [t for t in board.suite_tasks("paper") if t.condition.label == "aruco"]


def confirmatory(board: Board) -> list[Comparison]:
    """The **confirmatory** family, fixed here before any run: each learned configuration
    against each analytic law of the board on each of the goal's tasks (:func:`goal_tasks`),
    paired by seed and Holm-adjusted on its own (the goal's verdicts read it)."""
    laws = [e.name for e in board.entries if not e.learned]
    learned = [e.name for e in board.entries if e.learned]
    return _family(board, [(m, law) for m in learned for law in laws], goal_tasks(board))


def comparisons_markdown(found: Sequence[Comparison], tasks_: Sequence[Task]) -> str:
    """A row per pair, a column per task: who is significantly better (Holm, family-wise
    5 %), ``n.s.``, or a tie at the floor/ceiling; then the significant differences."""
    labels = [t.label for t in tasks_]
    by_pair: dict[tuple[str, str], dict[str, Comparison]] = {}
    for c in found:
        by_pair.setdefault((c.a, c.b), {})[c.task] = c
    matrix = [
        (f"{a} vs {b}", *(per_task[t].verdict if t in per_task else "–" for t in labels))
        for (a, b), per_task in by_pair.items()
    ]
    lines = [markdown_table(["A vs B", *labels], matrix)]
    sig = [c for c in found if c.significant]
    tested = sum(1 for c in found if not c.tie)
    lines += [
        "",
        f"{tested} tests in the family ({len(found) - tested} ties at a bound, not tested); "
        f"{len(sig)} significant after Holm's correction.",
        "",
    ]
    if sig:
        header = ["task", "A", "B", "success A − B [95 % CI]", "p (McNemar)", "p (Holm)"]
        rows = [
            (
                c.task,
                c.a,
                c.b,
                f"{c.difference.value:+.2f} [{c.difference.low:+.2f}, {c.difference.high:+.2f}]",
                f"{c.p_value:.2g}",
                f"{c.p_holm:.2g}",
            )
            for c in sig
        ]
        lines.append(markdown_table(header, rows))
    return "\n".join(lines) + "\n"


def improvement_markdown(board: Board) -> str:
    """P(learned > PPC) and P(learned > filtered PPC) over every task."""
    by_name = {e.name: e for e in board.entries}
    lines = [
        "| configuration | P(> PPC) [95 % CI] | P(> filtered PPC) [95 % CI] |",
        "|---|---|---|",
    ]
    for e in board.entries:
        if not e.learned:
            continue
        a = improvement(board, e, by_name["ppc"])
        b = improvement(board, e, by_name["filtered_ppc"])
        lines.append(f"| {e.name} | {_agg(a)} | {_agg(b)} |")
    return "\n".join(lines) + "\n"


def goal_markdown(goals: Sequence[Mapping[str, Any]]) -> str:
    header = [
        "configuration",
        f"runs with A, B, C ideal ≥ {GOAL_IDEAL_RATE:.0%} each",
        f"paper tasks won under aruco vs {GOAL_REFERENCE} (Holm)",
        "lost",
        "goal met",
    ]
    rows = [
        (
            g["policy"],
            f"{g['ideal_runs']} of {len(g['runs'])}",
            ", ".join(g["wins"]) or "none",
            ", ".join(g["losses"]) or "none",
            "yes" if g["met"] else "no",
        )
        for g in goals
    ]
    return markdown_table(header, rows) + "\n"


def readme_problem(readme: Path) -> str | None:
    """Why :func:`splice_readme` could not splice ``readme`` (None: it can): checked before
    the board runs, so a wrong ``--readme`` is not found after hours of episodes."""
    try:
        body = readme.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        return f"cannot read it ({exc})"
    start, end = MARKERS
    if start not in body or end not in body.split(start, 1)[1]:
        return f"it has no {start} ... {end} markers"
    if not os.access(readme.parent, os.W_OK):
        return f"its folder {readme.parent} is not writable"
    return None


def splice_readme(readme: Path, text: str) -> None:
    """Replace what lies between the page's markers with ``text``."""
    body = readme.read_text()
    start, end = MARKERS
    if start not in body or end not in body:
        raise ValueError(f"{readme} has no {start} ... {end} markers")
    head, rest = body.split(start, 1)
    _, tail = rest.split(end, 1)
    write_text_atomic(readme, f"{head}{start}\n{text}{end}{tail}")


# ----------------------------------------------------------------------------------------------
# Command line
# ----------------------------------------------------------------------------------------------


def code_versions(store: Store, records: Sequence[Any]) -> list[tuple[str, bool]]:
    """The distinct (commit, uncommitted changes?) of the runs that wrote ``records``."""
    runs = {r["run_id"]: r["stamp"] for r in store.runs({rec.run_id for rec in records})}
    out = {
        (str(st.get("commit", "unknown")), bool(st.get("modified")))
        for st in (runs.get(rec.run_id, {}) for rec in records)
    }
    return sorted(out)


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="platoon-leaderboard",
        description=(__doc__ or "").split("\n\n")[0],
    )
    add_models_option(p, "on the board")
    p.add_argument(
        "--store",
        type=Path,
        default=Path("results/leaderboard"),
        help="the evaluation store (a folder or a .sqlite file)",
    )
    p.add_argument(
        "--paper-seeds",
        type=count(1),
        default=None,
        help="episodes per run and paper task: a configuration's runs split the seeds, an "
        "analytic law plays them all (runs x this; default: the suite's, 20)",
    )
    p.add_argument(
        "--heldout-seeds",
        type=count(1),
        default=None,
        help="layouts per held-out task (default: the suite's, 200)",
    )
    add_workers_option(p)
    add_batch_option(p)
    p.add_argument(
        "--docs", type=Path, default=Path("docs"), help="where the tables go (default: ./docs)"
    )
    p.add_argument(
        "--readme",
        type=Path,
        default=Path("docs/benchmark.md"),
        help="the page whose table (between its leaderboard markers) is replaced "
        "(default: ./docs/benchmark.md); checked before any episode runs",
    )
    p.add_argument("--no-readme", action="store_true", help="leave that page alone")
    p.add_argument(
        "--allow-mixed",
        action="store_true",
        help="publish rows from several commits or an uncommitted tree (the board says so)",
    )
    p.add_argument("--no-cards", action="store_true", help="leave the model cards alone")
    p.add_argument(
        "--oracle",
        type=Path,
        default=None,
        help="the privileged oracle's results to mark beside the entries, outside every "
        "comparison (a feasibility.json of python -m experiments.studies.feasibility; "
        "default: DOCS/data/feasibility.json when it exists)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p.parse_args(argv)


def _seeds_text(task: Task, runs: int) -> str:
    """How many episodes, on which seeds, a suite's tasks have (:func:`episode_seeds`)."""
    n = task.seeds
    if task.partitioned:
        return (
            f"{task.suite}: {n} layouts per task (seeds 0–{n - 1}), each played once by every "
            f"policy: a configuration's {runs} runs share them out ({n // runs}–{-(-n // runs)} "
            "each), an analytic law plays them all"
        )
    if not task.split:
        return f"{task.suite}: {n} episodes per task, seeds 0–{n - 1} for every run"
    return (
        f"{task.suite}: {n} episodes per run and task; a configuration's run k on seeds "
        f"{n}k … {n}k + {n - 1}, an analytic law on all {runs * n} (0–{runs * n - 1})"
    )


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    opened = _open(args)
    if opened is None:
        return 2
    models, store = opened
    board_entries = entries(models)
    board_tasks = tasks(args.paper_seeds, args.heldout_seeds)
    stamp = metadata_stamp(
        _TOOL,
        {
            "policies": {s.name: s.description() for e in board_entries for s in e.runs},
            "tasks": [f"{t.suite}:{t.label}:{t.seeds}" for t in board_tasks],
        },
        argv,
    )
    try:
        grid, refused = cells(board_entries, board_tasks)
    except TooFewLayoutsError as exc:
        print(f"platoon-leaderboard: error: {exc} (--heldout-seeds)", file=sys.stderr)
        return 2
    print(f"{len(board_entries)} policies, {len(board_tasks)} tasks, {len(grid)} episodes")
    with store:
        result = run_grid(
            store,
            grid,
            tool=_TOOL,
            stamp=stamp,
            workers=args.workers,
            batch=args.batch,
            progress=not args.no_progress,
        )
        print(f"{store.path}: {result.ran} episode(s) run, {result.reused} already in the store")
        if result.interrupted:
            print(f"interrupted: finished episodes are in {store.path}; re-run to resume")
            return 130
        records = [result.records[rc.key] for rc in result.cells if rc.key in result.records]
        provenance = provenance_markdown(store, records, result.run_id)
        # the rows' code versions and this run's own: rows from another commit than the one
        # running now are as mixed as rows from two commits
        mixed = sorted(
            {
                *code_versions(store, records),
                (str(stamp.get("commit", "unknown")), bool(stamp.get("modified"))),
            }
        )
    if len(mixed) > 1 or any(dirty for _, dirty in mixed):
        shown = "; ".join(f"{c[:12]}{' + uncommitted changes' if d else ''}" for c, d in mixed)
        if not args.allow_mixed:
            print(
                f"platoon-leaderboard: error: the board's rows come from {len(mixed)} code "
                f"version(s) ({shown}); a published board is made at one clean commit. Commit, "
                "use a fresh --store, or pass --allow-mixed to publish it anyway (it says so).",
                file=sys.stderr,
            )
            return 2
        provenance = f"**Mixed code versions (--allow-mixed)**: {shown}.\n\n" + provenance
    board = build_board(board_entries, board_tasks, result, refused)
    return _publish(args, board, models, stamp, provenance, failed=bool(result.failed))


def _open(args: argparse.Namespace) -> tuple[Path, Store] | None:
    """The models folder and the store, after the checks made before any work (each failure
    printed; None then): the models folder exists, the README can be spliced, and the store is
    one (a file that is not a store, or not ours, is refused untouched)."""
    models = args.models if args.models is not None else default_models_dir()
    if models is None or not models.is_dir():
        print(
            f"platoon-leaderboard: error: no models folder "
            f"({args.models or 'none found in the source checkout'}); pass --models DIR",
            file=sys.stderr,
        )
        return None
    problem = None if args.no_readme else readme_problem(args.readme)
    if problem:
        print(f"platoon-leaderboard: error: --readme {args.readme}: {problem} (or --no-readme)",
              file=sys.stderr)  # fmt: skip
        return None
    try:
        store = Store(store_file(args.store))
    except StoreError as exc:
        print(f"platoon-leaderboard: error: --store {args.store}: {exc}", file=sys.stderr)
        return None
    return models, store


def _publish(
    args: argparse.Namespace,
    board: Board,
    models: Path,
    stamp: Mapping[str, Any],
    provenance: str,
    *,
    failed: bool,
) -> int:
    """Write the board's statistics: ``leaderboard.md`` and its figures, the model cards and
    the README's table (unless told not to); print the tables. The exit code (1 if an episode
    failed)."""
    rows = [
        suite_row(board, e, s, c.label)
        for s in SUITES
        for c in suite(s).conditions
        for e in board.entries
    ]
    found = comparisons(board)
    confirmed = confirmatory(board)
    goals = [goal(board, e, confirmed) for e in board.entries if e.learned]
    oracle_file = args.oracle or args.docs / "data" / "feasibility.json"
    oracle = load_oracle(oracle_file) if args.oracle or oracle_file.is_file() else {}
    improvements = improvement_markdown(board)
    goal_text = goal_markdown(goals)
    figures = args.docs / "figures"
    figures.mkdir(parents=True, exist_ok=True)
    meta = png_metadata(stamp)
    plot_tasks(board, figures / "leaderboard_tasks.png", meta)
    plot_profiles(board, figures / "leaderboard_profiles.png", meta)
    plot_forest(board, figures / "leaderboard_forest.png", meta, oracle)
    plot_confirmatory(confirmed, figures / "leaderboard_confirmatory.png", meta)
    table = table_markdown(rows)
    doc = leaderboard_markdown(
        board,
        provenance,
        table,
        found,
        improvements,
        goal_text,
        confirmed=confirmed,
        oracle=oracle,
    )
    write_text_atomic(args.docs / "leaderboard.md", doc)
    if not args.no_cards:
        write_cards(board, models, figures / "learning_curves.png", meta)
    if not args.no_readme:
        splice_readme(args.readme, table)
    print(table)
    print(improvements)
    print(goal_text)
    print(f"wrote {args.docs / 'leaderboard.md'} and {figures}/leaderboard_*.png")
    return 1 if failed else 0


def leaderboard_markdown(
    board: Board,
    provenance: str,
    table: str,
    found: Sequence[Comparison],
    improvements: str,
    goal_text: str,
    *,
    confirmed: Sequence[Comparison] = (),
    oracle: Mapping[str, tuple[int, int]] | None = None,
) -> str:
    """The text of ``docs/leaderboard.md``: the provenance, the suite table, the per-task
    tables, the comparisons (the confirmatory family ``confirmed`` and the exploratory
    ``found``), the probability of improvement, the profiles and the goal; ``oracle``: the
    privileged oracle's results per task, marked beside the entries and in no comparison."""
    seeds = "; ".join(_seeds_text(board.suite_tasks(s)[0], span(board.entries)) for s in SUITES)
    doc = [
        "# Leaderboard\n",
        "Made by `python -m experiments.studies.leaderboard` (see its module docstring for every "
        "statistic); do not edit by hand.\n",
        provenance,
        f"Tasks: {len(board.tasks)} ({seeds}); learned configurations: their shipped training "
        "seeds are the runs.\n",
        "## Per policy and suite\n",
        table,
        "\nMean success: the mean over the condition's tasks of the task success rates (every "
        "task weighs the same, nothing is trimmed), with a 95 % hierarchical-bootstrap interval: "
        "training seeds resampled, then each seed's task rate drawn from its Jeffreys posterior "
        "(the episode noise; an analytic law is one seed). IQM: rliable's interquartile mean "
        f"over runs × tasks, shown only where an entry has ≥ {IQM_MIN_SCORES} scores (below "
        "that the trimming drops whole tasks). "
        "Violations are counted per 1,000 control steps of 10 ms (per 10 s of driving), since "
        "the models act every 25 ms. rms e_d and e_β: the mean of the episodes' rms errors "
        "(after a 5 s transient, while the predecessor is visible). Effort: the time integral of "
        "u² + ω² per follower.\n",
        "## Per task: successes (runs pooled) [95 % Wilson interval] and the most frequent "
        "violation\n",
        "⊥: no episode succeeded (floor), ⊤: every episode did (ceiling): no interval inside the "
        "data separates two policies there.\n",
        task_table_markdown(board, oracle),
        (
            f"*{ORACLE_LABEL}*: the oracle of docs/feasibility.md, which plans on the true "
            "state; a reference of what is achievable, in no comparison and no goal. `–`: "
            "not run on that task.\n"
            if oracle
            else "The privileged oracle has not been run on these tasks (docs/feasibility.md).\n"
        ),
        "![success per task](figures/leaderboard_tasks.png)\n",
        "![success per task with intervals, the oracle marked](figures/leaderboard_forest.png)\n",
        "## Per task, graded: path done / smallest margin\n",
        "Success is binary; this table shows how far an unsolved task gets. First number: the "
        "mean fraction of the leader's path done before the first violation (1: the whole "
        "path); second: the median over episodes of each episode's smallest normalised "
        "distance or bearing margin (1 at the set point, 0 at a bound, negative beyond it). "
        "Definitions: docs/metrics.md. `–`: rows written before these metrics existed.\n",
        task_graded_markdown(board),
        "## Confirmatory comparisons (the goal's family)\n",
        "Fixed in code before any run (`confirmatory`): each learned configuration against each "
        "analytic law on each paper study under aruco. Each comparison pairs the two entries' "
        "episodes of the same seed (a configuration's training seeds share out the seeds the "
        "law plays all of) and is a two-sided exact McNemar test on the discordant pairs; the "
        "family's p-values are Holm-adjusted on their own (family-wise error 5 %). The "
        "difference interval is Newcombe's for paired proportions. The goal reads this "
        "family.\n",
        comparisons_markdown(confirmed, goal_tasks(board)),
        "![the confirmatory family at a glance](figures/leaderboard_confirmatory.png)\n"
        if confirmed
        else "",
        "## Exploratory comparisons (who beats whom on which task)\n",
        "The family: every pair of policies on every task both ran, paired by seed as above "
        "(exact McNemar, Newcombe's paired interval), Holm-adjusted as one family apart from "
        "the confirmatory one. A pair at the floor or the ceiling on a task is a tie, not a "
        "test. The functions are in experiments/significance.py.\n",
        comparisons_markdown(found, board.tasks),
        f"## Probability of improvement (success rates of all {len(board.tasks)} tasks)\n",
        improvements,
        "## Performance profiles\n",
        "![performance profiles](figures/leaderboard_profiles.png)\n",
        "## The goal\n",
        f"A configuration meets it when every training seed completes each of studies A, B "
        f"and C under ideal sensing in ≥ {GOAL_IDEAL_RATE:.0%} of its episodes, and under the "
        f"aruco profile it beats `{GOAL_REFERENCE}` on at least one of those studies and loses "
        "on none, by the pairwise comparisons above (the configuration's runs together and "
        "the filtered PPC on the same episode seeds, Fisher's exact test, Holm-adjusted over "
        "the whole family).\n",
        goal_text,
    ]
    if board.missing:
        doc.append(f"\n**{board.missing} episode(s) failed or are missing**: re-run to retry.\n")
    return "\n".join(doc)


if __name__ == "__main__":
    sys.exit(main())
