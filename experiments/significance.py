"""Success-rate statistics a reviewer can sign: per-task intervals, a stratified aggregate, a
hierarchical bootstrap over training seeds, and pairwise tests with Holm's correction.

Every benchmark task here is all-or-nothing per episode (an episode succeeds or it does not),
so a policy's result on a task is a binomial count ``k`` of ``n``. What this module reports:

* **Per task** (:func:`task_rate`): the success rate ``k / n`` with its 95 % **Wilson** score
  interval (``scipy.stats.binomtest(k, n).proportion_ci(method="wilson")``). Unlike a bootstrap
  over the episodes, it has a non-zero width at 0/20 and 20/20. A rate of 0 or 1 is flagged as
  a floor or a ceiling.
* **The headline aggregate** (:func:`mean_success`): the mean success rate over tasks (every
  task weighs the same; nothing is trimmed) with a 95 % interval from a **hierarchical
  bootstrap**: the training seeds are resampled with replacement (level 1), then each chosen
  seed's success rate on each task is drawn from its Jeffreys posterior
  ``Beta(k + 1/2, n - k + 1/2)`` (level 2: the episode noise of that seed and task; unlike
  resampling the episodes it does not collapse to a point at 0/n and n/n). A deterministic
  analytic law is one "seed": level 1 is then a no-op. The tasks are strata: each replicate
  keeps every task.
* **Pairwise comparisons** (:func:`compare`): on each task, the difference of two success
  rates (A − B) with Newcombe's hybrid score interval (method 10 of Newcombe, 1998, built from
  the two Wilson intervals) and a two-sided **Fisher exact test** on the 2×2 table of
  episodes (seeds pooled); the p-values of the whole stated family of comparisons are adjusted
  by **Holm's** step-down method (:func:`holm`), which controls the family-wise error rate.
  A comparison in which both are at the floor (0/n) or both at the ceiling (n/n) is a *tie*,
  flagged as such (its p-value is 1: there is nothing to test), never silently counted as
  half a win.
* **Paired comparisons** (:func:`compare_paired`), for two policies that played the same
  episode seeds (the board's design: a configuration's training seeds share out the seeds an
  analytic law plays all of): each seed is a pair of outcomes; the test is the two-sided
  **exact McNemar** test (:func:`mcnemar_exact`: the binomial test of the discordant pairs,
  ``scipy.stats.binomtest(b, b + c, 1/2)``), the interval Newcombe's for paired proportions
  (:func:`newcombe_paired_difference`, method 10 of Newcombe, 1998b: the two Wilson intervals
  combined with the pairs' correlation ``phi``); it contains its point estimate by
  construction. Seeds from disjoint blocks (a configuration's runs) pool into one table of
  pairs: each pair compares the two policies on one seed, so blocks of different difficulty
  stratify themselves. Ties and Holm's correction as for :func:`compare`; the family is the
  returned list, so a caller that states two families (the board's confirmatory and
  exploratory) calls it once per family.

Bootstraps are seeded, so tables regenerate identically.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.stats import binomtest, fisher_exact

from experiments.stats import Aggregate

__all__ = [
    "ALPHA",
    "Comparison",
    "Interval",
    "TaskRate",
    "compare",
    "compare_paired",
    "holm",
    "mcnemar_exact",
    "mean_success",
    "newcombe_difference",
    "newcombe_paired_difference",
    "task_rate",
    "wilson",
]

#: The family-wise error rate of the pairwise tests, and 1 - the intervals' coverage.
ALPHA = 0.05


#: A point estimate and its 95 % interval (the statistics module's record).
Interval = Aggregate


def _count(k: int, n: int) -> tuple[int, int]:
    if isinstance(k, bool) or isinstance(n, bool) or int(k) != k or int(n) != n:
        raise ValueError(f"success counts must be whole numbers, got {k!r} of {n!r}")
    if n < 1 or not 0 <= k <= n:
        raise ValueError(f"need 0 <= successes <= episodes and episodes >= 1, got {k} of {n}")
    return int(k), int(n)


def wilson(k: int, n: int, confidence: float = 1 - ALPHA) -> tuple[float, float]:
    """The Wilson score interval (95 % by default) of ``k`` successes in ``n`` episodes, the
    project's one implementation (``scipy.stats.binomtest``); ``(nan, nan)`` for ``n = 0`` (a
    table cell with no episodes), a ``ValueError`` unless ``0 <= k <= n`` are whole numbers."""
    if n == 0:
        return (math.nan, math.nan)
    k, n = _count(k, n)
    ci = binomtest(k, n).proportion_ci(confidence_level=confidence, method="wilson")
    return float(ci.low), float(ci.high)


@dataclass(frozen=True)
class TaskRate:
    """One policy on one task: ``successes`` of ``episodes``, the rate and its Wilson interval;
    ``floor``/``ceiling``: the rate is 0 / 1 (no interval inside the data can separate two
    policies there)."""

    successes: int
    episodes: int
    rate: float
    low: float
    high: float

    @property
    def floor(self) -> bool:
        return self.successes == 0

    @property
    def ceiling(self) -> bool:
        return self.successes == self.episodes

    def __str__(self) -> str:
        return f"{self.successes}/{self.episodes} [{self.low:.2f}, {self.high:.2f}]"


def task_rate(k: int, n: int) -> TaskRate:
    """``k`` of ``n`` episodes succeeded: the rate with its 95 % Wilson interval."""
    k, n = _count(k, n)
    low, high = wilson(k, n)
    return TaskRate(k, n, k / n, low, high)


def _counts(counts: ArrayLike) -> NDArray[np.int64]:
    """``(seeds, tasks, 2)`` integer array of (successes, episodes)."""
    a = np.asarray(counts)
    if a.ndim == 2 and a.shape[-1] == 2:
        a = a[None]  # one seed
    if a.ndim != 3 or a.shape[-1] != 2 or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(
            f"counts must be (seeds, tasks, 2) = (successes, episodes), got shape {a.shape}"
        )
    if not np.all(np.isfinite(a)) or np.any(a != np.round(a)):
        raise ValueError("counts must be whole numbers")
    a = a.astype(np.int64)
    k, n = a[..., 0], a[..., 1]
    if np.any(n < 1) or np.any(k < 0) or np.any(k > n):
        raise ValueError("every (seed, task) needs 0 <= successes <= episodes and episodes >= 1")
    return a


def mean_success(counts: ArrayLike, *, reps: int = 4000, seed: int = 0) -> Interval:
    """The mean success rate over tasks and its 95 % hierarchical-bootstrap interval (module
    doc). ``counts`` is ``(seeds, tasks, 2)``: per training seed and task, (successes,
    episodes); a ``(tasks, 2)`` array is one seed (an analytic law)."""
    if reps < 100:
        raise ValueError(f"reps must be >= 100, got {reps}")
    a = _counts(counts)
    k = a[..., 0].astype(np.float64)
    n = a[..., 1].astype(np.float64)
    point = float(np.mean(k / n))  # tasks weigh the same; seeds weigh the same
    rng = np.random.default_rng(seed)
    seeds = a.shape[0]
    picks = rng.integers(0, seeds, size=(reps, seeds)) if seeds > 1 else np.zeros((reps, 1), int)
    rates = rng.beta(k[picks] + 0.5, n[picks] - k[picks] + 0.5)  # (reps, seeds, tasks)
    means = rates.mean(axis=(1, 2))
    low, high = np.quantile(means, [ALPHA / 2, 1 - ALPHA / 2])
    # The Jeffreys posterior puts no mass at exactly 0 or 1, so an entry at the floor or the
    # ceiling everywhere would get an interval that excludes its own rate: the bounds are
    # extended to the point (the usual boundary modification of the Jeffreys interval).
    return Interval(point, min(float(low), point), max(float(high), point))


def newcombe_difference(k1: int, n1: int, k2: int, n2: int) -> Interval:
    """``k1/n1 - k2/n2`` with Newcombe's hybrid score interval (from the two Wilson
    intervals; it stays inside [-1, 1] and has a width at 0/n and n/n)."""
    p1, p2 = _count(k1, n1)[0] / n1, _count(k2, n2)[0] / n2
    l1, u1 = wilson(k1, n1)
    l2, u2 = wilson(k2, n2)
    d = p1 - p2
    low = d - math.sqrt((p1 - l1) ** 2 + (u2 - p2) ** 2)
    high = d + math.sqrt((u1 - p1) ** 2 + (p2 - l2) ** 2)
    return Interval(d, max(-1.0, low), min(1.0, high))


def newcombe_paired_difference(both: int, only_a: int, only_b: int, neither: int) -> Interval:
    """``p_A - p_B`` of paired outcomes (``both`` pairs where both succeed, ``only_a`` where
    only A does, ``only_b`` where only B does, ``neither``) with Newcombe's interval for paired
    proportions (1998b, method 10): the Wilson intervals of ``p_A`` and ``p_B`` combined with
    the pairs' correlation ``phi`` (0 where a margin is empty, so that it reduces to
    :func:`newcombe_difference`'s hybrid interval for ``n`` pairs)."""
    counts = (both, only_a, only_b, neither)
    if any(isinstance(x, bool) or int(x) != x or x < 0 for x in counts):
        raise ValueError(f"pair counts must be integers >= 0, got {counts}")
    n = both + only_a + only_b + neither
    if n == 0:
        raise ValueError("no pairs")
    k1, k2 = both + only_a, both + only_b
    p1, p2 = k1 / n, k2 / n
    l1, u1 = wilson(k1, n)
    l2, u2 = wilson(k2, n)
    margins = (both + only_a) * (only_b + neither) * (both + only_b) * (only_a + neither)
    phi = (both * neither - only_a * only_b) / math.sqrt(margins) if margins else 0.0
    d = p1 - p2
    low = d - math.sqrt(max(0.0, (p1 - l1) ** 2 - 2 * phi * (p1 - l1) * (u2 - p2) + (u2 - p2) ** 2))
    high = d + math.sqrt(
        max(0.0, (u1 - p1) ** 2 - 2 * phi * (u1 - p1) * (p2 - l2) + (p2 - l2) ** 2)
    )
    return Interval(d, max(-1.0, low), min(1.0, high))


def mcnemar_exact(b: int, c: int) -> float:
    """The two-sided exact McNemar p-value of ``b`` and ``c`` discordant pairs (one policy
    succeeds and the other fails, and the reverse): twice the binomial tail of ``min(b, c)``
    under ``Bin(b + c, 1/2)``, capped at 1 (1 with no discordant pair); equal to
    ``scipy.stats.binomtest(b, b + c, 0.5).pvalue``."""
    if b < 0 or c < 0:
        raise ValueError("counts must be non-negative")
    n = b + c
    if n == 0:
        return 1.0
    k = min(b, c)
    tail = sum(math.comb(n, i) for i in range(k + 1)) / 2.0**n
    return min(1.0, 2.0 * tail)


def holm(p_values: Sequence[float]) -> list[float]:
    """Holm's step-down adjusted p-values (same order as given): the ``i``-th smallest is
    multiplied by ``m - i`` (``i`` from 0), made monotone, capped at 1."""
    p = np.asarray(p_values, dtype=np.float64)
    if p.ndim != 1 or np.any(~np.isfinite(p)) or np.any((p < 0) | (p > 1)):
        raise ValueError("p-values must be a flat sequence of numbers in [0, 1]")
    m = p.size
    order = np.argsort(p, kind="stable")
    adjusted = np.empty(m)
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, float(p[i]) * (m - rank)))
        adjusted[i] = running
    return adjusted.tolist()


@dataclass(frozen=True)
class Comparison:
    """A against B on one task: the success difference with its interval, Fisher's exact
    p-value, the Holm-adjusted p-value over the family, and the verdict."""

    task: str
    a: str
    b: str
    difference: Interval
    p_value: float
    p_holm: float
    tie: str  # "floor", "ceiling" or "" (a tie at a bound is flagged, not tested)

    @property
    def significant(self) -> bool:
        """Whether A and B differ at family-wise level :data:`ALPHA` (Holm)."""
        return not self.tie and self.p_holm < ALPHA

    @property
    def verdict(self) -> str:
        """``"A"`` or ``"B"`` (who is significantly better), ``"tie at floor"``/``"tie at
        ceiling"``, or ``"n.s."``."""
        if self.tie:
            return f"tie at {self.tie}"
        if not self.significant:
            return "n.s."
        return self.a if self.difference.value > 0 else self.b


#: One comparison before the family's correction: task, A, B, difference, p-value, tie.
_Raw = tuple[str, str, str, Interval, float, str]


def _holm_family(raw: Sequence[_Raw]) -> list[Comparison]:
    """The comparisons ``raw`` as one family: the p-values of its tests (the ties are not
    tests) Holm-adjusted together."""
    tested = [i for i, r in enumerate(raw) if not r[5]]
    adjusted = holm([raw[i][4] for i in tested]) if tested else []
    p_holm = [1.0] * len(raw)
    for i, q in zip(tested, adjusted, strict=True):
        p_holm[i] = q
    return [
        Comparison(t, a, b, d, p, q, tie)
        for (t, a, b, d, p, tie), q in zip(raw, p_holm, strict=True)
    ]


def compare(
    rates: Mapping[str, Mapping[str, tuple[int, int]]], pairs: Sequence[tuple[str, str]]
) -> list[Comparison]:
    """Every pair of ``pairs`` on every task both have: ``rates[policy][task] = (successes,
    episodes)`` (a learned configuration's seeds pooled). The family adjusted by Holm is the
    whole returned list (the ties excepted: they are not tests)."""
    raw: list[_Raw] = []
    for a, b in pairs:
        if a not in rates or b not in rates:
            raise ValueError(f"unknown policy in pair {(a, b)}; known: {sorted(rates)}")
        for task in rates[a]:
            if task not in rates[b]:
                continue
            (k1, n1), (k2, n2) = rates[a][task], rates[b][task]
            diff = newcombe_difference(k1, n1, k2, n2)
            tie = "floor" if k1 == 0 and k2 == 0 else "ceiling" if k1 == n1 and k2 == n2 else ""
            p = 1.0 if tie else float(fisher_exact([[k1, n1 - k1], [k2, n2 - k2]]).pvalue)
            raw.append((task, a, b, diff, p, tie))
    return _holm_family(raw)


def compare_paired(
    outcomes: Mapping[tuple[str, str], Mapping[str, Sequence[tuple[bool, bool]]]],
) -> list[Comparison]:
    """The paired family: ``outcomes[(a, b)][task]`` = the pairs ``(a succeeded, b succeeded)``
    of the episodes both played with the same seed. Each is an exact McNemar test with
    Newcombe's paired interval (module doc); a pair where both are at the floor or both at the
    ceiling is a tie, not a test; the p-values of every test returned are Holm-adjusted
    together."""
    raw: list[_Raw] = []
    for (a, b), per_task in outcomes.items():
        for task, pairs in per_task.items():
            if not pairs:
                continue
            both = sum(1 for x, y in pairs if x and y)
            only_a = sum(1 for x, y in pairs if x and not y)
            only_b = sum(1 for x, y in pairs if y and not x)
            neither = len(pairs) - both - only_a - only_b
            diff = newcombe_paired_difference(both, only_a, only_b, neither)
            tie = (
                "floor" if both + only_a + only_b == 0 else "ceiling" if both == len(pairs) else ""
            )
            p = 1.0 if tie else mcnemar_exact(only_a, only_b)
            raw.append((task, a, b, diff, p, tie))
    return _holm_family(raw)
