"""The leaderboard's figures (:mod:`experiments.studies.leaderboard` writes them into
``docs/figures/leaderboard_*.png``), each at most :data:`MAX_FIGURE_HEIGHT` tall:

* :func:`plot_tasks`: a policy × task map of success rates, annotated with the most frequent
  violation;
* :func:`plot_forest`: per task, every entry's success with its Wilson interval, the privileged
  oracle marked;
* :func:`plot_confirmatory`: the confirmatory family as a win/loss grid;
* :func:`plot_profiles`: performance profiles per suite.

Matplotlib is imported only when a figure is drawn (the ``[plot]`` extra).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from experiments.board import (
    ORACLE_LABEL,
    SUITES,
    Board,
    task_counts,
    task_outcome,
)
from experiments.significance import Comparison, wilson
from experiments.stats import performance_profile

__all__ = [
    "MAX_FIGURE_HEIGHT",
    "plot_confirmatory",
    "plot_forest",
    "plot_profiles",
    "plot_tasks",
]


def _pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend, imported only when a figure is drawn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _annotated_grid(
    values: np.ndarray,
    text: Sequence[Sequence[str]],
    rows: Sequence[str],
    columns: Sequence[str],
    size: tuple[float, float],
    vmin: float,
) -> tuple[Any, Any, Any]:
    """A rows × columns colour grid of ``values`` (red to green over ``[vmin, 1]``, NaN blank)
    with ``text[i][j]`` written in each cell; returns the figure, its axes and the image."""
    fig, ax = _pyplot().subplots(figsize=size)
    im = ax.imshow(values, vmin=vmin, vmax=1, cmap="RdYlGn", aspect="auto")
    for i, row in enumerate(text):
        for j, note in enumerate(row):
            ax.text(j, i, note, ha="center", va="center", fontsize=7)
    ax.set_xticks(range(len(columns)), columns, rotation=40, ha="right", fontsize=8)
    ax.set_yticks(range(len(rows)), rows, fontsize=8)
    return fig, ax, im


def _save(fig: Any, out: Path, metadata: Mapping[str, str]) -> Path:
    fig.tight_layout()
    fig.savefig(out, dpi=120, metadata=dict(metadata))
    _pyplot().close(fig)
    return out


def plot_tasks(board: Board, out: Path, metadata: Mapping[str, str]) -> Path:
    """A policy × task map of success rates (mean over runs), each cell annotated with its rate
    and its most frequent violation cause."""
    rates = np.full((len(board.entries), len(board.tasks)), math.nan)
    notes = [["" for _ in board.tasks] for _ in board.entries]
    abbrev = {
        "collision_robot": "robot",
        "collision_obstacle": "obst.",
        "occluded": "occl.",
        "out_of_range": "range",
        "out_of_fov": "fov",
    }
    for i, e in enumerate(board.entries):
        for j, t in enumerate(board.tasks):
            outcome = task_outcome(board, e.name, t)
            if outcome is not None:
                rates[i, j], worst = outcome
                notes[i][j] = f"{rates[i, j]:.2f}" + (f"\n{abbrev[worst]}" if worst else "")
            elif (e.name, t) in board.refused:
                notes[i][j] = "refused"
    fig, ax, im = _annotated_grid(
        rates,
        notes,
        [e.name for e in board.entries],
        [t.label for t in board.tasks],
        size=(1.1 * len(board.tasks) + 2.5, 0.55 * len(board.entries) + 1.6),
        vmin=0,
    )
    fig.colorbar(im, ax=ax, label="success rate (mean over runs)")
    ax.set_title("Success per task, and the most frequent violation")
    return _save(fig, out, metadata)


#: The tallest figure the board draws [inches] (at its 120 dpi: 1,080 pixels, one screen).
MAX_FIGURE_HEIGHT = 9.0


def plot_forest(
    board: Board,
    out: Path,
    metadata: Mapping[str, str],
    oracle: Mapping[str, tuple[int, int]] | None = None,
) -> Path:
    """Per task a panel of every entry's success (runs pooled) with its 95 % Wilson interval,
    the privileged oracle marked (a red star) where ``oracle`` has the task; panels four to a
    row, the figure at most :data:`MAX_FIGURE_HEIGHT` tall."""
    plt = _pyplot()
    names = [e.name for e in board.entries]
    cols = min(4, max(1, len(board.tasks)))
    rows = -(-len(board.tasks) // cols)
    height = min(MAX_FIGURE_HEIGHT, rows * (0.13 * len(names) + 0.9) + 0.6)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, height), sharex=True, squeeze=False)
    for ax, t in zip(axes.flat, board.tasks, strict=False):
        for i, name in enumerate(names):
            k, n = task_counts(board, name, t)
            if n == 0:
                continue
            lo, hi = wilson(k, n)
            ax.plot([lo, hi], [i, i], color="tab:blue", lw=1.2)
            ax.plot(k / n, i, "o", color="tab:blue", ms=3.5)
        if oracle and t.label in oracle:
            k, n = oracle[t.label]
            lo, hi = wilson(k, n)
            ax.plot([lo, hi], [-1, -1], color="tab:red", lw=1.2)
            ax.plot(k / n, -1, "*", color="tab:red", ms=8, label=ORACLE_LABEL)
        ax.set_title(t.label, fontsize=8)
        ax.set_yticks(range(-1, len(names)), [ORACLE_LABEL, *names], fontsize=6)
        ax.set_ylim(len(names) - 0.5, -1.5)
        ax.set_xlim(-0.02, 1.02)
        ax.grid(axis="x", alpha=0.3)
        ax.tick_params(axis="x", labelsize=7)
    for ax in list(axes.flat)[len(board.tasks) :]:
        ax.set_visible(False)
    fig.supxlabel("success rate, 95 % Wilson interval (runs pooled)", fontsize=8)
    return _save(fig, out, metadata)


def plot_confirmatory(
    confirmed: Sequence[Comparison], out: Path, metadata: Mapping[str, str]
) -> Path | None:
    """The confirmatory family as a compact grid: a row per learned configuration, a column per
    law and task, each cell a win (green), a loss (red), n.s. or a tie at a bound (grey); None
    for an empty family."""
    if not confirmed:
        return None
    rows = list(dict.fromkeys(c.a for c in confirmed))
    columns = list(dict.fromkeys(f"{c.b}\n{c.task}" for c in confirmed))
    values = np.full((len(rows), len(columns)), math.nan)
    text = [["" for _ in columns] for _ in rows]
    for c in confirmed:
        i, j = rows.index(c.a), columns.index(f"{c.b}\n{c.task}")
        verdict = c.verdict
        values[i, j] = 1.0 if verdict == c.a else 0.0 if verdict == c.b else 0.5
        text[i][j] = "win" if verdict == c.a else "loss" if verdict == c.b else verdict
    size = (0.9 * len(columns) + 2.5, min(MAX_FIGURE_HEIGHT, 0.35 * len(rows) + 1.8))
    fig, ax, _ = _annotated_grid(values, text, rows, columns, size, vmin=0)
    ax.set_title("Confirmatory family: each configuration against each law (Holm)", fontsize=9)
    return _save(fig, out, metadata)


def plot_profiles(board: Board, out: Path, metadata: Mapping[str, str]) -> Path:
    """Performance profiles per suite: the fraction of run × task success rates > τ."""
    taus = np.linspace(0, 1, 101)
    fig, axes = _pyplot().subplots(1, len(SUITES), figsize=(5 * len(SUITES), 3.6), sharey=True)
    for ax, name in zip(np.atleast_1d(axes), SUITES, strict=True):
        task_list = board.suite_tasks(name)
        data = {}
        for e in board.entries:
            m = board.success_matrix(e.name, task_list)
            if not np.isnan(m).any():
                data[e.name] = m
        if data:
            for k, v in performance_profile(data, taus.tolist()).items():
                ax.plot(taus, v, label=k)
        ax.set_title(f"{name} suite")
        ax.set_xlabel("success-rate threshold τ")
        ax.grid(alpha=0.3)
    np.atleast_1d(axes)[0].set_ylabel("fraction of runs × tasks > τ")
    np.atleast_1d(axes)[0].legend(fontsize=7)
    return _save(fig, out, metadata)
