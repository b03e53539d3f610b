"""docs/tune.md's table of the searches that were not shipped, from their committed files.

Each search (``agent-envs tune --out tune-paper-LEARNER``) commits ``trials.csv`` (one row
per trial: its best validation cost on the validation seeds 1000..1004, the objective) and
``tune_summary.md`` (whose "Parameter importances" list is Optuna's fANOVA over the trials).
The hand-chosen entry it is compared with is the same learner's run on the same training seed
(0) and validation seeds in the paper sweep: the lowest ``cost_mean`` of its
``learning_curve.csv``. Nothing here trains; the table is what those files say.
"""

from __future__ import annotations

import csv
import math
import re
from pathlib import Path

#: a tune output folder is named tune-paper-LEARNER
FOLDER = re.compile(r"tune-paper-(?P<learner>[a-z0-9-]+)$")
#: one importance line of tune_summary.md: "- name: 0.217"
IMPORTANCE = re.compile(r"^- (?P<name>[A-Za-z0-9_]+): (?P<value>[0-9.]+)$")


def _column(path: Path, name: str) -> list[float]:
    """One numeric column of a CSV file."""
    with open(path, newline="") as handle:
        return [float(row[name]) for row in csv.DictReader(handle)]


def _lowest_finite(values: list[float], error: str) -> float:
    """The smallest finite value (ValueError `error` when there is none)."""
    finite = [v for v in values if math.isfinite(v)]
    if not finite:
        raise ValueError(error)
    return min(finite)


def best_trial_cost(trials: Path) -> tuple[int, float]:
    """(trials, the lowest finite ``validation_cost``) of a search's ``trials.csv``."""
    costs = _column(trials, "validation_cost")
    return len(costs), _lowest_finite(costs, f"{trials}: no trial has a finite validation_cost")


def top_importances(summary: Path, count: int = 2) -> list[tuple[str, float]]:
    """The `count` first (largest) fANOVA importances listed in a ``tune_summary.md``."""
    lines = summary.read_text().splitlines()
    try:
        start = next(i for i, line in enumerate(lines) if line.startswith("## Parameter imp"))
    except StopIteration:
        raise ValueError(f"{summary}: no 'Parameter importances' section") from None
    found = []
    for line in lines[start + 1 :]:
        if line.startswith("## "):
            break
        match = IMPORTANCE.match(line.strip())
        if match:
            found.append((match["name"], float(match["value"])))
    return found[:count]


def best_validation_cost(curve: Path) -> float:
    """The lowest finite ``cost_mean`` of a run's ``learning_curve.csv``."""
    return _lowest_finite(
        _column(curve, "cost_mean"), f"{curve}: no evaluation has a finite cost_mean"
    )


def tune_search_table(*files: Path) -> str:
    """Rows of (trials.csv, tune_summary.md, the hand-chosen run's learning_curve.csv) triples,
    one per search, in the order given; the learner is read from the search's folder name."""
    if not files or len(files) % 3:
        raise ValueError("tune_search_table takes (trials.csv, tune_summary.md, curve) triples")
    lines = [
        "| learner | trials | best trial's validation cost | hand-chosen entry (training "
        "seed 0) | most important (fANOVA) |",
        "|---|---|---|---|---|",
    ]
    for trials, summary, curve in zip(files[::3], files[1::3], files[2::3], strict=True):
        match = FOLDER.match(trials.parent.name)
        if match is None:
            raise ValueError(f"{trials.parent}: a search folder is named tune-paper-LEARNER")
        count, best = best_trial_cost(trials)
        important = ", ".join(f"{name} {value:.2f}" for name, value in top_importances(summary))
        lines.append(
            f"| {match['learner']} | {count} | {best:.3g} | {best_validation_cost(curve):.3g} | "
            f"{important} |"
        )
    return "\n".join(lines)


__all__ = ["best_trial_cost", "best_validation_cost", "top_importances", "tune_search_table"]
