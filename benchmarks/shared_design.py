"""Design runs of the parameter-shared learners on the validation seeds (issue 41).

    python benchmarks/shared_design.py TASK VARIANT SEED --out DIR     # one run
    python benchmarks/shared_design.py --collect DIR [DIR ...]     # writes runs.csv

A *variant* (docs/results/shared-design/variants.json) changes the paper preset's ``ppo-shared``
learner: its policy kwargs, ``normalize``, env options (interface) and budget (``timesteps``).
One run trains it on a benchmark task's env (`agent_envs.training.commands.leaderboard.
task_preset`) with one training seed, validated during training on the task's validation seeds
1000-1004; the test seeds are never read. ``--collect`` gathers the runs' learning curves into
``runs.csv``, from which `agent_envs.training.results.design_runs.design_table` renders the table
of docs/learners/shared.md. Each run takes 4-8 minutes on one of 2 cores (docs/learners/shared.md).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results" / "shared-design"


def variant_learner(variant: str) -> object:
    """The paper preset's ppo-shared learner with the variant's changes."""
    from agent_envs.training.commands.presets import PRESETS

    changes = json.loads((RESULTS / "variants.json").read_text())[variant]
    base = next(lr for lr in PRESETS["paper"].learners if lr.name == "ppo-shared")
    hyper = dict(base.hyperparams)
    hyper["policy_kwargs"] = {**hyper["policy_kwargs"], **changes.get("policy_kwargs", {})}
    return dataclasses.replace(
        base,
        name=variant,
        hyperparams=hyper,
        env_kwargs={**base.env_kwargs, **changes.get("env_kwargs", {})},
        normalize=changes.get("normalize", base.normalize),
        timesteps=int(changes.get("timesteps", base.timesteps)),
    )


def run(task_id: str, variant: str, seed: int, out: Path) -> Path:
    """Train one variant on one task with one seed; the run folder."""
    import torch
    from threadpoolctl import threadpool_limits

    from agent_envs.tasks import get_task
    from agent_envs.training.commands.experiment import ExperimentOptions, learner_config
    from agent_envs.training.commands.leaderboard import task_preset
    from agent_envs.training.commands.learner_runs import train_from_dict

    torch.set_num_threads(1)
    learner = variant_learner(variant)
    task = get_task(task_id)
    preset = dataclasses.replace(task_preset(task), learners=(learner,))
    options = ExperimentOptions(torch_threads=1)
    with threadpool_limits(1):
        config = learner_config(
            preset, preset.settings[0], learner, seed, options, out / task.file_stem
        )
        return train_from_dict(config.to_dict())


def collect(folders: list[Path]) -> Path:
    """Every run's learning curve under `folders` into RESULTS/runs.csv."""
    from agent_envs.tasks import get_task
    from agent_envs.training.results.design_runs import curve_rows, write_runs

    rows = []
    for curve in sorted(p for f in folders for p in f.glob("*/*/learning_curve.csv")):
        stem, variant, seed = curve.parent.name.split("__")
        rows += curve_rows(get_task(f"agent_envs/{stem}").id, variant, int(seed), curve)
    write_runs(rows, RESULTS / "runs.csv")
    return RESULTS / "runs.csv"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("task", nargs="?")
    parser.add_argument("variant", nargs="?")
    parser.add_argument("seed", nargs="?", type=int)
    parser.add_argument("--out", type=Path, default=Path("shared-design"))
    parser.add_argument("--collect", type=Path, nargs="+")
    args = parser.parse_args(argv)
    if args.collect:
        print(f"wrote {collect(args.collect)}")
        return 0
    if None in (args.task, args.variant, args.seed):
        parser.error("give TASK VARIANT SEED, or --collect DIR")
    print(f"trained {run(args.task, args.variant, args.seed, args.out)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
