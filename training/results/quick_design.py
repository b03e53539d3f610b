"""The quick preset's budget design runs on the validation seeds (docs/presets.md, issue 42).

Each design run (``benchmarks/quick_design.py``) trains one variant of a quick-preset learner
(docs/results/quick-design/variants.json: its budget, number of validations, hyperparameters)
with one training seed, validated during training on the validation seeds 1000..1009: each row
of its ``learning_curve.csv``, and of ``runs.csv`` (`design_runs.RUN_COLUMNS`), holds the mean
swarm cost J of the deterministic policy over those S = 10 episodes. The run keeps its best
validation's model, J_best = min over its validations of J. ``references.csv``
(`REFERENCE_COLUMNS`) holds the cost of the quick preset's optimum (``optimal``: the optimal
open-loop plan of each episode), the proportional law and the centre law
(``proportional-common``) on each of the S seeds.

The gap of a run to the optimum is the gap of the means, J_best / V - 1 with V the optimum's
mean cost over the same S seeds (J_best is a mean over the seeds, not a per-seed quantity, so
the mean of per-seed gaps cannot be formed from it); a law's gap is its mean cost / V - 1.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from agent_envs.training.defaults import DEFAULT_EVAL_SEED
from agent_envs.training.results.design_runs import read_runs
from agent_envs.training.results.episode_csv import write_rows

#: validation episodes of the quick preset, on the seeds DEFAULT_EVAL_SEED + i
VALIDATION_EPISODES = 10
#: the validation seeds 1000..1009
VALIDATION_SEEDS = tuple(range(DEFAULT_EVAL_SEED, DEFAULT_EVAL_SEED + VALIDATION_EPISODES))
#: Columns of references.csv: one controller's cost on one validation seed.
REFERENCE_COLUMNS = ("policy", "seed", "total_cost")
#: the optimum, and the laws whose gaps the table shows (label, policy)
OPTIMUM = "optimal"
LAWS = (
    ("the proportional controller (no training)", "proportional"),
    ("the centre law `proportional-common` (no training)", "proportional-common"),
)
#: the training seeds of the table's columns
TRAINING_SEEDS = (0, 1, 2)


def write_references(rows: Iterable[dict[str, Any]], path: Path) -> None:
    """Write `REFERENCE_COLUMNS` rows to `path` (floats in repr: the file round-trips exactly);
    ValueError for a row with other columns."""
    rows = list(rows)
    for row in rows:
        if tuple(row) != REFERENCE_COLUMNS:
            raise ValueError(f"a references.csv row has the columns {REFERENCE_COLUMNS}")
    write_rows(path, rows)


def read_references(path: Path) -> dict[str, dict[int, float]]:
    """policy -> {validation seed: cost} of a references.csv; ValueError unless every policy
    has exactly the seeds `VALIDATION_SEEDS`."""
    costs: dict[str, dict[int, float]] = {}
    with open(path, newline="") as handle:
        for row in csv.DictReader(handle):
            costs.setdefault(row["policy"], {})[int(row["seed"])] = float(row["total_cost"])
    for policy, by_seed in costs.items():
        if tuple(sorted(by_seed)) != VALIDATION_SEEDS:
            raise ValueError(f"{path}: {policy} is not on the validation seeds 1000..1009")
    return costs


def mean_cost(references: dict[str, dict[int, float]], policy: str) -> float:
    """A controller's mean cost over the validation seeds (V for ``optimal``)."""
    return sum(references[policy][s] for s in VALIDATION_SEEDS) / len(VALIDATION_SEEDS)


def best_gaps(runs: Path, references: Path) -> dict[tuple[str, int], float]:
    """(variant, training seed) -> J_best / V - 1 of each run of `runs`."""
    value = mean_cost(read_references(references), OPTIMUM)
    best: dict[tuple[str, int], float] = {}
    for row in read_runs(runs):
        key = (row["variant"], row["training_seed"])
        best[key] = min(best.get(key, row["cost_mean"]), row["cost_mean"])
    return {key: cost / value - 1 for key, cost in best.items()}


def _percent(gap: float) -> str:
    return f"{100 * gap:+.2f}%"


def quick_design_table(runs: Path, references: Path, variants: Path) -> str:
    """docs/presets.md's table: one row per variant of `variants` (in its order, its label),
    the gap J_best / V - 1 of its run with each training seed (blank: not run); then the
    laws' gaps, the same for every training seed."""
    gaps = best_gaps(runs, references)
    labels = {name: spec["label"] for name, spec in json.loads(variants.read_text()).items()}
    unknown = sorted({variant for variant, _ in gaps} - set(labels))
    if unknown:
        raise ValueError(f"{runs}: variants {unknown} are not in {variants}")
    out = [
        "| design run | training seed 0 | seed 1 | seed 2 |",
        "|---|---|---|---|",
    ]
    for name, label in labels.items():
        cells = [_percent(gaps[name, s]) if (name, s) in gaps else "" for s in TRAINING_SEEDS]
        out.append(f"| {label} | {' | '.join(cells)} |")
    costs = read_references(references)
    value = mean_cost(costs, OPTIMUM)
    for label, policy in LAWS:
        cell = _percent(mean_cost(costs, policy) / value - 1)
        out.append(f"| {label} | {cell} | {cell} | {cell} |")
    return "\n".join(out)


__all__ = [
    "LAWS",
    "OPTIMUM",
    "REFERENCE_COLUMNS",
    "TRAINING_SEEDS",
    "VALIDATION_EPISODES",
    "VALIDATION_SEEDS",
    "best_gaps",
    "mean_cost",
    "quick_design_table",
    "read_references",
    "write_references",
]
