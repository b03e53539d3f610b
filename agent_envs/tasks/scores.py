"""The score of a policy on a task, per seed and over seeds.

Per test seed s, with J_s the policy's cost (minus the sum of its rewards: the discrete cost
functional `eq:discrete_cost_functional` on the env's paths), V_s the task's yardstick and
J0_s the zero control's cost on the same seed (`agent_envs.tasks.references`):

    gap_s   = (J_s - V_s) / V_s                      (0 at the yardstick, +0.05 = 5% above)
    score_s = 100 (J0_s - J_s) / (J0_s - V_s)       (0 = the zero control, 100 = V)

D4RL's normalized score with a real optimum in place of an "expert". It is never clipped: above
100 means cheaper than V (possible where V is MPC, or by the noise margin of an open-loop plan),
below 0 costlier than doing nothing. An episode that diverged (the env ended it early, so its
summed cost covers only the steps it ran) gets gap = +inf and score = -inf.

Over seeds (`summarize`): the mean with a 95% Student-t interval, and the interquartile mean
(IQM, the 25% trimmed mean: `rliable.metrics.aggregate_iqm`, the same as
`scipy.stats.trim_mean(x, 0.25)`, which computes it here so that scoring needs no extra) with a
95% percentile-bootstrap interval that resamples the test seeds (with several training runs,
whole columns of the (runs, seeds) matrix: the seeds are the sample). The bootstrap draws from a
generator seeded here (`BOOTSTRAP_SEED`), so the same scores give the same interval.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Replications of the bootstrap interval.
BOOTSTRAP_RESAMPLES = 5_000
#: Seed of the bootstrap's generator.
BOOTSTRAP_SEED = 0
#: Confidence level of every interval.
CONFIDENCE = 0.95


def gap(cost: np.ndarray, value: np.ndarray) -> np.ndarray:
    """(J - V) / V, element-wise."""
    cost, value = np.asarray(cost, dtype=float), np.asarray(value, dtype=float)
    return (cost - value) / value


def normalized_score(cost: np.ndarray, value: np.ndarray, zero_cost: np.ndarray) -> np.ndarray:
    """100 (J0 - J) / (J0 - V), element-wise, never clipped."""
    cost = np.asarray(cost, dtype=float)
    value, zero_cost = np.asarray(value, dtype=float), np.asarray(zero_cost, dtype=float)
    return 100.0 * (zero_cost - cost) / (zero_cost - value)


def iqm(values: np.ndarray) -> float:
    """Interquartile mean over all entries (25% cut at each end, as rliable's)."""
    from scipy import stats

    return float(stats.trim_mean(np.asarray(values, dtype=float).reshape(-1), 0.25))


@dataclass(frozen=True)
class Summary:
    """A quantity over test seeds: mean [t-interval], IQM [bootstrap interval], n seeds."""

    mean: float
    mean_low: float
    mean_high: float
    iqm: float
    iqm_low: float
    iqm_high: float
    n_seeds: int
    n_runs: int

    def as_dict(self) -> dict[str, float | int]:
        return dict(self.__dict__)


def _t_interval(values: np.ndarray) -> tuple[float, float, float]:
    from scipy import stats

    mean = float(np.mean(values))
    if values.size < 2 or not np.all(np.isfinite(values)):
        return mean, mean, mean
    half = float(stats.t.ppf(0.5 + CONFIDENCE / 2, values.size - 1) * stats.sem(values))
    return mean, mean - half, mean + half


def _iqm_interval(matrix: np.ndarray) -> tuple[float, float]:
    """Percentile bootstrap of the IQM, resampling seeds (columns of a (runs, seeds) matrix)."""
    from scipy import stats

    seeds = matrix.shape[1]
    if seeds < 2 or not np.all(np.isfinite(matrix)):
        point = iqm(matrix)
        return point, point
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    picks = rng.integers(0, seeds, size=(BOOTSTRAP_RESAMPLES, seeds))
    resampled = matrix[:, picks].transpose(1, 0, 2).reshape(BOOTSTRAP_RESAMPLES, -1)
    estimates = stats.trim_mean(resampled, 0.25, axis=1)
    alpha = (1 - CONFIDENCE) / 2
    low, high = np.quantile(estimates, [alpha, 1 - alpha])
    return float(low), float(high)


def summarize(values: np.ndarray) -> Summary:
    """Mean and IQM with their intervals over the test seeds.

    Args:
        values: (seeds,) per-seed values of one policy, or (runs, seeds) for several training
            runs of one learner on the same seeds (the mean's interval is over the seeds of the
            per-seed mean over runs; the IQM is over every entry).
    """
    matrix = np.asarray(values, dtype=float)
    if matrix.ndim == 1:
        matrix = matrix[None, :]
    if matrix.ndim != 2 or matrix.size == 0:
        raise ValueError(f"values must be (seeds,) or (runs, seeds), got shape {matrix.shape}")
    mean, low, high = _t_interval(matrix.mean(axis=0))
    iqm_low, iqm_high = _iqm_interval(matrix)
    return Summary(
        mean, low, high, iqm(matrix), iqm_low, iqm_high, matrix.shape[1], matrix.shape[0]
    )


__all__ = [
    "BOOTSTRAP_RESAMPLES",
    "BOOTSTRAP_SEED",
    "CONFIDENCE",
    "Summary",
    "gap",
    "iqm",
    "normalized_score",
    "summarize",
]
