"""What do good controls look like in action units, and what does the common control lose?

The env options of docs/env-options.md were designed from these figures. At the paper's setting
(training.commands.presets.PAPER_ENV: N = 100, m = 50, eps = 0.05, SERB, 20 paths,
max_control = 25) on the validation seeds 1000, 1001, ... (`training.defaults.DEFAULT_EVAL_SEED`:
these figures chose env options and bounds, so they never read a test seed), for the optimal
control (the sample-average solve of `agent_envs.baselines.OptimalController`) and the
proportional law u_k = beta (xbar - E x_k):

- the largest |u_k^n| and the largest |mean_k u_k^n| (the common control), in action units
  (/ max_control);
- the common mode's share of the control energy, sum_n N |mean_k u_k^n|^2 / sum_n sum_k |u_k^n|^2;
- how linear the common control is in the centre's offset: R^2 of mean_k u_k^n on
  (xbar - c^n) with one gain per step n (a time-varying linear feedback on the summary
  observation), pooled over the seeds;
- the cost of applying only the common mode of the same controller (the env with
  ``action_basis="common"``: the controller's mean control broadcast to every agent) against
  the controller itself on the same seeds: what the "common" action basis can lose.

With ``--out DIR/STEM.json`` it writes, beside the summary, the per-episode figures
``DIR/STEM_episodes.csv`` and the per-step common control and centre offset
``DIR/STEM_steps.csv`` (`agent_envs.training.results.env_options_episodes`): the summary is
computed from those rows, so `agent-envs tables` recomputes the published table from them.

    OPENBLAS_NUM_THREADS=1 python benchmarks/env_options.py [--seeds 5] [--out FILE.json]
        [--env-kwargs '{"epsilon": 1.0}']    # another setting (over the paper's)

docs/env-options.md's tables: ``--out docs/results/env-options/results.json`` (183 s on 2
cores) and ``--env-kwargs '{"epsilon": 1.0}' --out docs/results/env-options/results_eps1.json``
(475 s).
"""

from __future__ import annotations

import argparse
import json
import time

import gymnasium as gym
import numpy as np

import agent_envs  # noqa: F401  (registers the env)
from agent_envs.baselines import make_baseline
from agent_envs.training.commands.presets import PAPER_ENV
from agent_envs.training.defaults import DEFAULT_EVAL_SEED
from agent_envs.training.results.env_options_episodes import (
    episode_files,
    episode_rows,
    summary_from_rows,
)
from agent_envs.training.results.episode_csv import Row, write_rows

#: The env of the figures: the paper's, with --env-kwargs over it.
SETTING = dict(PAPER_ENV)


def episode(name: str, seed: int, **options: str) -> dict[str, np.ndarray | float]:
    """One validation episode of controller `name` on the setting's env with `options`: cost, the
    applied controls (m, N) and the centre's offsets xbar - c^n (m,)."""
    env = gym.make("agent_envs/Swarm-v0", **SETTING, **options)
    policy = make_baseline(name, env)
    obs, info = env.reset(seed=seed)
    target = env.unwrapped.params.target_vector[0]
    cost, controls, offsets, done = 0.0, [], [], False
    while not done:
        offsets.append(target - env.unwrapped.positions.mean())
        action, _ = policy.predict(obs)
        obs, reward, terminated, truncated, info = env.step(action)
        controls.append(info["control"][:, 0])
        cost -= reward
        done = terminated or truncated
    return {"cost": cost, "controls": np.array(controls), "offsets": np.array(offsets)}


def measure(name: str, seeds: list[int], max_control: float) -> tuple[list[Row], list[Row]]:
    """The episode and step rows of controller `name` on `seeds`
    (`agent_envs.training.results.env_options_episodes`)."""
    runs = [episode(name, s) for s in seeds]
    common_runs = [episode(name, s, action_basis="common") for s in seeds]
    episodes, steps = [], []
    for seed, run, common_run in zip(seeds, runs, common_runs, strict=True):
        row, step_rows = episode_rows(name, seed, run, common_run["cost"], max_control)
        episodes.append(row)
        steps += step_rows
    return episodes, steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--seeds", type=int, default=5, help="validation seeds 1000, 1001, ... (never test seeds)"
    )
    parser.add_argument("--out", default=None, help="write the figures as JSON here")
    parser.add_argument("--env-kwargs", default="{}", help="JSON env kwargs over the paper's")
    args = parser.parse_args()
    SETTING.update(json.loads(args.env_kwargs))
    seeds = list(range(DEFAULT_EVAL_SEED, DEFAULT_EVAL_SEED + args.seeds))
    start = time.perf_counter()
    episodes, steps = [], []
    for name in ("optimal", "proportional"):
        rows, step_rows = measure(name, seeds, SETTING["max_control"])
        episodes += rows
        steps += step_rows
    results = summary_from_rows(episodes, steps)
    elapsed = time.perf_counter() - start
    print(f"{SETTING}, validation seeds {seeds[0]}..{seeds[-1]} ({elapsed:.0f} s)")
    keys = list(results["optimal"])
    print(f"{'':32s}" + "".join(f"{name:>14s}" for name in results))
    for key in keys:
        print(f"{key:32s}" + "".join(f"{results[n][key]:14.4g}" for n in results))
    if args.out:
        with open(args.out, "w") as fh:
            json.dump({"seeds": seeds, "env_kwargs": SETTING, "results": results}, fh, indent=2)
        episodes_path, steps_path = episode_files(args.out)
        write_rows(episodes_path, episodes)
        write_rows(steps_path, steps)


if __name__ == "__main__":
    main()
