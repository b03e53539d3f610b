"""Design runs of the parameter-shared learners on the validation seeds (issue 41's choices).

Each design run trains one variant of the paper preset's ``ppo-shared`` learner (a change of its
hyperparameters or interface) on one benchmark task's env with one training seed, and validates
it during training on the task's validation seeds 1000-1004 (the run's ``learning_curve.csv``:
the mean swarm cost of the deterministic policy over those 5 episodes at each evaluation). The
test seeds are not used.

``runs.csv`` (`RUN_COLUMNS`) holds every evaluation of every run; `design_table` renders one row
per run from it: the first and the best validation cost and the best's gap to the optimum on the
same 5 seeds, ``(J_best - V) / V``, where V is the open-loop optimum's mean cost there
(docs/results/env-options: `results.json` for eps = 0.05, `results_eps1.json` for eps = 1),
next to the proportional law's gap (its cost is in every evaluation row, measured in the run).
"""

from __future__ import annotations

import csv
import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from agent_envs.training.results.episode_csv import write_rows

#: Columns of runs.csv: the run, then one evaluation.
RUN_COLUMNS = (
    "task",
    "variant",
    "training_seed",
    "timesteps",
    "cost_mean",
    "proportional_cost",
    "zero_cost",
)
#: The optimum's validation-seed file of each task (docs/results/env-options).
OPTIMUM_FILES = {
    "agent_envs/StiffSwarm-v0": "results.json",
    "agent_envs/WeakCouplingSwarm-v0": "results_eps1.json",
}


def curve_rows(task: str, variant: str, seed: int, curve: Path) -> list[dict[str, Any]]:
    """The evaluations of one run's learning_curve.csv as `RUN_COLUMNS` rows (``zero_cost``
    nan when the curve has no zero-control line: an `apg` run logs the proportional and the
    turnpike controllers only)."""
    with open(curve, newline="") as handle:
        return [
            {
                "task": task,
                "variant": variant,
                "training_seed": seed,
                "timesteps": int(row["timesteps"]),
                "cost_mean": float(row["cost_mean"]),
                "proportional_cost": float(row["proportional_cost"]),
                "zero_cost": float(row.get("zero_cost", "nan")),
            }
            for row in csv.DictReader(handle)
        ]


def write_runs(rows: Iterable[dict[str, Any]], path: Path) -> None:
    """Write `RUN_COLUMNS` rows to `path` with `episode_csv.write_rows` (floats in repr: the file
    round-trips exactly); ValueError for a row with other columns."""
    rows = list(rows)
    for row in rows:
        if tuple(row) != RUN_COLUMNS:
            raise ValueError(f"a runs.csv row has the columns {RUN_COLUMNS}; got {tuple(row)}")
    write_rows(path, rows)


def read_runs(path: Path) -> list[dict[str, Any]]:
    """The rows of a runs.csv, numbers parsed."""
    with open(path, newline="") as handle:
        rows = list(csv.DictReader(handle))
    for row in rows:
        row["training_seed"] = int(row["training_seed"])
        row["timesteps"] = int(row["timesteps"])
        for key in ("cost_mean", "proportional_cost", "zero_cost"):
            row[key] = float(row[key])
    return rows


def validation_optimum(task: str, env_options: Path) -> float:
    """V: the open-loop optimum's mean cost on the validation seeds 1000-1004 for `task`."""
    data = json.loads((env_options / OPTIMUM_FILES[task]).read_text())
    if list(data["seeds"]) != [1000, 1001, 1002, 1003, 1004]:
        raise ValueError(f"{OPTIMUM_FILES[task]} is not on the validation seeds 1000-1004")
    return float(data["results"]["optimal"]["cost"])


def design_table(runs: Path, env_options: Path) -> str:
    """One Markdown row per run (sorted by task, variant, seed): its last evaluation's agent-steps,
    the first and best validation cost, the best's gap to V and the proportional law's gap."""
    rows = read_runs(runs)
    keys = sorted({(r["task"], r["variant"], r["training_seed"]) for r in rows})
    out = [
        "| task | variant | training seed | agent-steps | first validation | best validation "
        "| best's gap to V | proportional's gap |",
        "|---|---|---|---|---|---|---|---|",
    ]
    values = {task: validation_optimum(task, env_options) for task in {k[0] for k in keys}}
    for task, variant, seed in keys:
        mine = [
            r
            for r in rows
            if (r["task"], r["variant"], r["training_seed"]) == (task, variant, seed)
        ]
        value = values[task]
        best = min(r["cost_mean"] for r in mine)
        law = mine[0]["proportional_cost"]
        out.append(
            f"| {task.split('/')[-1]} | {variant} | {seed} | {mine[-1]['timesteps']:,} "
            f"| {mine[0]['cost_mean']:.4f} | {best:.4f} | {100 * (best - value) / value:+.1f}% "
            f"| {100 * (law - value) / value:+.1f}% |"
        )
    return "\n".join(out)


__all__ = [
    "OPTIMUM_FILES",
    "RUN_COLUMNS",
    "curve_rows",
    "design_table",
    "read_runs",
    "validation_optimum",
    "write_runs",
]
