"""Across-seed statistics of a sweep (Agarwal et al., "Deep RL at the Edge of the Statistical
Precipice", NeurIPS 2021; the `rliable` library).

Scores. rliable maximizes scores; our policies minimize the episode cost (minus the return, the
discrete cost functional `eq:discrete_cost_functional`). The score of an episode is its
**negative cost**, ``score = -total_cost``, and a diverged episode (it stops early, so its
accumulated cost would look cheap) scores ``-inf``: it ranks below every finished episode.
Because the interquartile mean is a symmetric trimmed mean, ``IQM(-c) = -IQM(c)``: the tables
show the IQM *of the cost* (lower is better), with the score interval negated and swapped.

Layout. A policy's scores form a matrix (runs x tasks): runs are the training seeds, tasks are
the held-out test episodes (test seed i is the same initial state and noise for every policy).
A reference controller trains nothing: one run. This is rliable's layout (runs = seeds, tasks =
games), so:

- **IQM**: the 25% trimmed mean over all runs x tasks (`rliable.metrics.aggregate_iqm`);
- **stratified bootstrap CI**: runs are resampled with replacement within each task (rliable's
  `StratifiedBootstrap`), percentile interval. It measures the uncertainty from the finite
  number of training seeds; the test episodes are held fixed. With one run (a reference, or a
  sweep with one seed) the interval has zero width;
- **probability of improvement** P(X > Y): for each task, the probability that a random run of
  X scores higher (costs less) than a random run of Y, ties counting one half (the
  Mann-Whitney U statistic / (n_X n_Y)), averaged over tasks
  (`rliable.metrics.probability_of_improvement`); its CI resamples X's and Y's runs
  independently within each task (rliable's `StratifiedIndependentBootstrap`).

The point estimates come from `rliable.metrics`. The bootstrap runs on `scipy.stats.bootstrap`
(each task's runs passed as one sample, so they are resampled independently: the stratified
bootstrap) with the generator passed in: `rliable.library` imports `arch`, and every `arch`
release that `rliable` accepts (< 8) fails to import with pandas 3.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd

#: bootstrap replications of the CIs (rliable's default is 50 000)
DEFAULT_RESAMPLES = 10_000
#: seed of the bootstrap's generator when none is passed
DEFAULT_BOOTSTRAP_SEED = 0


def scores_from_costs(costs: np.ndarray, diverged: np.ndarray | None = None) -> np.ndarray:
    """rliable scores from episode costs: ``-cost``, and ``-inf`` where the episode diverged.

    Args:
        costs: (runs, tasks) total costs.
        diverged: (runs, tasks) booleans, or None.
    """
    scores = -np.asarray(costs, dtype=float)
    if diverged is not None:
        scores = np.where(np.asarray(diverged, dtype=bool), -np.inf, scores)
    return scores


def iqm(scores: np.ndarray) -> float:
    """Interquartile mean over all runs x tasks (`rliable.metrics.aggregate_iqm`)."""
    from rliable import metrics

    return float(metrics.aggregate_iqm(np.asarray(scores, dtype=float)))


def probability_of_improvement(scores_x: np.ndarray, scores_y: np.ndarray) -> float:
    """P(X > Y) averaged over tasks (`rliable.metrics.probability_of_improvement`)."""
    from rliable import metrics

    x, y = np.asarray(scores_x, dtype=float), np.asarray(scores_y, dtype=float)
    _check_tasks(x, y)
    return float(metrics.probability_of_improvement(x, y))


def _check_tasks(x: np.ndarray, y: np.ndarray) -> None:
    if x.ndim != 2 or y.ndim != 2 or x.shape[1] != y.shape[1]:
        raise ValueError(
            f"scores must be (runs, tasks) matrices with the same tasks, got {x.shape} and "
            f"{y.shape}"
        )


def _trimmed_mean_batched(stacked: np.ndarray) -> np.ndarray:
    """25% trimmed mean over the last two axes (runs, tasks) of a (batch, runs, tasks) array."""
    from scipy import stats

    flat = stacked.reshape(*stacked.shape[:-2], -1)
    return stats.trim_mean(flat, 0.25, axis=-1)


def _pairwise_improvement_batched(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """P(X > Y) + P(X = Y) / 2 per task, averaged over tasks, for (..., runs, tasks) arrays."""
    greater = (x[..., :, None, :] > y[..., None, :, :]).mean(axis=(-3, -2))
    ties = (x[..., :, None, :] == y[..., None, :, :]).mean(axis=(-3, -2))
    return (greater + 0.5 * ties).mean(axis=-1)


def _bootstrap(samples: list[np.ndarray], statistic, rng, resamples: int, confidence: float):
    from scipy import stats

    result = stats.bootstrap(
        tuple(samples),
        statistic,
        n_resamples=resamples,
        vectorized=True,
        axis=-1,
        method="percentile",
        confidence_level=confidence,
        rng=rng,
        batch=max(1, 2_000_000 // max(sum(s.size for s in samples), 1)),
    )
    return float(result.confidence_interval.low), float(result.confidence_interval.high)


def iqm_interval(
    scores: np.ndarray,
    rng: np.random.Generator,
    resamples: int = DEFAULT_RESAMPLES,
    confidence: float = 0.95,
) -> tuple[float, float, float]:
    """(IQM, low, high): the stratified-bootstrap percentile CI over runs within each task.

    One run: the interval is the point (nothing to resample).
    """
    x = np.asarray(scores, dtype=float)
    point = iqm(x)
    runs, tasks = x.shape
    if runs < 2:
        return point, point, point

    def statistic(*columns: np.ndarray, axis: int = -1) -> np.ndarray:
        return _trimmed_mean_batched(np.stack(columns, axis=-1))

    low, high = _bootstrap([x[:, j] for j in range(tasks)], statistic, rng, resamples, confidence)
    return point, low, high


def improvement_interval(
    scores_x: np.ndarray,
    scores_y: np.ndarray,
    rng: np.random.Generator,
    resamples: int = DEFAULT_RESAMPLES,
    confidence: float = 0.95,
) -> tuple[float, float, float]:
    """(P(X > Y), low, high): runs of X and of Y resampled independently within each task.

    A one-run side is held fixed (resampling one value returns it); both one-run: the point.
    """
    x, y = np.asarray(scores_x, dtype=float), np.asarray(scores_y, dtype=float)
    _check_tasks(x, y)
    point = probability_of_improvement(x, y)
    tasks = x.shape[1]
    resample_x, resample_y = x.shape[0] > 1, y.shape[0] > 1
    if not (resample_x or resample_y):
        return point, point, point
    samples = ([x[:, j] for j in range(tasks)] if resample_x else []) + (
        [y[:, j] for j in range(tasks)] if resample_y else []
    )

    def statistic(*columns: np.ndarray, axis: int = -1) -> np.ndarray:
        k = 0
        if resample_x:
            xs, k = np.stack(columns[:tasks], axis=-1), tasks
        if resample_y:
            ys = np.stack(columns[k : k + tasks], axis=-1)
        if not resample_x:
            xs = np.broadcast_to(x, (*ys.shape[:-2], *x.shape))
        if not resample_y:
            ys = np.broadcast_to(y, (*xs.shape[:-2], *y.shape))
        return _pairwise_improvement_batched(xs, ys)

    low, high = _bootstrap(samples, statistic, rng, resamples, confidence)
    return point, low, high


@dataclass(frozen=True)
class PolicyScores:
    """The (runs, tasks) costs of one policy; `diverged` marks episodes that blew up."""

    costs: np.ndarray
    diverged: np.ndarray

    @property
    def scores(self) -> np.ndarray:
        return scores_from_costs(self.costs, self.diverged)


def across_seed_table(
    policies: Mapping[str, PolicyScores],
    references: list[str],
    rng: np.random.Generator | None = None,
    resamples: int = DEFAULT_RESAMPLES,
    confidence: float = 0.95,
) -> pd.DataFrame:
    """One row per policy: runs, episodes, mean cost, IQM cost with its stratified-bootstrap CI,
    and P(policy costs less than ref) with its CI for every reference `ref` present.

    Costs of diverged episodes count as +inf (score -inf); the mean cost is over finished
    episodes only, with the divergence rate next to it.
    """
    rng = np.random.default_rng(DEFAULT_BOOTSTRAP_SEED) if rng is None else rng
    rows = []
    for name, data in policies.items():
        costs = np.asarray(data.costs, dtype=float)
        diverged = np.asarray(data.diverged, dtype=bool)
        point, low, high = iqm_interval(data.scores, rng, resamples, confidence)
        finished = costs[~diverged]
        row = {
            "policy": name,
            "runs": costs.shape[0],
            "episodes": costs.size,
            "mean_cost": float(finished.mean()) if finished.size else float("nan"),
            "divergence_rate": float(diverged.mean()),
            "iqm_cost": -point,
            "iqm_cost_ci_low": -high,
            "iqm_cost_ci_high": -low,
        }
        for ref in references:
            if ref == name or ref not in policies:
                continue
            p, lo, hi = improvement_interval(
                data.scores, policies[ref].scores, rng, resamples, confidence
            )
            row[f"poi_vs_{ref}"] = p
            row[f"poi_vs_{ref}_ci_low"] = lo
            row[f"poi_vs_{ref}_ci_high"] = hi
        rows.append(row)
    return pd.DataFrame(rows)


def _fmt(value: float) -> str:
    if not np.isfinite(value):
        return "inf" if value > 0 else ("-inf" if value < 0 else "n/a")
    return f"{value:.4g}"


def display_across_seed_table(table: pd.DataFrame, references: list[str]) -> pd.DataFrame:
    """The table as strings for the report: point [low, high] columns."""
    out = pd.DataFrame(
        {
            "policy": table["policy"],
            "training seeds": table["runs"],
            "episodes": table["episodes"],
            "mean cost": table["mean_cost"].map(_fmt),
            "IQM cost [95% CI]": [
                f"{_fmt(p)} [{_fmt(lo)}, {_fmt(hi)}]"
                for p, lo, hi in zip(
                    table["iqm_cost"],
                    table["iqm_cost_ci_low"],
                    table["iqm_cost_ci_high"],
                    strict=True,
                )
            ],
            "divergence rate": table["divergence_rate"].map(lambda v: f"{100 * v:.0f}%"),
        }
    )
    for ref in references:
        col = f"poi_vs_{ref}"
        if col not in table:
            continue
        out[f"P(cost < {ref}) [95% CI]"] = [
            "" if not np.isfinite(p) else f"{p:.2f} [{lo:.2f}, {hi:.2f}]"
            for p, lo, hi in zip(
                table[col].astype(float),
                table[f"{col}_ci_low"].astype(float),
                table[f"{col}_ci_high"].astype(float),
                strict=True,
            )
        ]
    return out


__all__ = [
    "DEFAULT_RESAMPLES",
    "PolicyScores",
    "across_seed_table",
    "display_across_seed_table",
    "improvement_interval",
    "iqm",
    "iqm_interval",
    "probability_of_improvement",
    "scores_from_costs",
]
