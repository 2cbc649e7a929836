"""Aggregate statistics over training seeds × tasks, as the RL field reports them (rliable).

*Deep Reinforcement Learning at the Edge of the Statistical Precipice* (Agarwal et al., 2021)
recommends, for a few runs per method:

* the **interquartile mean** (IQM, the mean of the middle 50 % of all run × task scores) rather
  than the mean or median;
* **stratified bootstrap** confidence intervals: runs resampled with replacement within each
  task;
* the **probability of improvement** ``P(X > Y)``: the chance that a run of X beats a run of Y
  on a task drawn at random (a Mann-Whitney U statistic, ties count half);
* **performance profiles**: the fraction of run × task scores above each threshold ``tau``.

This module wraps the ``rliable`` library (the ``[stats]`` extra: ``rliable>=1.2,<1.3`` and
``pandas<3``, since rliable 1.2 does not import with pandas 3). Scores are arrays of shape
``(runs, tasks)``: one row per training seed, one column per task (a scenario, a held-out tier,
...). Bootstrap intervals are seeded, so that a table regenerates identically.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "Aggregate",
    "aggregate",
    "bootstrap_episodes",
    "iqm",
    "performance_profile",
    "probability_of_improvement",
]


def _rliable() -> tuple[Any, Any]:
    try:
        from rliable import library, metrics
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise ImportError(
            "experiments.stats needs rliable: pip install -e '.[stats]' "
            f"(rliable 1.2 with pandas<3); import failed: {exc}"
        ) from exc
    return library, metrics


@contextmanager
def _seeded(seed: int) -> Iterator[np.random.RandomState]:
    """A seeded stream for rliable's bootstrap, which draws its resampling indices from numpy's
    *global* generator (``np.random.choice``) whatever ``random_state`` it is given: the global
    state is seeded for the call and restored after it."""
    saved = np.random.get_state()  # noqa: NPY002 (rliable draws from the legacy global)
    np.random.seed(seed)  # noqa: NPY002
    try:
        yield np.random.RandomState(seed)
    finally:
        np.random.set_state(saved)  # noqa: NPY002


def _scores(x: ArrayLike, name: str = "scores") -> NDArray[np.float64]:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim != 2 or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(f"{name} must be a (runs, tasks) array, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite (a NaN would silently change the statistic)")
    return a


def iqm(scores: ArrayLike) -> float:
    """The interquartile mean of all run × task scores (the 25 % trimmed mean)."""
    _, metrics = _rliable()
    return float(metrics.aggregate_iqm(_scores(scores)))


@dataclass(frozen=True)
class Aggregate:
    """A point estimate and its 95 % stratified-bootstrap interval."""

    value: float
    low: float
    high: float

    def __str__(self) -> str:
        return f"{self.value:.3f} [{self.low:.3f}, {self.high:.3f}]"


def aggregate(
    score_dict: Mapping[str, ArrayLike],
    statistic: str = "iqm",
    *,
    reps: int = 2000,
    seed: int = 0,
) -> dict[str, Aggregate]:
    """Per method, ``statistic`` (``iqm``, ``mean``, ``median`` or ``optimality_gap``) over its
    ``(runs, tasks)`` scores, with a 95 % stratified-bootstrap percentile interval."""
    library, metrics = _rliable()
    funcs = {
        "iqm": metrics.aggregate_iqm,
        "mean": metrics.aggregate_mean,
        "median": metrics.aggregate_median,
        "optimality_gap": metrics.aggregate_optimality_gap,
    }
    if statistic not in funcs:
        raise ValueError(f"statistic must be one of {sorted(funcs)}, got {statistic!r}")
    if reps < 100:
        raise ValueError(f"reps must be >= 100, got {reps}")
    fn = funcs[statistic]
    out = {}
    for k, v in score_dict.items():
        # one bootstrap per method with its own seeded stream: a method's interval does not
        # depend on which other methods are in the table
        with _seeded(seed) as state:
            points, intervals = library.get_interval_estimates(
                {k: _scores(v, k)}, lambda x: np.array([fn(x)]), reps=reps, random_state=state
            )
        out[k] = Aggregate(
            float(points[k][0]), float(intervals[k][0, 0]), float(intervals[k][1, 0])
        )
    return out


def bootstrap_episodes(episodes: ArrayLike, *, reps: int = 2000, seed: int = 0) -> Aggregate:
    """The IQM over tasks of the task means of one run's ``(episodes, tasks)`` scores, with a
    95 % interval from resampling the episodes within each task (rliable's stratified
    bootstrap with the episodes as its "runs").

    For a deterministic policy (one run), the episodes are the only source of variation: this
    is its counterpart of :func:`aggregate` over training seeds.
    """
    library, metrics = _rliable()
    e = _scores(episodes, "episodes")

    def statistic(x: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.array([metrics.aggregate_iqm(x.mean(axis=0, keepdims=True))])

    with _seeded(seed) as state:
        points, intervals = library.get_interval_estimates(
            {"run": e}, statistic, reps=reps, random_state=state
        )
    return Aggregate(
        float(points["run"][0]), float(intervals["run"][0, 0]), float(intervals["run"][1, 0])
    )


def probability_of_improvement(
    x: ArrayLike, y: ArrayLike, *, reps: int = 2000, seed: int = 0
) -> Aggregate:
    """``P(X > Y)`` averaged over tasks (ties count half), with its 95 % stratified-bootstrap
    interval. ``x`` and ``y`` are ``(runs, tasks)`` arrays with the same tasks (columns); the
    numbers of runs may differ."""
    library, metrics = _rliable()
    sx, sy = _scores(x, "x"), _scores(y, "y")
    if sx.shape[1] != sy.shape[1]:
        raise ValueError(f"x and y need the same tasks, got {sx.shape[1]} and {sy.shape[1]}")
    with _seeded(seed) as state:
        points, intervals = library.get_interval_estimates(
            {"pair": [sx, sy]},
            lambda a, b: np.array([metrics.probability_of_improvement(a, b)]),
            reps=reps,
            random_state=state,
        )
    return Aggregate(
        float(points["pair"][0]), float(intervals["pair"][0, 0]), float(intervals["pair"][1, 0])
    )


def performance_profile(
    score_dict: Mapping[str, ArrayLike], taus: Sequence[float]
) -> dict[str, NDArray[np.float64]]:
    """Per method, the fraction of its run × task scores ``> tau`` for each ``tau`` (the score
    distribution of rliable's performance profiles)."""
    library, _ = _rliable()
    data = {k: _scores(v, k) for k, v in score_dict.items()}
    tau = np.asarray(list(taus), dtype=np.float64)
    with _seeded(0):  # the point estimates do not depend on it; the unused intervals do
        points, _ = library.create_performance_profile(data, tau, reps=100)
    return {k: np.asarray(points[k], dtype=np.float64) for k in data}
