"""The table of a compare preset over its training seeds, from the runs' per-episode files.

    python -m agent_envs.training.commands.seed_table quick \\
        docs/results/quick/seed0/episodes.csv docs/results/quick/seed1/episodes.csv \\
        docs/results/quick/seed2/episodes.csv

`agent-envs compare --preset P --seed S` trains one training seed and writes the held-out
evaluation's per-episode costs to ``OUT/evaluation/episodes.csv`` (columns policy, seed,
total_cost, ...). Given one such file per training seed (in seed order), `seed_table_markdown`
writes one row per policy:

- mean cost over the test seeds, per training seed;
- gap to optimal, per training seed: the mean over the test seeds s of (J(s) - V(s)) / V(s),
  with V(s) the optimal open-loop plan's cost on seed s (``optimal`` in the same file);
- paired ratio to the proportional controller and to the learner's fair baseline
  (`interface_references.fair_baseline` of its env options), per training seed: the mean over
  the test seeds of J(s) / J_ref(s).

References do not train: their episodes are the same in every file (checked), so their row
has one value per column. The published quick table (docs/results.md) is this function's
output on the files under docs/results/quick/, recomputed digit for digit by the tests.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from agent_envs.training.commands.interface_references import fair_baseline
from agent_envs.training.commands.presets import get_preset

#: The policy whose cost is V in the gap to optimal.
OPTIMUM = "optimal"


def _costs(path: str | Path) -> pd.DataFrame:
    """(test seeds x policies) total costs of one episodes file."""
    episodes = pd.read_csv(path)
    return episodes.pivot(index="seed", columns="policy", values="total_cost")


def _gap(costs: pd.DataFrame, policy: str) -> float:
    value = costs[OPTIMUM]
    return float(((costs[policy] - value) / value).mean())


def _ratio(costs: pd.DataFrame, policy: str, reference: str) -> float:
    return float((costs[policy] / costs[reference]).mean())


def _cells(values: Sequence[float], fmt: str, suffix: str = "") -> str:
    return " / ".join(format(v, fmt) + suffix for v in values)


def seed_table_markdown(preset_name: str, files: Sequence[str | Path]) -> str:
    """The Markdown table of `preset_name`'s learners and references, one episodes file per
    training seed (the preset's seeds, in order): learners first (preset order), then the
    references by mean cost. Cells with three numbers are training seeds 0 / 1 / 2 (the
    preset's); gaps in %, ratios to 3 decimals."""
    preset = get_preset(preset_name)
    runs = [_costs(f) for f in files]
    learners = [lr for lr in preset.learners if lr.name in runs[0]]
    lines = [
        "| policy | fair baseline | mean cost | gap to optimal | ratio to proportional | "
        "ratio to fair baseline |",
        "|---|---|---|---|---|---|",
    ]
    for learner in learners:
        fair = fair_baseline(learner.env_kwargs)
        gaps = [100 * _gap(c, learner.name) for c in runs]
        prop = [_ratio(c, learner.name, "proportional") for c in runs]
        fairs = [_ratio(c, learner.name, fair) for c in runs]
        means = [float(c[learner.name].mean()) for c in runs]
        lines.append(
            f"| **{learner.name}** | {fair} | {_cells(means, '.4g')} | "
            f"{_cells(gaps, '+.2f', '%')} | {_cells(prop, '.3f')} | {_cells(fairs, '.3f')} |"
        )
    references = [p for p in runs[0].columns if p not in {lr.name for lr in learners}]
    for name in references:
        if any(not np.array_equal(c[name].to_numpy(), runs[0][name].to_numpy()) for c in runs):
            raise ValueError(f"reference {name!r} differs between the training seeds' files")
    for name in sorted(references, key=lambda p: runs[0][p].mean()):
        gap = 100 * _gap(runs[0], name)
        prop = _ratio(runs[0], name, "proportional")
        mean = float(runs[0][name].mean())
        lines.append(f"| {name} | | {mean:.4g} | {gap:+.2f}% | {prop:.3f} | |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m agent_envs.training.commands.seed_table PRESET FILE...``: print the table."""
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) < 2:
        print("usage: python -m agent_envs.training.commands.seed_table PRESET EPISODES.csv...")
        return 2
    print(seed_table_markdown(args[0], args[1:]), end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())


__all__ = ["OPTIMUM", "main", "seed_table_markdown"]
