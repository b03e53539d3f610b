"""The BenchMARL task's action scale (`max_control`), chosen on validation seeds.

For each candidate max_control: BenchMARL's MAPPO (its default algorithm and MLP configs, a
small frames budget on CPU) trains on the SWARM task at N = 10, m = 20, eps = 0.05 (the quick
preset's env), and the swarm cost J of its deterministic policy is measured before training
(a fresh policy) and after, on validation seeds 1000.. (never the test seeds), beside the zero
control, the proportional law and the optimum on the Gymnasium env with the same kwargs.

    python benchmarks/benchmarl_action_scale.py --out docs/results/marl/action_scale.json

Needs the `marl` extra. Takes about 2-4 minutes per candidate on 2 shared cores.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from agent_envs.baselines import make_baseline
from agent_envs.training.defaults import DEFAULT_EVAL_SEED, GYM_ENV_ID
from agent_envs.training.results.rollout import make_swarm_env, rollout

ENV = {"n_agents": 10, "n_steps": 20, "epsilon": 0.05}
CANDIDATES = (150.0, 25.0, 10.0)
BASELINES = ("zero", "proportional", "optimal")


def validation_seeds(count: int) -> list[int]:
    """The first `count` validation seeds (1000, 1001, ...)."""
    return list(range(DEFAULT_EVAL_SEED, DEFAULT_EVAL_SEED + count))


def baseline_costs(env_kwargs: dict, seeds: list[int]) -> dict[str, list[float]]:
    """J per seed of each baseline on the Gymnasium env: minus the episode's summed reward."""
    env = make_swarm_env(GYM_ENV_ID, env_kwargs)
    costs = {}
    for name in BASELINES:
        policy = make_baseline(name, env)
        costs[name] = [-float(np.sum(rollout(policy, env, seed=s).rewards)) for s in seeds]
    env.close()
    return costs


def experiment_config(frames: int, batch: int, minibatch_iters: int, folder: str):
    """BenchMARL's default experiment config, with a small budget and csv logs only."""
    from benchmarl.experiment import ExperimentConfig

    config = ExperimentConfig.get_from_yaml()
    config.max_n_frames = frames
    config.on_policy_collected_frames_per_batch = batch
    config.on_policy_n_minibatch_iters = minibatch_iters
    config.loggers = ["csv"]
    config.evaluation = False
    config.render = False
    config.create_json = False
    config.save_folder = folder
    return config


def policy_costs(module, env_kwargs: dict, seeds: list[int]) -> dict[str, list[float]]:
    """J per seed of the deterministic policy (tanh(loc)) and of the sampled one (torch seeded
    with 0 first, so the draws repeat)."""
    import torch

    from agent_envs.training.learners.benchmarl_policy import GroupPolicy
    from agent_envs.training.learners.multiagent import evaluate_per_agent

    deterministic = evaluate_per_agent(GroupPolicy(module), env_kwargs, seeds).sum(axis=1)
    torch.manual_seed(0)
    sampled = evaluate_per_agent(GroupPolicy(module, sample=True), env_kwargs, seeds).sum(axis=1)
    return {"deterministic": deterministic.tolist(), "sampled": sampled.tolist()}


def mappo_costs(env_kwargs: dict, seeds: list[int], args: argparse.Namespace) -> dict:
    """J per seed of MAPPO's policy before and after training, and its training time."""
    from benchmarl.algorithms import MappoConfig
    from benchmarl.experiment import Experiment
    from benchmarl.models.mlp import MlpConfig

    from agent_envs.training.learners.benchmarl_task import SwarmTask

    task = SwarmTask.SWARM.get_task()
    task.config.update(env_kwargs)
    with tempfile.TemporaryDirectory() as folder:
        experiment = Experiment(
            task=task,
            algorithm_config=MappoConfig.get_from_yaml(),
            model_config=MlpConfig.get_from_yaml(),
            critic_model_config=MlpConfig.get_from_yaml(),
            seed=args.train_seed,
            config=experiment_config(args.frames, args.batch, args.minibatch_iters, folder),
        )
        before = policy_costs(experiment.policy, env_kwargs, seeds)
        start = time.perf_counter()
        experiment.run()
        seconds = time.perf_counter() - start
        after = policy_costs(experiment.policy, env_kwargs, seeds)
    return {
        "fresh": before["deterministic"],
        "trained": after["deterministic"],
        "fresh_sampled": before["sampled"],
        "trained_sampled": after["sampled"],
        "train_seconds": seconds,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--candidates", type=float, nargs="+", default=list(CANDIDATES))
    parser.add_argument("--seeds", type=int, default=10, help="validation seeds 1000..")
    parser.add_argument("--frames", type=int, default=6000)
    parser.add_argument("--batch", type=int, default=2000)
    parser.add_argument("--minibatch-iters", type=int, default=45)
    parser.add_argument("--train-seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    seeds = validation_seeds(args.seeds)
    rows = []
    print(
        f"{'max_control':>11} | {'fresh':>8} {'trained':>8} | {'sampled:':>8} {'fresh':>8} "
        f"{'trained':>8} | {'zero':>6} {'prop':>6} {'opt':>6}"
    )
    for scale in args.candidates:
        env_kwargs = {**ENV, "max_control": scale}
        costs = {**baseline_costs(env_kwargs, seeds), **mappo_costs(env_kwargs, seeds, args)}
        rows.append({"max_control": scale, **costs})
        mean = {k: float(np.mean(v)) for k, v in costs.items() if isinstance(v, list)}
        print(
            f"{scale:11.1f} | {mean['fresh']:8.3f} {mean['trained']:8.3f} | {'':8} "
            f"{mean['fresh_sampled']:8.3f} {mean['trained_sampled']:8.3f} | "
            f"{mean['zero']:6.3f} {mean['proportional']:6.3f} {mean['optimal']:6.3f}",
            flush=True,
        )
    result = {
        "env": ENV,
        "seeds": seeds,
        "algorithm": "BenchMARL 1.5.2 MAPPO, default MappoConfig and MlpConfig (actor, critic)",
        "experiment": {
            "max_n_frames": args.frames,
            "on_policy_collected_frames_per_batch": args.batch,
            "on_policy_n_minibatch_iters": args.minibatch_iters,
            "train_seed": args.train_seed,
            "other": "BenchMARL's base_experiment.yaml defaults",
        },
        "cost": "swarm cost J per validation seed: fresh/trained the deterministic policy "
        "(tanh(loc)), *_sampled the sampled one (torch.manual_seed(0) first)",
        "rows": rows,
    }
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
