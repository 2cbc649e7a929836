"""Learning curves: what ``platoon-train`` logs per run, and the figure over training seeds.

During training, :class:`LearningCurveCallback` appends one row to ``DIR/progress.csv`` every
``every`` follower transitions, about the **follower episodes that ended since the last row**
(every follower of an env copy ends its episode when the copy's episode ends):

``timesteps``
    follower transitions so far (SB3's ``num_timesteps``).
``wall_time_s``
    seconds since this invocation started (a resumed run restarts it).
``episodes``
    follower episodes that ended in the window (0: the next three columns are empty).
``return_mean``
    their mean undiscounted return of the env's reward (before any Lagrangian penalty).
``success_rate``
    the fraction of the **team** episodes (an env copy's episode, all its followers) that
    ended in the window without a safety violation of any follower (truncated: the leader
    finished its path or the step limit was reached). A violation ends the episode of every
    follower of the copy, so a per-follower rate would count the others as successes.
``cost_mean``
    the followers' mean episode cost, the sum of ``info["cost"]`` (1 at a step with a
    violation): the quantity ``ppo_lagrangian`` holds to its budget.
``lambda``
    the Lagrange multiplier when the row is written (``ppo_lagrangian``; else empty). It is
    updated after each rollout, so a row shows the value the window's last rollout trained
    with, not yet the update from its costs.

A resumed run keeps the rows up to the timesteps it resumes from and drops the later ones (the
checkpoint it continues from predates them).

:func:`read_progress` reads such a file back, :func:`plot_learning_curves` draws return,
success and cost against timesteps for several configurations, each the mean over its seeds
with the band between the lowest and the highest seed, on a common grid of timesteps.
"""

from __future__ import annotations

import csv
import math
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from stable_baselines3.common.callbacks import BaseCallback

__all__ = [
    "PROGRESS_COLUMNS",
    "PROGRESS_FILE",
    "LearningCurveCallback",
    "ProgressLog",
    "curve_on_grid",
    "plot_learning_curves",
    "read_progress",
]

#: The learning-curve file of a run directory.
PROGRESS_FILE = "progress.csv"
#: Its columns, in order.
PROGRESS_COLUMNS = (
    "timesteps",
    "wall_time_s",
    "episodes",
    "return_mean",
    "success_rate",
    "cost_mean",
    "lambda",
)


class ProgressLog:
    """The writer of ``progress.csv`` (:data:`PROGRESS_COLUMNS`), shared by both engines.

    A driver calls :meth:`start` once, :meth:`add` with the follower episodes that ended (in
    any order, as they end), :meth:`due` to ask whether ``every`` timesteps have passed since
    the last row, and :meth:`write` to append a row about the episodes added since that row
    (and forget them). SB3 asks after every vectorised step (:class:`LearningCurveCallback`),
    RLlib after every training iteration (:mod:`training.rllib`).

    Args:
        path: the CSV file (``DIR/progress.csv``).
        every: follower transitions between rows (> 0).
        resume_from: the timesteps a resumed run continues from: rows after it are dropped and
            the others kept; ``None`` (a fresh run) starts the file anew.
    """

    def __init__(self, path: Path, every: int, *, resume_from: int | None = None) -> None:
        if every <= 0:
            raise ValueError(f"every must be > 0, got {every}")
        self.path = Path(path)
        self.every = int(every)
        self.resume_from = resume_from
        self._returns: list[float] = []
        self._costs: list[float] = []
        self._teams: list[bool] = []
        #: The timesteps of the last row (or of :meth:`start`).
        self.last = 0
        self._t0 = 0.0

    def start(self, timesteps: int) -> None:
        """Write the header (and, resuming, the kept rows); count from ``timesteps``."""
        kept: list[dict[str, str]] = []
        if self.resume_from is not None and self.path.exists():
            kept = [r for r in read_rows(self.path) if int(r["timesteps"]) <= self.resume_from]
        with self.path.open("w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=PROGRESS_COLUMNS)
            writer.writeheader()
            writer.writerows(kept)
        self.last = int(timesteps)
        self._t0 = time.perf_counter()

    def add(
        self,
        *,
        returns: Sequence[float] = (),
        costs: Sequence[float] = (),
        teams: Sequence[bool] = (),
    ) -> None:
        """Add ended episodes: follower returns (unpenalised), follower episode costs (one per
        follower episode: the ``episodes`` column counts them) and team successes."""
        self._returns.extend(float(r) for r in returns)
        self._costs.extend(float(c) for c in costs)
        self._teams.extend(bool(t) for t in teams)

    def due(self, timesteps: int) -> bool:
        """Whether ``every`` timesteps have passed since the last row."""
        return int(timesteps) - self.last >= self.every

    def write(self, timesteps: int, multiplier: float | None = None) -> None:
        """Append the row at ``timesteps`` (``multiplier``: the Lagrange multiplier, or None)."""
        self.last = int(timesteps)
        n = len(self._costs)
        costs = np.asarray(self._costs)
        row: dict[str, Any] = {
            "timesteps": int(timesteps),
            "wall_time_s": f"{time.perf_counter() - self._t0:.1f}",
            "episodes": n,
            "return_mean": f"{np.mean(self._returns):.6g}" if self._returns else "",
            "success_rate": f"{np.mean(self._teams):.6g}" if self._teams else "",
            "cost_mean": f"{np.mean(costs):.6g}" if n else "",
            "lambda": "" if multiplier is None else f"{float(multiplier):.6g}",
        }
        with self.path.open("a", newline="") as f:
            csv.DictWriter(f, fieldnames=PROGRESS_COLUMNS).writerow(row)
        self._returns.clear()
        self._costs.clear()
        self._teams.clear()


class LearningCurveCallback(BaseCallback):
    """Append a :data:`PROGRESS_COLUMNS` row to ``path`` every ``every`` timesteps (SB3; the
    rows are :class:`ProgressLog`'s).

    Args:
        path: the CSV file (``DIR/progress.csv``).
        every: follower transitions between rows (> 0).
        resume_from: the timesteps a resumed run continues from: rows after it are dropped and
            the others kept; ``None`` (a fresh run) starts the file anew.
        multiplier: a callable returning the Lagrange multiplier, or ``None``.
    """

    def __init__(
        self,
        path: Path,
        every: int,
        *,
        resume_from: int | None = None,
        multiplier: Any = None,
    ) -> None:
        super().__init__()
        self.log = ProgressLog(path, every, resume_from=resume_from)
        self.path = self.log.path
        self.every = self.log.every
        self.resume_from = resume_from
        self.multiplier = multiplier
        self._episode_cost: NDArray[np.float64] = np.zeros(0)
        self._team_of: NDArray[np.int64] = np.zeros(0, dtype=np.int64)

    def _on_training_start(self) -> None:
        self.log.start(self.num_timesteps)
        self._episode_cost = np.zeros(self.training_env.num_envs)
        self._team_of = _slot_teams(self.training_env)

    def _on_step(self) -> bool:
        dones = np.asarray(self.locals["dones"], dtype=bool)
        infos = self.locals["infos"]
        for k, info in enumerate(infos):
            self._episode_cost[k] += float(info.get("cost", 0.0))
        returns: list[float] = []
        costs: list[float] = []
        for k in np.flatnonzero(dones).tolist():
            episode = infos[k].get("episode")
            if episode is not None:
                returns.append(float(episode["r"]))
            costs.append(float(self._episode_cost[k]))
        teams = [
            bool(np.all(self._episode_cost[self._team_of == team] == 0))
            for team in np.unique(self._team_of[dones]).tolist()
        ]
        self.log.add(returns=returns, costs=costs, teams=teams)
        self._episode_cost[dones] = 0.0
        if self.log.due(self.num_timesteps):
            self._write_row()
        return True

    def _on_training_end(self) -> None:
        if self.num_timesteps > self.log.last:
            self._write_row()

    def _write_row(self) -> None:
        lam = None if self.multiplier is None else float(self.multiplier())
        self.log.write(self.num_timesteps, lam)


def _slot_teams(venv: Any) -> NDArray[np.int64]:
    """The env copy owning each slot of ``venv`` (through its wrappers); a vector env without
    ``env_slots`` counts each slot as a team of one."""
    base = venv
    while not hasattr(base, "env_slots") and hasattr(base, "venv"):
        base = base.venv
    team = np.arange(venv.num_envs, dtype=np.int64)
    if hasattr(base, "env_slots") and hasattr(base, "n_envs"):
        for j in range(base.n_envs):
            slots = base.env_slots(j)
            team[slots.start : slots.stop] = j
    return team


def read_rows(path: Path) -> list[dict[str, str]]:
    """The rows of a progress file as strings; refuses a file with other columns."""
    with Path(path).open(newline="") as f:
        reader = csv.DictReader(f)
        if tuple(reader.fieldnames or ()) != PROGRESS_COLUMNS:
            raise ValueError(
                f"{path}: columns {reader.fieldnames}, expected {list(PROGRESS_COLUMNS)}"
            )
        return list(reader)


def read_progress(path: Path) -> dict[str, NDArray[np.float64]]:
    """A progress file as one float array per column (an empty cell is NaN)."""
    rows = read_rows(path)
    if not rows:
        raise ValueError(f"{path}: no rows (the run logged nothing yet)")
    return {
        c: np.array([float(r[c]) if r[c] != "" else math.nan for r in rows])
        for c in PROGRESS_COLUMNS
    }


def curve_on_grid(
    runs: Sequence[Mapping[str, NDArray[np.float64]]], column: str, points: int = 100
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``column`` of several runs interpolated onto one grid of timesteps.

    The grid spans the timesteps every run reached (from the largest first row to the smallest
    last row). Windows without an ended episode (NaN) are skipped before interpolating. Returns
    ``(grid, values)`` with ``values`` of shape ``(len(runs), points)``.
    """
    if not runs:
        raise ValueError("no runs")
    lo = max(float(r["timesteps"][0]) for r in runs)
    hi = min(float(r["timesteps"][-1]) for r in runs)
    if hi < lo:
        raise ValueError("the runs' timesteps do not overlap")
    grid = np.linspace(lo, hi, points)
    values = np.empty((len(runs), points))
    for i, r in enumerate(runs):
        ok = ~np.isnan(r[column])
        if not ok.any():
            values[i] = math.nan
            continue
        values[i] = np.interp(grid, r["timesteps"][ok], r[column][ok])
    return grid, values


def plot_learning_curves(
    configs: Mapping[str, Sequence[Path]],
    out: Path,
    *,
    smooth: int = 5,
    metadata: Mapping[str, str] | None = None,
) -> Path:
    """Return, success rate and episode cost vs timesteps, one line per configuration.

    Args:
        configs: configuration name → its runs' ``progress.csv`` files (one per seed).
        out: the PNG to write.
        smooth: a moving average over this many logged rows, per run, before averaging.
        metadata: PNG text fields (e.g. :func:`experiments.stamp.png_metadata`).

    Each line is the mean over the configuration's seeds, the band spans the lowest and the
    highest seed; the legend gives the number of seeds.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    columns = (
        ("return_mean", "episode return"),
        ("success_rate", "success rate"),
        ("cost_mean", "episode cost (violations)"),
    )
    fig, axes = plt.subplots(1, len(columns), figsize=(4.2 * len(columns), 3.4))
    for name, files in configs.items():
        runs = [_smoothed(read_progress(p), smooth) for p in files]
        for ax, (column, _) in zip(axes, columns, strict=True):
            grid, values = curve_on_grid(runs, column)
            mean = np.nanmean(values, axis=0)
            (line,) = ax.plot(grid, mean, label=f"{name} ({len(runs)} seeds)")
            ax.fill_between(
                grid,
                np.nanmin(values, axis=0),
                np.nanmax(values, axis=0),
                alpha=0.2,
                color=line.get_color(),
                linewidth=0,
            )
    for ax, (_, label) in zip(axes, columns, strict=True):
        ax.set_xlabel("follower transitions")
        ax.set_title(label)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120, metadata=dict(metadata or {}))
    plt.close(fig)
    return out


def _smoothed(run: dict[str, NDArray[np.float64]], window: int) -> dict[str, NDArray[np.float64]]:
    """A trailing moving average of the value columns over ``window`` rows (NaNs ignored)."""
    if window <= 1:
        return run
    out = dict(run)
    for c in ("return_mean", "success_rate", "cost_mean"):
        v = run[c]
        sm = np.full_like(v, math.nan)
        for i in range(len(v)):
            w = v[max(0, i - window + 1) : i + 1]
            if (~np.isnan(w)).any():
                sm[i] = np.nanmean(w)
        out[c] = sm
    return out
