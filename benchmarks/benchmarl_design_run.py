"""One design run of a BenchMARL learner on a benchmark task: its validation curve, committed.

Trains `agent_envs.training.learners.benchmarl_runs.MarlRun` (MAPPO or IPPO, training seed,
frame budget, action scale) with `train_run` and copies the run's config.json, validation.csv
(J on the validation seeds 1000.. after each batch) and result.json (best J, its frames, wall
time) to ``OUT/TASK/ALGORITHM_seedS/`` (not the weights), with the command and the load:

    nice -n 5 python benchmarks/benchmarl_design_run.py --algorithm mappo --frames 48000 \\
        --out docs/results/marl-study

Needs the `marl` extra. Test seeds are never touched.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
from pathlib import Path

from agent_envs.training.learners.benchmarl_runs import (
    ALGORITHMS,
    CONFIG_FILE,
    CURVE_FILE,
    DEFAULT_ACTION_SCALE,
    DEFAULT_MINIBATCH_ITERS,
    RESULT_FILE,
    MarlRun,
    train_run,
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="agent_envs/StiffSwarm-v0")
    parser.add_argument("--algorithm", choices=list(ALGORITHMS), default="mappo")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--frames", type=int, required=True)
    parser.add_argument("--action-scale", type=float, default=DEFAULT_ACTION_SCALE)
    parser.add_argument("--minibatch-iters", type=int, default=DEFAULT_MINIBATCH_ITERS)
    parser.add_argument("--out", type=Path, default=Path("docs/results/marl-study"))
    args = parser.parse_args()
    run = MarlRun(
        args.task,
        args.algorithm,
        args.seed,
        frames=args.frames,
        action_scale=args.action_scale,
        minibatch_iters=args.minibatch_iters,
    )
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as runs:
        folder = train_run(run, runs)
        target = args.out / folder.relative_to(runs)
        target.mkdir(parents=True, exist_ok=True)
        for name in (CONFIG_FILE, CURVE_FILE):
            shutil.copyfile(folder / name, target / name)
        result = json.loads((folder / RESULT_FILE).read_text())
    result["command"] = "nice -n 5 python " + " ".join(sys.argv)
    result["load_average_before"] = load_before
    result["load_average_after"] = os.getloadavg()
    (target / RESULT_FILE).write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
