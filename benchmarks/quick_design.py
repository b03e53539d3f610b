"""Budget design runs of the quick preset's learners on the validation seeds (issue 42).

    python benchmarks/quick_design.py VARIANT SEED --out DIR     # one run
    python benchmarks/quick_design.py --references               # writes references.csv
    python benchmarks/quick_design.py --collect DIR [DIR ...]     # writes runs.csv

A *variant* (docs/results/quick-design/variants.json) is one of the quick preset's learners
(``learner``) with changes: its budget (``timesteps``: SB3 timesteps, agent-steps for
``ppo-shared``, iterations for ``apg``), the number of validations (``evaluations``, the
preset's `Preset.evaluations`), hyperparameters over its own (``hyperparams``; for ``apg``
`APGConfig` fields) and policy kwargs over its own (``policy_kwargs``); ``label`` is its row of
the table. One run trains it with `learner_config` of the quick preset on the preset's env with
one training seed, validated during training on the validation seeds 1000..1009 (10 episodes,
as the preset's SB3 learners; the test seeds 10000.. are never read). ``--collect`` gathers the
runs' learning curves into ``runs.csv`` (`design_runs.write_runs`); ``--references`` evaluates
the quick preset's optimum (``optimal``, the open-loop plan per episode), the proportional
controller and the centre law (``proportional-common``) on the same 10 seeds into
``references.csv`` (`quick_design.write_references`), so each run's gap to the optimum is
recomputable: `agent_envs.training.results.quick_design.quick_design_table` renders
docs/presets.md's table from the three files. A run takes 20-240 s on one loaded core.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results" / "quick-design"
#: the controllers of references.csv: the optimum, the proportional law and the centre law
REFERENCES = ("optimal", "proportional", "proportional-common")


def variant_preset(variant: str) -> tuple[Any, Any]:
    """(the quick preset with the variant's number of validations and its learner alone, the
    variant's learner: the preset's learner with the variant's changes, named `variant`)."""
    from agent_envs.training.commands.presets import PRESETS

    changes = json.loads((RESULTS / "variants.json").read_text())[variant]
    quick = PRESETS["quick"]
    base = next(lr for lr in quick.learners if lr.name == changes["learner"])
    hyper = {**base.hyperparams, **changes.get("hyperparams", {})}
    if "policy_kwargs" in changes:
        hyper["policy_kwargs"] = {**hyper["policy_kwargs"], **changes["policy_kwargs"]}
    learner = dataclasses.replace(
        base,
        name=variant,
        hyperparams=hyper,
        timesteps=int(changes.get("timesteps", base.timesteps)),
    )
    preset = dataclasses.replace(
        quick,
        learners=(learner,),
        evaluations=int(changes.get("evaluations", quick.evaluations)),
    )
    return preset, learner


def run(variant: str, seed: int, out: Path) -> Path:
    """Train one variant with one training seed; the run folder (``OUT/main__VARIANT__SEED``)."""
    import torch
    from threadpoolctl import threadpool_limits

    from agent_envs.training.commands.experiment import ExperimentOptions, learner_config
    from agent_envs.training.commands.learner_runs import train_from_dict

    torch.set_num_threads(1)
    preset, learner = variant_preset(variant)
    options = ExperimentOptions(torch_threads=1)
    with threadpool_limits(1):
        config = learner_config(preset, preset.settings[0], learner, seed, options, out)
        if not isinstance(config, dict):
            config = config.to_dict()
        return train_from_dict(config)


def references() -> Path:
    """The optimum's, the proportional law's and the centre law's cost on each validation seed
    of the quick preset's env, as its reference trials build them, into RESULTS/references.csv."""
    from threadpoolctl import threadpool_limits

    from agent_envs.training.commands.evaluate import evaluate_policies
    from agent_envs.training.commands.experiment import REFERENCE, ExperimentOptions, build_trials
    from agent_envs.training.commands.presets import PRESETS
    from agent_envs.training.defaults import DEFAULT_EVAL_SEED
    from agent_envs.training.results.quick_design import VALIDATION_EPISODES, write_references

    options = ExperimentOptions(references=REFERENCES)
    trials = [t for t in build_trials(PRESETS["quick"], options) if t.kind == REFERENCE]
    seeds = range(DEFAULT_EVAL_SEED, DEFAULT_EVAL_SEED + VALIDATION_EPISODES)
    with threadpool_limits(1):
        results = evaluate_policies(
            {t.policy: t.reference_spec() for t in trials},
            env_kwargs=trials[0].eval_env_kwargs,
            seeds=seeds,
            progress=False,
        )
    rows = [
        {"policy": str(r["policy"]), "seed": int(r["seed"]), "total_cost": float(r["total_cost"])}
        for r in results.episodes.to_dict(orient="records")
    ]
    write_references(rows, RESULTS / "references.csv")
    return RESULTS / "references.csv"


def collect(folders: list[Path]) -> Path:
    """Every run's learning curve under `folders` (``*/main__VARIANT__SEED/``) into
    RESULTS/runs.csv, in variants.json's order, then by training seed."""
    from agent_envs.training.results.design_runs import curve_rows, write_runs

    order = list(json.loads((RESULTS / "variants.json").read_text()))
    runs = []
    for curve in (p for f in folders for p in f.glob("*/learning_curve.csv")):
        _, variant, seed = curve.parent.name.split("__")
        runs.append((order.index(variant), int(seed), variant, curve))
    rows = []
    for _, seed, variant, curve in sorted(runs):
        rows += curve_rows("quick", variant, seed, curve)
    write_runs(rows, RESULTS / "runs.csv")
    return RESULTS / "runs.csv"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("variant", nargs="?")
    parser.add_argument("seed", nargs="?", type=int)
    parser.add_argument("--out", type=Path, default=Path("quick-design"))
    parser.add_argument("--collect", type=Path, nargs="+")
    parser.add_argument("--references", action="store_true")
    args = parser.parse_args(argv)
    if args.references:
        print(f"wrote {references()}")
    if args.collect:
        print(f"wrote {collect(args.collect)}")
    if args.references or args.collect:
        return 0
    if None in (args.variant, args.seed):
        parser.error("give VARIANT SEED, or --collect DIR, or --references")
    print(f"trained {run(args.variant, args.seed, args.out)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
