"""Across-seed statistics (`agent_envs.training.results.seed_statistics`) on hand-computable
examples and against rliable (skipped without the `sweep` extra, which installs rliable)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rliable")

from agent_envs.training.results.seed_statistics import (
    PolicyScores,
    across_seed_table,
    improvement_interval,
    iqm,
    iqm_interval,
    probability_of_improvement,
    scores_from_costs,
)


def test_iqm_hand_computed():
    """Costs 1..7 and an outlier 100 over 2 seeds x 4 episodes: the IQM drops the lowest two
    and highest two of the 8 values, mean(3, 4, 5, 6) = 4.5; the mean is 16."""
    costs = np.array([[1.0, 2.0, 3.0, 4.0], [5.0, 6.0, 7.0, 100.0]])
    scores = scores_from_costs(costs)
    assert iqm(scores) == pytest.approx(-4.5)
    table = across_seed_table({"p": PolicyScores(costs, np.zeros_like(costs, bool))}, [])
    assert table.loc[0, "iqm_cost"] == pytest.approx(4.5)
    assert table.loc[0, "mean_cost"] == pytest.approx(16.0)


def test_iqm_agrees_with_rliable():
    from rliable import metrics

    scores = np.random.default_rng(1).normal(size=(3, 7))
    assert iqm(scores) == pytest.approx(float(metrics.aggregate_iqm(scores)))


def test_diverged_episode_counts_as_the_worst():
    costs = np.array([[1.0, 2.0, 3.0, 0.5]])
    diverged = np.array([[False, False, False, True]])  # stopped early: its cost looks cheap
    scores = scores_from_costs(costs, diverged)
    assert scores[0, 3] == -np.inf
    # trimmed: the IQM of (-inf, -3, -2, -1) keeps (-3, -2)
    assert iqm(scores) == pytest.approx(-2.5)


def test_probability_of_improvement_hand_computed():
    """Episode 1: learner seeds cost 1 and 2 vs the reference's 2: a win and a tie (0.75).
    Episode 2: 3 and 5 vs 4: a win and a loss (0.5). Mean 0.625."""
    learner = scores_from_costs(np.array([[1.0, 3.0], [2.0, 5.0]]))
    reference = scores_from_costs(np.array([[2.0, 4.0]]))
    assert probability_of_improvement(learner, reference) == pytest.approx(0.625)
    p, low, high = improvement_interval(learner, reference, np.random.default_rng(0), 2000)
    assert p == pytest.approx(0.625)
    # resampling the learner's 2 seeds per episode: each episode's value is in {0.5, 0.75, 1}
    # and {0, 0.5, 1}; the extremes are reachable
    assert low == pytest.approx(0.25) and high == pytest.approx(1.0)


def test_stratified_bootstrap_resamples_runs_within_tasks():
    """Seeds that agree on every episode leave nothing to resample within an episode: the
    stratified interval has zero width (an i.i.d. bootstrap over all cells would not)."""
    scores = np.array([[1.0, 2.0, 3.0, 4.0], [1.0, 2.0, 3.0, 4.0]])
    point, low, high = iqm_interval(scores, np.random.default_rng(0), 1000)
    assert point == low == high == pytest.approx(2.5)


def test_bootstrap_interval_contains_the_point_and_is_reproducible():
    scores = np.random.default_rng(2).normal(size=(4, 10))
    a = iqm_interval(scores, np.random.default_rng(5), 2000)
    b = iqm_interval(scores, np.random.default_rng(5), 2000)
    assert a == b
    assert a[1] < a[0] < a[2]


def test_one_run_has_a_zero_width_interval():
    scores = np.array([[1.0, 5.0, 2.0]])
    assert iqm_interval(scores, np.random.default_rng(0)) == (iqm(scores),) * 3


def test_probability_of_improvement_needs_the_same_tasks():
    with pytest.raises(ValueError, match="same tasks"):
        probability_of_improvement(np.zeros((2, 3)), np.zeros((1, 4)))


def test_batched_improvement_used_by_the_bootstrap_agrees_with_rliable():
    """The bootstrap evaluates P(X > Y) on many resamples at once; on one sample it is rliable's
    Mann-Whitney based value (integer scores, so ties occur)."""
    from rliable import metrics

    from agent_envs.training.results.seed_statistics import _pairwise_improvement_batched

    rng = np.random.default_rng(3)
    for runs_x, runs_y in ((3, 1), (2, 4), (5, 5)):
        x = rng.integers(0, 4, size=(runs_x, 6)).astype(float)
        y = rng.integers(0, 4, size=(runs_y, 6)).astype(float)
        expected = float(metrics.probability_of_improvement(x, y))
        assert float(_pairwise_improvement_batched(x, y)) == pytest.approx(expected)


def test_batched_iqm_used_by_the_bootstrap_agrees_with_rliable():
    from rliable import metrics

    from agent_envs.training.results.seed_statistics import _trimmed_mean_batched

    batch = np.random.default_rng(4).normal(size=(5, 3, 7))  # 5 resamples of (3 runs, 7 tasks)
    expected = [float(metrics.aggregate_iqm(b)) for b in batch]
    assert _trimmed_mean_batched(batch) == pytest.approx(expected)
