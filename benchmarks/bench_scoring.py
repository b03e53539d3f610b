"""What scoring costs on top of running the episodes: `agent_envs.tasks.score` against the bare
episodes of the same policy on the same seeds, cold (a fresh process) and warm, as a ratio.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_scoring.py            # StiffSwarm-v0
    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_scoring.py --task agent_envs/NoisySwarm-v0

The target (the benchmark issue): scoring a callable policy on the paper task's 20 test seeds
takes at most 2x the time of running its episodes alone. "Alone" is the loop a user writes:
`gym.make(task)`, reset on each test seed, step until the episode ends, sum the rewards; scoring
adds the reference file's hash check, the action checks and the score arithmetic. The policy is
the proportional law as a numpy callable (cheap, so the ratio shows the scoring's own cost).

Cold: each side in its own fresh process (import, env, first steps; `--rounds` processes each,
alternating). Warm: both in one process after one warm-up of each, alternating rounds. Prints
min / median / max of each side and of the per-round ratio.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time

CHILD = """
import json, sys, time
t0 = time.perf_counter()
import numpy as np, gymnasium as gym
import agent_envs
from agent_envs.tasks import get_task, score
task = get_task(sys.argv[2])
n, d = task.n_agents, task.dim
def policy(obs):
    return np.clip(12.0 * (obs[2 * n * d : 2 * n * d + d] - obs[: n * d].reshape(n, d)) / 25.0,
                   -1, 1).reshape(-1).astype(np.float32)
if sys.argv[1] == "score":
    score(policy, task)
else:
    env = gym.make(task.id)
    for seed in task.test_seeds:
        obs, _ = env.reset(seed=seed)
        total, done = 0.0, False
        while not done:
            obs, r, te, tr, _ = env.step(policy(obs))
            total, done = total + r, te or tr
print(json.dumps({"seconds": time.perf_counter() - t0}))
"""


def _cold(side: str, task: str) -> float:
    done = subprocess.run(
        [sys.executable, "-c", CHILD, side, task], capture_output=True, text=True, check=True
    )
    return json.loads(done.stdout.strip().splitlines()[-1])["seconds"]


def _warm_sides(task_id: str):
    import gymnasium as gym
    import numpy as np

    import agent_envs  # noqa: F401
    from agent_envs.tasks import get_task, score

    task = get_task(task_id)
    n, d = task.n_agents, task.dim
    lo = 2 * n * d

    def policy(obs):
        x = obs[: n * d].reshape(n, d)
        return np.clip(12.0 * (obs[lo : lo + d] - x) / 25.0, -1, 1).reshape(-1).astype(np.float32)

    def alone() -> None:
        env = gym.make(task.id)
        for seed in task.test_seeds:
            obs, _ = env.reset(seed=seed)
            done = False
            while not done:
                obs, _, te, tr, _ = env.step(policy(obs))
                done = te or tr

    def scoring() -> None:
        score(policy, task)

    return alone, scoring


def _row(name: str, values: list[float], unit: str = "s") -> str:
    return (
        f"| {name} | {min(values):.3f} {unit} | {statistics.median(values):.3f} {unit} | "
        f"{max(values):.3f} {unit} |"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", default="agent_envs/StiffSwarm-v0")
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args(argv)
    if args.rounds < 1:
        print("bench_scoring.py: error: --rounds must be >= 1", file=sys.stderr)
        return 2
    from agent_envs.tasks import get_task

    try:
        get_task(args.task)
    except (TypeError, ValueError) as exc:
        print(f"bench_scoring.py: error: {exc}", file=sys.stderr)
        return 2
    cold_alone, cold_score = [], []
    for _ in range(args.rounds):
        cold_alone.append(_cold("alone", args.task))
        cold_score.append(_cold("score", args.task))
    alone, scoring = _warm_sides(args.task)
    alone()
    scoring()
    warm_alone, warm_score = [], []
    for _ in range(args.rounds):
        for fn, out in ((alone, warm_alone), (scoring, warm_score)):
            start = time.perf_counter()
            fn()
            out.append(time.perf_counter() - start)
    cold_ratio = [s / a for s, a in zip(cold_score, cold_alone, strict=True)]
    warm_ratio = [s / a for s, a in zip(warm_score, warm_alone, strict=True)]
    print(f"Scoring overhead on {args.task}, 20 test seeds, {args.rounds} rounds\n")
    print("| figure | min | median | max |\n|---|---|---|---|")
    print(_row("cold: episodes alone (fresh process)", cold_alone))
    print(_row("cold: score() (fresh process)", cold_score))
    print(_row("cold: score / alone", cold_ratio, "x"))
    print(_row("warm: episodes alone", warm_alone))
    print(_row("warm: score()", warm_score))
    print(_row("warm: score / alone", warm_ratio, "x"))
    print(
        f"\ntarget: score / alone <= 2 (median warm {statistics.median(warm_ratio):.3f}x, "
        f"cold {statistics.median(cold_ratio):.3f}x)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
