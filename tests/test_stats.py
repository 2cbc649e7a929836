"""experiments.stats against hand-computed cases (rliable behind it)."""

from __future__ import annotations

import numpy as np
import pytest

from experiments import stats


def test_rliable_imports_with_the_pinned_pandas() -> None:
    import pandas
    import rliable  # noqa: F401  (rliable 1.2 fails to import with pandas 3)

    assert int(pandas.__version__.split(".")[0]) < 3


def test_iqm_hand_case() -> None:
    # 8 scores, 25 % trimmed from each end: the mean of 3, 4, 5, 6 = 4.5.
    scores = np.array([[1.0, 8.0], [2.0, 7.0], [3.0, 6.0], [4.0, 5.0]])
    assert stats.iqm(scores) == pytest.approx(4.5)
    with pytest.raises(ValueError, match="finite"):
        stats.iqm([[1.0, np.nan]])
    with pytest.raises(ValueError, match=r"\(runs, tasks\)"):
        stats.iqm([1.0, 2.0])


def test_probability_of_improvement_hand_case() -> None:
    # One task; x = {1, 3}, y = {2, 2}: pairs (1,2) lose, (3,2) win -> P(X > Y) = 2/4 = 0.5.
    # Ties count half: x = {2}, y = {2} -> 0.5; x = {3, 3}, y = {1, 2} -> 1.
    assert stats.probability_of_improvement([[1.0], [3.0]], [[2.0], [2.0]]).value == 0.5
    assert stats.probability_of_improvement([[2.0]], [[2.0]]).value == 0.5
    res = stats.probability_of_improvement([[3.0], [3.0]], [[1.0], [2.0]])
    assert res.value == 1.0 and res.low == 1.0 and res.high == 1.0
    # Two tasks: the average of the per-task probabilities (1 and 0) = 0.5.
    x = np.array([[5.0, 0.0], [6.0, 1.0]])
    y = np.array([[1.0, 2.0], [2.0, 3.0]])
    assert stats.probability_of_improvement(x, y).value == pytest.approx(0.5)
    with pytest.raises(ValueError, match="same tasks"):
        stats.probability_of_improvement(x, y[:, :1])


def test_aggregate_interval_brackets_the_estimate_and_is_seeded() -> None:
    rng = np.random.default_rng(0)
    data = {"a": rng.normal(1.0, 0.2, size=(5, 3)), "b": rng.normal(0.5, 0.2, size=(5, 3))}
    first = stats.aggregate(data, reps=500, seed=3)
    again = stats.aggregate(data, reps=500, seed=3)
    assert first == again
    for k, agg in first.items():
        assert agg.low <= agg.value <= agg.high
        assert agg.value == pytest.approx(stats.iqm(data[k]))
    assert first["a"].low > first["b"].high  # clearly separated
    # A constant score has a zero-width interval.
    const = stats.aggregate({"c": np.ones((4, 2))}, "mean", reps=200)["c"]
    assert (const.value, const.low, const.high) == (1.0, 1.0, 1.0)
    with pytest.raises(ValueError, match="statistic"):
        stats.aggregate(data, "mode")


def test_performance_profile_hand_case() -> None:
    scores = {"a": np.array([[0.1, 0.5], [0.9, 0.7]])}
    profile = stats.performance_profile(scores, [0.0, 0.5, 0.8, 1.0])
    # Fraction of the four scores strictly above tau: 4/4, 2/4 (0.7, 0.9), 1/4, 0/4.
    np.testing.assert_allclose(profile["a"], [1.0, 0.5, 0.25, 0.0])
