"""A fresh BenchMARL policy's swarm cost on a benchmark task, by interface and action scale s.

Before any training, a policy should cost about what the zero control costs, or PPO spends its
budget undoing its start (docs/learners/marl-libraries.md, "The action scale"). For each agent
observation layout (with the team reward) this builds BenchMARL's MAPPO experiment (training
seed 0; IPPO's actor is the same network) and measures its deterministic policy's mean J on the
task's validation seeds 1000.. with actions x s (`benchmarl_runs.validation_cost`: the task's
own env, max_control 25), beside the zero control and the proportional law with the bound
25 s (the cost of the bound to a good law):

    nice -n 5 python benchmarks/benchmarl_fresh_policy.py --out docs/results/marl-study/fresh.json

Needs the `marl` extra. About a minute per layout at N = 100.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import tempfile
from pathlib import Path

import numpy as np

from agent_envs.baselines import make_baseline
from agent_envs.training.defaults import GYM_ENV_ID
from agent_envs.training.learners.benchmarl_runs import MarlRun, build_experiment, validation_cost
from agent_envs.training.results.rollout import make_swarm_env, rollout

LAYOUTS = {
    "swarm": {"observation": "swarm", "agent_reward": "team"},
    "relative": {"observation": "relative", "agent_reward": "team"},
    "local": {"observation": "local", "neighbours": 6, "agent_reward": "team"},
}
SCALES = (1.0, 0.5, 0.25, 0.125)


def law_cost(name: str, run: MarlRun) -> float:
    """Mean J of a baseline law on the Gymnasium env with the train env's bound 25 s."""
    kwargs = {k: v for k, v in run.train_env_kwargs().items() if k not in LAYOUTS["local"]}
    env = make_swarm_env(GYM_ENV_ID, kwargs)
    policy = make_baseline(name, env)
    costs = [-float(np.sum(rollout(policy, env, seed=s).rewards)) for s in run.validation_seeds()]
    env.close()
    return float(np.mean(costs))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="agent_envs/StiffSwarm-v0")
    parser.add_argument("--layouts", nargs="+", default=list(LAYOUTS))
    parser.add_argument("--scales", type=float, nargs="+", default=list(SCALES))
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    import torch

    torch.set_num_threads(1)
    rows = []
    for layout in args.layouts:
        base = MarlRun(
            args.task, "mappo", 0, interface=LAYOUTS[layout], validation_episodes=args.episodes
        )
        with tempfile.TemporaryDirectory() as folder:
            policy = build_experiment(base, Path(folder)).policy
        for scale in args.scales:
            run = dataclasses.replace(base, action_scale=scale)
            row = {
                "layout": layout,
                "action_scale": scale,
                "max_control": run.train_env_kwargs()["max_control"],
                "fresh": validation_cost(policy, run),
                "zero": law_cost("zero", run),
                "proportional": law_cost("proportional", run),
            }
            print(row, flush=True)
            rows.append(row)
    result = {"task": args.task, "seeds": base.validation_seeds(), "rows": rows}
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
