"""Cost of one env step against one bare integrator step, measured in the same run (a ratio).

For N = 100 (the paper's stiff setting, eps = 0.05) and n_paths = 1 and 20, times

- bare:  dW = brownian_increments(rng, x.shape, tau); x = integrator.step(model, x, u, t, tau, dW)
  (exactly what `simulate` does per step, with a plain `SwarmModel`), restarting every m steps
  from uniform_positions(default_rng(k), ...) for episode k;
- gym:   `SwarmEnv.step(action)` (action -> control, integrator step, divergence check,
  running cost, observation with the path-mean interaction drift, info);
- pz:    `SwarmParallelEnv.step(actions)` (the same, plus N per-agent dicts).

Both envs are the raw classes (no gym.make wrappers); the controls are the same fixed u.
The envs are reset with seed=k for episode k, so the three loops visit the same states and
noise. Each timing is the best of `--repeats` interleaved blocks of `--steps` steps; resets
happen inside the timing, as in an RL loop. Aim: gym / bare < 1.3.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_env_step.py [--integrator serb]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np

from agent_envs import SwarmModel, SwarmParams, make_integrator
from agent_envs.draws import brownian_increments, uniform_positions
from agent_envs.envs import SwarmEnv, SwarmParallelEnv


def best_times(fns: dict[str, Callable[[], None]], steps: int, repeats: int) -> dict[str, float]:
    """Best over `repeats` rounds of the mean seconds per call of each function.

    The rounds interleave the functions (one block of `steps` calls each), so that a change of
    machine load hits all of them alike.
    """
    best = dict.fromkeys(fns, float("inf"))
    for _ in range(repeats):
        for name, fn in fns.items():
            start = time.perf_counter()
            for _ in range(steps):
                fn()
            best[name] = min(best[name], (time.perf_counter() - start) / steps)
    return best


def bench(integrator: str, n_paths: int, steps: int, repeats: int) -> dict[str, float]:
    n_agents, n_steps = 100, 50
    params = SwarmParams(n_agents=n_agents)
    max_control = 150.0
    action = np.random.default_rng(1).uniform(-0.5, 0.5, n_agents).astype(np.float32)
    control = max_control * action.astype(np.float64).reshape(n_agents, 1)

    # Episode k starts from reset(seed=k) in the envs and from default_rng(k) in the bare loop
    # (the generator gymnasium's seeding builds), so all three visit exactly the same states and
    # noise: the cost of the Krylov phi-action depends on the state.
    model = SwarmModel(params)
    scheme = make_integrator(integrator)
    dt = params.horizon / n_steps
    bare = {"episode": -1, "n": n_steps}

    def bare_step() -> None:
        if bare["n"] == n_steps:
            bare["episode"] += 1
            bare["rng"] = np.random.default_rng(bare["episode"])
            x0 = uniform_positions(bare["rng"], n_agents, 1)
            bare["x"], bare["n"] = np.broadcast_to(x0, (n_paths, n_agents, 1)).copy(), 0
        dw = brownian_increments(bare["rng"], bare["x"].shape, dt)
        bare["x"] = scheme.step(model, bare["x"], control, bare["n"] * dt, dt, dw)
        bare["n"] += 1

    kwargs = {"n_agents": n_agents, "integrator": integrator, "n_paths": n_paths}
    kwargs |= {"n_steps": n_steps, "max_control": max_control}
    env = SwarmEnv(**kwargs)
    gym_episode = [0]
    env.reset(seed=0)

    def gym_step() -> None:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            gym_episode[0] += 1
            env.reset(seed=gym_episode[0])

    par_env = SwarmParallelEnv(**kwargs)
    pz_episode = [0]
    par_env.reset(seed=0)
    actions = {agent: action[k : k + 1] for k, agent in enumerate(par_env.possible_agents)}

    def pz_step() -> None:
        par_env.step(actions)
        if not par_env.agents:
            pz_episode[0] += 1
            par_env.reset(seed=pz_episode[0])

    fns = {"bare": bare_step, "gym": gym_step, "pz": pz_step}
    for fn in fns.values():
        fn()  # warm-up
    return best_times(fns, steps, repeats)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--integrator", default="serb")
    parser.add_argument("--steps", type=int, default=100, help="steps per timed block")
    parser.add_argument("--repeats", type=int, default=5, help="timed blocks (best is kept)")
    args = parser.parse_args()
    print(f"N=100, eps=0.05, integrator={args.integrator}, best of {args.repeats}x{args.steps}")
    head = f"{'n_paths':>7} | {'bare ms':>8} {'gym ms':>8} {'pz ms':>8} |"
    print(f"{head} {'gym/bare':>8} {'pz/bare':>8}")
    for n_paths in (1, 20):
        t = bench(args.integrator, n_paths, args.steps, args.repeats)
        print(
            f"{n_paths:>7} | {1e3 * t['bare']:8.3f} {1e3 * t['gym']:8.3f} {1e3 * t['pz']:8.3f} | "
            f"{t['gym'] / t['bare']:8.2f} {t['pz'] / t['bare']:8.2f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
