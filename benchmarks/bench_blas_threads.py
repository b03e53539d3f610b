"""Env steps/s with the BLAS pools limited inside the hot path vs left at their default size.

Run WITHOUT OPENBLAS_NUM_THREADS (the point is the default pools):

    python benchmarks/bench_blas_threads.py [--n-agents 100] [--steps 300] [--repeats 5]

Times `SwarmEnv.step` (SERB, N agents, 1 path) with `agent_envs.arrays.HOT_PATH_BLAS_THREADS`
= 1 (the default: one BLAS thread while stepping) and = None (pools untouched), interleaved
over `--repeats` rounds so a change of machine load hits both alike; prints steps/s of each,
their ratio, the machine's load average, and the cost of entering `hot_path_threads()` once.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from agent_envs import arrays
from agent_envs.envs import SwarmEnv


def steps_per_second(env: SwarmEnv, steps: int, seed: int) -> float:
    action = np.zeros(env.action_space.shape, dtype=np.float32)
    env.reset(seed=seed)
    start = time.perf_counter()
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset(seed=seed)
    return steps / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n-agents", type=int, default=100)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    env = SwarmEnv(n_agents=args.n_agents, integrator="serb")
    best = {1: 0.0, None: 0.0}
    for k in range(args.repeats):
        for limit in (1, None):
            arrays.HOT_PATH_BLAS_THREADS = limit
            best[limit] = max(best[limit], steps_per_second(env, args.steps, k))
    arrays.HOT_PATH_BLAS_THREADS = 1
    n = 2000
    start = time.perf_counter()
    for _ in range(n):
        with arrays.hot_path_threads():
            pass
    enter = (time.perf_counter() - start) / n
    print(
        f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', '(unset)')}, "
        f"load average {os.getloadavg()[0]:.1f}, N = {args.n_agents}, SERB, 1 path"
    )
    print("| BLAS threads while stepping | env steps/s (best of rounds) |")
    print("|---|---|")
    print(f"| limited to 1 (default) | {best[1]:.0f} |")
    print(f"| library default | {best[None]:.0f} |")
    print(
        f"ratio limited / default: {best[1] / best[None]:.2f}; "
        f"entering hot_path_threads(): {1e6 * enter:.1f} us"
    )


if __name__ == "__main__":
    main()
