"""A parameter-shared per-agent policy trained at N = 100, evaluated at other swarm sizes.

A per-agent policy (PettingZoo training; its observation is one agent's row, here the
``"swarm"`` layout of docs/env-options.md) runs at any N: `PerAgentPolicy` builds the N rows
from the Gymnasium observation. This script evaluates the final models of the given runs with
`agent_envs.training.commands.evaluate.evaluate_policies` on the paper setting
(`training.commands.presets.PAPER_ENV`) with ``n_agents`` replaced, next to the proportional
and zero controllers on the same test seeds, and prints the mean cost of each and the ratio to the
proportional controller (the issue's target at N = 10^4: within 2x).

    OPENBLAS_NUM_THREADS=1 python benchmarks/shared_across_n.py RUN [RUN ...] \\
        [--sizes 20 1000 10000] [--seeds 10] [--model final|best] [--out FILE.csv] \\
        [--episodes EPISODES.csv]

``--model best`` evaluates each run's best model on the validation seeds (what the leaderboard
scores) instead of its final one; ``--episodes`` writes every episode's cost (policy, N, seed).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import pandas as pd

from agent_envs.training.commands.evaluate import evaluate_policies
from agent_envs.training.commands.presets import PAPER_ENV

REFERENCES = ("proportional", "zero")


def evaluate_at(
    runs: list[Path], n_agents: int, seeds: list[int], model: str = "final"
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Mean cost per policy at swarm size `n_agents` (rows: policy, n_agents, mean_cost, ...)
    and the episodes (policy, n_agents, seed, total_cost)."""
    policies = {f"shared ({run.name})": str(run / f"{model}_model.zip") for run in runs}
    policies.update({name: name for name in REFERENCES})
    start = time.perf_counter()
    results = evaluate_policies(
        policies, env_kwargs={**PAPER_ENV, "n_agents": n_agents}, seeds=seeds, progress=False
    )
    episodes = results.episodes[["policy", "seed", "total_cost"]].copy()
    episodes.insert(1, "n_agents", n_agents)
    table = results.episodes.groupby("policy", sort=False)["total_cost"].agg(["mean", "std"])
    table = table.rename(columns={"mean": "mean_cost", "std": "std_cost"}).reset_index()
    table["ratio_to_proportional"] = table["mean_cost"] / float(
        table.loc[table["policy"] == "proportional", "mean_cost"].iloc[0]
    )
    table.insert(1, "n_agents", n_agents)
    table["wall_s"] = time.perf_counter() - start
    return table, episodes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="run folders of the shared learner")
    parser.add_argument("--sizes", nargs="+", type=int, default=[20, 1000, 10_000])
    parser.add_argument("--seeds", type=int, default=10, help="test seeds 10000, 10001, ...")
    parser.add_argument("--model", choices=("final", "best"), default="final")
    parser.add_argument("--out", type=Path, default=None, help="write the table as CSV here")
    parser.add_argument("--episodes", type=Path, default=None, help="write every episode here")
    args = parser.parse_args()
    seeds = list(range(10_000, 10_000 + args.seeds))
    tables, episodes = [], []
    for n in args.sizes:
        table, rows = evaluate_at(args.runs, n, seeds, args.model)
        print(table.to_string(index=False), flush=True)
        tables.append(table)
        episodes.append(rows)
    if args.out:
        pd.concat(tables).to_csv(args.out, index=False)
    if args.episodes:
        pd.concat(episodes).to_csv(args.episodes, index=False)


if __name__ == "__main__":
    main()
