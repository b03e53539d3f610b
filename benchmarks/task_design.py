"""The design figures of the benchmark's tasks, on validation seeds only.

    OPENBLAS_NUM_THREADS=1 python benchmarks/task_design.py [--seeds 1000 1001] [--out FILE.json]

Two choices of `agent_envs.tasks.catalog` are checked here, on the tasks' validation seeds
(1000..; never a test seed):

- the action bound |u| <= 25 of every task: the optimal open-loop control's largest |u_k^n| on
  each task (the bound must not clip the yardstick), next to the proportional law's (which it
  may clip: the bound is part of the task);
- the noisy task's sigma = 0.5: MPC's cost against the open-loop optimum's on the same seeds
  (feedback must beat any open-loop plan clearly for MPC to be the yardstick).

The large task is left out (no optimum is solved at N = 10^4). Needs the `train` extra (torch).
"""

from __future__ import annotations

import argparse
import json
import sys

import gymnasium as gym
import numpy as np

import agent_envs  # noqa: F401  (registers the task ids)
from agent_envs.baselines import make_baseline
from agent_envs.tasks import TASK_LIST
from agent_envs.training.results.committed_tables import design_table


def episode(task_id: str, name: str, seed: int) -> tuple[float, float]:
    """(cost, largest |u|) of one validation episode of a reference."""
    env = gym.make(task_id)
    policy = make_baseline(name, env)
    obs, _ = env.reset(seed=seed)
    cost, largest, done = 0.0, 0.0, False
    while not done:
        action, _ = policy.predict(obs)
        obs, reward, terminated, truncated, info = env.step(action)
        cost -= float(reward)
        largest = max(largest, float(np.abs(info["control"]).max()))
        done = terminated or truncated
    return cost, largest


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1000, 1001])
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    rows = []
    for task in TASK_LIST:
        if task.yardstick == "lower_bound":
            continue
        bad = [s for s in args.seeds if s in task.test_seeds or s not in task.validation_seeds]
        if bad:
            print(f"task_design.py: error: --seeds {bad} are not validation seeds", file=sys.stderr)
            return 2
        names = ["optimal", "proportional"] + (["mpc"] if "mpc" in task.references else [])
        for seed in args.seeds:
            row = {"task": task.id, "seed": seed}
            for name in names:
                row[f"{name}_cost"], row[f"{name}_max_u"] = episode(task.id, name, seed)
            rows.append(row)
            print(json.dumps(row), flush=True)
    print("\n" + design_table(rows))
    if args.out:
        with open(args.out, "w") as handle:
            json.dump(rows, handle, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
