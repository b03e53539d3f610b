"""Estimate the wall time of `agent-envs sweep --preset paper` from short measured runs.

For each learner of the paper preset (its own TrainConfig, one seed, DummyVecEnv, no
evaluation during the short run) this trains `--short` timesteps and takes the time per
timestep; TD3's warm-up (random actions until `learning_starts`) is timed on its own, since it
costs an env step and no gradient step. It then times the evaluation per episode (on validation
seeds) of each trained model and of the reference controllers this install has. The estimate of one
learner trial is

    budget x (time per timestep)                           training
    + evaluations x validation_episodes x (eval per episode)  validation during training
    + test_episodes x (eval per episode)                   held-out evaluation

and a reference trial is test_episodes x (its eval per episode). The sum over the preset's
trials, divided by `--cores` (Ray runs one trial per core), is the estimate; it assumes the
trials pack perfectly onto the cores (the longest trial bounds the packing loss; it is printed).
The per-timestep rates of every PPO setting are taken from the main (SERB, eps = 0.05) one,
the slowest: EM steps cost about half as much.

    OPENBLAS_NUM_THREADS=1 python benchmarks/sweep_budget.py [--cores 2] [--out /tmp/budget]

The machine's load average is printed with the result: on a shared machine the rates are
pessimistic.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from collections import defaultdict

from agent_envs.training.commands.evaluate import evaluate_policies
from agent_envs.training.commands.experiment import LEARNER, ExperimentOptions, build_trials
from agent_envs.training.commands.presets import PRESETS
from agent_envs.training.commands.train import train
from agent_envs.training.config import TrainConfig
from agent_envs.training.defaults import DEFAULT_EVAL_SEED

#: short-run timesteps per learner (PPO: two rollouts; SAC/TD3: 1500 steps of gradient updates)
SHORT = {"ppo": 8192, "ppo-swarm": 8192, "sac": 1500, "td3": 1500, "ppo-shared": 8000}
EVAL_EPISODES = 2


def timed_train(trial, out: str, steps: int, **hyper) -> tuple[float, str]:
    hp = {**trial.train["hyperparams"], **hyper}
    config = TrainConfig.from_dict(
        {
            **trial.train,
            "out": out,
            "timesteps": steps,
            "eval_freq": 0,
            "checkpoint_freq": 10**9,
            "hyperparams": hp,
            "tensorboard": False,
            "run_name": f"{trial.trial_id}_{steps}_{len(hyper)}",
        }
    )
    start = time.perf_counter()
    run = train(config)
    return (time.perf_counter() - start) / steps, str(run / "final_model.zip")


def timed_eval(spec: str, trial) -> float:
    start = time.perf_counter()
    # timing only, but on validation seeds: a design script never reads a test seed
    seeds = list(range(DEFAULT_EVAL_SEED, DEFAULT_EVAL_SEED + EVAL_EPISODES))
    evaluate_policies({"p": spec}, env_kwargs=trial.eval_env_kwargs, seeds=seeds, progress=False)
    return (time.perf_counter() - start) / EVAL_EPISODES


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cores", type=int, default=2)
    parser.add_argument("--out", default=None, help="scratch folder (default: a temp dir)")
    args = parser.parse_args()
    out = args.out or tempfile.mkdtemp(prefix="sweep_budget_")
    preset = PRESETS["paper"]
    trials = build_trials(preset, ExperimentOptions(vec_env="dummy"), out)
    load_before = os.getloadavg()

    per_step: dict[str, float] = {}
    per_episode: dict[str, float] = {}
    warmup_per_step = None
    for trial in trials:
        if trial.kind != LEARNER or trial.setting != "main" or trial.seed != preset.seeds[0]:
            continue
        name = trial.policy
        hyper = {"learning_starts": 100} if name == "td3" else {}
        per_step[name], model = timed_train(trial, out, SHORT[name], **hyper)
        per_episode[name] = timed_eval(model, trial)
        if name == "td3":
            warmup_per_step, _ = timed_train(trial, out, 1000, learning_starts=10**6)
        print(
            f"{name:11s} {1e3 * per_step[name]:8.2f} ms per timestep, "
            f"{per_episode[name]:6.2f} s per test episode",
            flush=True,
        )
    print(f"td3 warm-up {1e3 * warmup_per_step:8.2f} ms per timestep (random actions)")
    for trial in trials:
        if trial.kind != LEARNER and trial.policy not in per_episode:
            # reference_spec: the preset's MPC plans on the noise-free model
            per_episode[trial.policy] = timed_eval(trial.reference_spec(), trial)
            print(f"{trial.policy:11s} {per_episode[trial.policy]:6.2f} s per test episode")

    seconds: dict[str, float] = defaultdict(float)
    longest = 0.0
    for trial in trials:
        episode = per_episode[trial.policy]
        if trial.kind == LEARNER:
            cfg = trial.train
            steps = cfg["timesteps"]
            training = steps * per_step[trial.policy]
            if trial.policy == "td3":
                warm = min(cfg["hyperparams"]["learning_starts"], steps)
                training = warm * warmup_per_step + (steps - warm) * per_step["td3"]
            validation = preset.evaluations * preset.validation_episodes * episode
            cost = training + validation + len(trial.test_seeds) * episode
        else:
            cost = len(trial.test_seeds) * episode
        longest = max(longest, cost)
        seconds[f"{trial.setting}/{trial.policy}"] += cost
    total = sum(seconds.values())
    print()
    for key, value in seconds.items():
        print(f"{key:24s} {value:8.0f} core-s")
    print(
        f"\npaper preset: {len(trials)} trials, {total:.0f} core-s; on {args.cores} cores "
        f"{total / args.cores / 3600:.2f} h (+ at most {longest / 3600:.2f} h packing loss)"
    )
    print(f"load average before {load_before[0]:.1f}, after {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
