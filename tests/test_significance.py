"""experiments.significance: Wilson intervals, the hierarchical bootstrap, Newcombe's
difference, Fisher's test with Holm's correction and the flagged ties; the paired family
(exact McNemar, Newcombe's paired interval)."""

from __future__ import annotations

import numpy as np
import pytest

from experiments.significance import (
    compare,
    compare_paired,
    holm,
    mcnemar_exact,
    mean_success,
    newcombe_difference,
    newcombe_paired_difference,
    task_rate,
    wilson,
)


def test_wilson_has_width_at_the_bounds() -> None:
    low, high = wilson(0, 20)
    assert low == 0.0 and 0.15 < high < 0.17  # 0.1611 (Wilson, 95 %)
    low, high = wilson(20, 20)
    assert 0.83 < low < 0.85 and high == pytest.approx(1.0)
    r = task_rate(7, 20)
    assert r.rate == 0.35 and r.low < 0.35 < r.high and not r.floor and not r.ceiling
    assert task_rate(0, 5).floor and task_rate(5, 5).ceiling


@pytest.mark.parametrize("k, n", [(-1, 5), (6, 5), (1, 0), (1.5, 4)])
def test_bad_counts_raise(k: float, n: int) -> None:
    with pytest.raises(ValueError):
        task_rate(k, n)  # type: ignore[arg-type]


def test_mean_success_keeps_every_task() -> None:
    """The headline is the plain mean over tasks (nothing trimmed), and its interval is not a
    point when every task is at 0/20 or 20/20."""
    counts = np.array([[20, 20], [0, 20], [6, 20]])  # one analytic law, three tasks
    m = mean_success(counts)
    assert m.value == pytest.approx((1 + 0 + 0.3) / 3)
    assert m.low < m.value < m.high
    top = mean_success(np.array([[20, 20], [20, 20]]))
    assert top.value == top.high == 1.0 and top.low < 0.95  # the point lies in its interval
    bounds = mean_success(np.array([[20, 20], [0, 20]]))
    assert bounds.value == 0.5 and bounds.high - bounds.low > 0.02


def test_mean_success_seeds_widen_the_interval() -> None:
    """Seeds that disagree widen the hierarchical interval beyond the episode noise."""
    agree = np.array([[[10, 20], [10, 20]]] * 5)
    disagree = np.array([[[k, 20], [k, 20]] for k in (0, 5, 10, 15, 20)])
    a, d = mean_success(agree), mean_success(disagree)
    assert a.value == d.value == 0.5
    assert d.high - d.low > (a.high - a.low) * 1.5


def test_mean_success_is_seeded_and_checks_shape() -> None:
    counts = np.array([[[3, 20], [9, 20]], [[5, 20], [11, 20]]])
    assert mean_success(counts, seed=3) == mean_success(counts, seed=3)
    with pytest.raises(ValueError):
        mean_success(np.zeros((2, 3, 3)))
    with pytest.raises(ValueError):
        mean_success(np.array([[3, 0]]))


def test_newcombe_difference() -> None:
    d = newcombe_difference(20, 20, 0, 20)
    assert d.value == 1.0 and d.low > 0.6 and d.high == 1.0
    d = newcombe_difference(10, 20, 10, 20)
    assert d.value == 0.0 and d.low < 0 < d.high


def test_holm() -> None:
    assert holm([0.01, 0.04, 0.03]) == pytest.approx([0.03, 0.06, 0.06])
    assert holm([0.5]) == [0.5]
    with pytest.raises(ValueError):
        holm([0.2, 1.5])


def test_compare_flags_ties_and_corrects_the_family() -> None:
    rates = {
        "A": {"t1": (20, 20), "t2": (0, 20), "t3": (20, 20), "t4": (12, 20)},
        "B": {"t1": (2, 20), "t2": (0, 20), "t3": (20, 20), "t4": (10, 20)},
    }
    out = {c.task: c for c in compare(rates, [("A", "B")])}
    assert out["t1"].significant and out["t1"].verdict == "A"
    assert out["t2"].tie == "floor" and out["t2"].verdict == "tie at floor"
    assert out["t3"].tie == "ceiling" and not out["t3"].significant
    assert out["t4"].verdict == "n.s."
    # two tests in the family (the ties are not tests): Holm doubles the smaller p-value
    assert out["t1"].p_holm == pytest.approx(min(1.0, 2 * out["t1"].p_value))
    with pytest.raises(ValueError):
        compare(rates, [("A", "C")])


def test_mcnemar_is_the_binomial_test_of_the_discordant_pairs() -> None:
    """A worked check against scipy: the exact McNemar p-value is binomtest(b, b + c, 1/2)."""
    from scipy.stats import binomtest

    for b, c in [(0, 1), (1, 0), (3, 9), (9, 3), (10, 10), (0, 12), (25, 7), (40, 0)]:
        assert mcnemar_exact(b, c) == pytest.approx(binomtest(b, b + c, 0.5).pvalue, rel=1e-12)
    assert mcnemar_exact(0, 0) == 1.0
    with pytest.raises(ValueError):
        mcnemar_exact(-1, 2)


def test_newcombe_paired_interval() -> None:
    """Uncorrelated pairs (phi = 0) give the unpaired hybrid interval for n pairs; correlated
    pairs a narrower one; every interval contains its point estimate and stays in [-1, 1]."""
    # phi = 0: both * neither == only_a * only_b
    paired = newcombe_paired_difference(4, 4, 2, 2)  # p_A = 8/12, p_B = 6/12
    unpaired = newcombe_difference(8, 12, 6, 12)
    assert paired.value == pytest.approx(unpaired.value)
    assert (paired.low, paired.high) == pytest.approx((unpaired.low, unpaired.high))
    # the same margins, positively correlated: narrower
    tight = newcombe_paired_difference(6, 2, 0, 4)
    assert tight.value == pytest.approx(paired.value)
    assert tight.high - tight.low < paired.high - paired.low
    for counts in [(0, 0, 0, 20), (20, 0, 0, 0), (0, 20, 0, 0), (0, 0, 20, 0), (19, 1, 0, 0)]:
        d = newcombe_paired_difference(*counts)
        assert -1.0 <= d.low <= d.value <= d.high <= 1.0
    with pytest.raises(ValueError):
        newcombe_paired_difference(0, 0, 0, 0)


def test_compare_paired_tests_the_discordant_pairs_and_corrects_its_own_family() -> None:
    pairs_t1 = [(True, False)] * 12 + [(True, True)] * 8  # A wins 12 discordant pairs
    pairs_t2 = [(False, False)] * 20  # floor
    pairs_t3 = [(True, False)] * 3 + [(False, True)] * 2 + [(True, True)] * 15
    out = {
        c.task: c
        for c in compare_paired({("A", "B"): {"t1": pairs_t1, "t2": pairs_t2, "t3": pairs_t3}})
    }
    assert out["t1"].p_value == pytest.approx(mcnemar_exact(12, 0))
    assert out["t1"].significant and out["t1"].verdict == "A"
    assert out["t2"].tie == "floor"
    assert out["t3"].verdict == "n.s." and out["t3"].difference.value == pytest.approx(0.05)
    assert out["t1"].p_holm == pytest.approx(min(1.0, 2 * out["t1"].p_value))  # two tests
    # Pooled unpaired, 20/20 vs 8/20 on t1; paired, the same data is 12 discordant pairs.
    assert out["t1"].difference.value == pytest.approx(0.6)
