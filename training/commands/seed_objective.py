"""The multi-seed objective of `agent-envs tune`: one trial's cost over several training seeds.

A trial trains its sampled hyperparameters once per training seed s_1 .. s_n, one seed after the
other, each run reporting the best validation cost c_i it has reached so far (non-increasing in
its timesteps t_i, 0 < t_i <= B, the learner's budget). The objective of the trial is

    J = agg(c_1, ..., c_n),   agg = max (worst), median or mean,

over each seed's final best cost. So that a scheduler (ASHA, the median stopping rule) can stop
a trial early, the seeds lie end to end on one time axis of T = n B timesteps: while seed i runs,
its evaluation at t_i is reported at T = (i - 1) B + t_i with the partial objective

    J(T) = agg(c_1, ..., c_{i-1}, c_i(t_i)),

the finished seeds' final costs and the running seed's best so far. Every trial follows the same
seeds in the same order, so trials compared at one T are at the same point of the same
protocol; the last report, at T = n B, is J itself. A run may end past its budget (PPO's last
rollout rounds up): t_i is cut at B on every seed but the last, so that no seed reaches the next
one's part of the axis (or the scheduler's end n B). With one seed, J(T) is the run's best
validation cost so far at its own timesteps: the single-seed search as it always was.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

#: how a trial's costs over its training seeds combine into its objective
SEED_OBJECTIVES = ("worst", "median", "mean")
#: the trials table's columns of the training seeds' best validation costs: prefix + seed
SEED_COLUMN_PREFIX = "cost_seed_"


def aggregate_seeds(costs: Sequence[float], objective: str) -> float:
    """The objective over per-seed costs: max (worst), median (the mean of the two middle
    costs for an even count) or arithmetic mean; ValueError for no cost or another name."""
    if objective not in SEED_OBJECTIVES:
        raise ValueError(
            f"--seed-objective must be one of {', '.join(SEED_OBJECTIVES)}, got {objective!r}"
        )
    values = [float(c) for c in costs]
    if not values:
        raise ValueError("no per-seed cost to aggregate")
    if objective == "worst":
        return max(values)
    if objective == "median":
        return float(statistics.median(values))
    return math.fsum(values) / len(values)


def seed_column(seed: int) -> str:
    """The column (and reported metric) of training seed `seed`'s best validation cost."""
    return f"{SEED_COLUMN_PREFIX}{seed}"


@dataclass
class SeedReports:
    """The reports of one trial over its `seeds` (each trained for `budget` timesteps): the
    running seed's validation rows in, the results the scheduler sees out (module docstring).

    `evaluation(row)` takes a validation row (``cost_mean``, ``timesteps``) of the running
    seed; `next_seed()` closes the running seed. `costs[s]` is seed s's best cost so far.
    """

    seeds: tuple[int, ...]
    budget: int
    objective: str
    metric: str = "validation_cost"
    costs: dict[int, float] = field(default_factory=dict)
    running: int = 0

    def evaluation(self, row: dict[str, Any]) -> dict[str, Any]:
        """The result to report for `row`: the partial objective J(T), the cumulative
        timesteps T, the running seed, its last cost and every started seed's best cost."""
        seed = self.seeds[self.running]
        cost = float(row["cost_mean"])
        self.costs[seed] = min(self.costs.get(seed, math.inf), cost)
        steps = int(row["timesteps"])
        if self.running < len(self.seeds) - 1:
            steps = min(steps, self.budget)
        return {
            self.metric: aggregate_seeds(list(self.costs.values()), self.objective),
            "last_cost": cost,
            "timesteps": self.running * self.budget + steps,
            "seed": seed,
            **{seed_column(s): c for s, c in self.costs.items()},
        }

    def next_seed(self) -> None:
        """The running seed finished its budget: the next one starts."""
        self.running += 1


__all__ = ["SEED_COLUMN_PREFIX", "SEED_OBJECTIVES", "SeedReports", "aggregate_seeds", "seed_column"]
