"""What do more threads (`num_threads`) give the native vector env and the single env?

Question: the compiled passes can run their batch members on numba's threads
(`num_threads=k` when the env is made; bit for bit the same results). How many env-steps/s do
the machine's other cores add at the paper setting (N = 100, m = 50, eps = 0.05, frozen
Jacobian, max_control = 25)?

Baselines in the same run (one process, interleaved rounds, medians of `--rounds`): the same
env on one thread, and the Python baseline of each case: Gymnasium's SyncVectorEnv at B = 64,
1 path (SERB and EM), B = 16 single envs stepped in a loop at 20 paths (SERB); and the paper
single env (20 paths) on 1 thread against `most` threads, SERB and EM. `most` is
`agent_envs.native.max_compiled_threads()` (numba's NUMBA_NUM_THREADS: the CPUs it sees); with
one thread there (or no numba) the script says so and stops.

    python benchmarks/bench_threads.py            # the three batch cases (~1 min)
    python benchmarks/bench_threads.py --quick    # B = 8, 2 rounds (seconds)
"""

from __future__ import annotations

import _timing  # isort: skip  (first: pins the BLAS pools before numpy loads)

import argparse
from collections.abc import Callable
from typing import Any

import gymnasium as gym
from _timing import env_kwargs

from agent_envs.envs import ENV_ID


def case_rates(
    integrator: str, b: int, n_paths: int, most: int, seconds: float, rounds: int
) -> dict:
    """env-steps/s of the native env on 1 and `most` threads and of the case's baseline."""
    kwargs = env_kwargs("paper", integrator, n_paths=n_paths)
    fns: dict[str, Callable[[], Any]] = {
        f"native{k}": _timing.native_stepper({**kwargs, "num_threads": k}, b)
        for k in sorted({1, most})
    }
    if n_paths == 1:
        sync = gym.make_vec(ENV_ID, num_envs=b, vectorization_mode="sync", **kwargs)
        sync.reset(seed=0)
        actions = _timing.batch_actions(b, kwargs["n_agents"])
        fns["baseline"] = lambda: sync.step(actions)
    else:
        singles = [_timing.single_env_stepper(kwargs, first_seed=1000 * i) for i in range(b)]
        fns["baseline"] = lambda: [s() for s in singles]
    calls = _timing.calls_for(fns["baseline"], seconds)
    return {name: b / t for name, t in _timing.interleaved(fns, calls, rounds).items()}


def single_rates(most: int, calls: int, rounds: int) -> dict[str, float]:
    """Steps/s of the paper single env, SERB and EM, on 1 and `most` threads."""
    fns = {
        f"{integrator}{k}": _timing.single_env_stepper(
            env_kwargs("paper", integrator, num_threads=k)
        )
        for k in sorted({1, most})
        for integrator in ("serb", "em")
    }
    return {name: 1.0 / t for name, t in _timing.interleaved(fns, calls, rounds).items()}


def main() -> int:
    from agent_envs import native

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="B = 8, 2 rounds of ~0.05 s")
    parser.add_argument("--rounds", type=int, default=None, help="interleaved rounds (medians)")
    parser.add_argument("--seconds", type=float, default=None, help="seconds per block")
    args = parser.parse_args()
    rounds = args.rounds or (2 if args.quick else 5)
    seconds = args.seconds or (0.05 if args.quick else 0.3)
    most = native.max_compiled_threads()
    print(f"The native vector env on {most} threads, paper setting, medians of {rounds} rounds")
    print(f"({_timing.compiled_paths()})\n")
    if most < 2:
        print("numba allows one thread here (NUMBA_NUM_THREADS, or no numba): nothing to compare")
        return 0
    cases = [("serb", 8, 1)] if args.quick else [("serb", 64, 1), ("serb", 16, 20), ("em", 64, 1)]
    rows = []
    for integrator, b, n_paths in cases:
        r = case_rates(integrator, b, n_paths, most, seconds, rounds)
        one, many = r["native1"], r[f"native{most}"]
        name = "SyncVectorEnv" if n_paths == 1 else f"{b} single envs in a loop"
        rows.append((integrator, n_paths, b, name, f"{one / r['baseline']:.2f}",
                     f"{many / r['baseline']:.2f}", f"{many / one:.2f}"))  # fmt: skip
    _timing.print_table(
        ("integrator", "paths", "B", "baseline", "native / baseline, 1 thread",
         f"{most} threads", f"{most} threads / 1"),
        rows,
    )  # fmt: skip
    s = single_rates(most, 10 if args.quick else 100, rounds)
    serb, em = s[f"serb{most}"] / s["serb1"], s[f"em{most}"] / s["em1"]
    print(f"The paper single env (20 paths), {most} threads / 1: SERB {serb:.2f}, EM {em:.2f}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
