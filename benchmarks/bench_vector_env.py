"""Native vector env against Gymnasium's SyncVectorEnv, and PPO on NativeVecEnv vs DummyVecEnv.

Ratios measured in the same run, N = 100 agents (the paper's stiff setting, eps = 0.05), one
path per env:

1. env-steps/s of `gym.make_vec(..., vectorization_mode="vector_entry_point")` (one batch)
   over `vectorization_mode="sync"` (one Python env per copy) for B = 16, 64, 256, for SERB
   with the default phi strategy (what the single env picks for its one path: Lanczos at
   N = 100; the native env then matches SyncVectorEnv bit for bit), SERB with
   phi_method="eigh" on both sides, and Euler-Maruyama. Actions are fixed
   uniform draws in [-0.5, 0.5]; autoresets happen inside the timing (m = 50). Each figure
   is the best of `--repeats` interleaved blocks of at least `--seconds` seconds, per CPU
   second of this process (robust when other processes share the cores) and per wall second.
2. PPO with the project's hyperparameters (`training/hyperparams/ppo.yml`, with
   VecNormalize and the horizon as termination), `--ppo-timesteps` timesteps, on
   `NativeVecEnv` and on SB3's `DummyVecEnv` of `gym.make` envs: timesteps/s of
   `model.learn` (torch with one thread), for n_envs = 4 (the default, n_steps = 256) and
   n_envs = 16 (n_steps = 64: the same 1024-sample rollouts).
3. `--device cuda`: B = `--gpu-envs` (4096) native envs on the GPU against the native env
   on the CPU at the same B (needs the torch core and a CUDA device; skipped otherwise).

    python benchmarks/bench_vector_env.py            # parts 1 and 2, about 2-3 minutes
    python benchmarks/bench_vector_env.py --quick    # part 1 at B = 16, short blocks (seconds)
    python benchmarks/bench_vector_env.py --device cuda

OPENBLAS_NUM_THREADS (and the other BLAS pools) are set to 1 below, before numpy loads.
"""

from __future__ import annotations

import os

for _pool in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_pool] = "1"

import argparse  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from typing import Any  # noqa: E402

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import agent_envs  # noqa: E402, F401  (registers agent_envs/Swarm-v0)
from agent_envs.envs import ENV_ID  # noqa: E402

N_AGENTS = 100
ENV_CONFIGS: dict[str, dict[str, Any]] = {
    "serb (auto)": {},
    "serb (eigh)": {"phi_method": "eigh"},
    "em": {"integrator": "em"},
}


def steps_per_second(step: Callable[[], None], batch: int, seconds: float) -> tuple[float, float]:
    """Env-steps per wall second and per CPU second of this process, over >= `seconds` (wall).

    One call of `step` is `batch` env-steps. Everything runs on one thread (BLAS pools and
    torch pinned to 1), so the CPU-time rate is what the code costs, and it stays meaningful
    when other processes share the cores; the wall-clock rate is what a user sees.
    """
    calls, start, cpu_start = 0, time.perf_counter(), time.process_time()
    while True:
        step()
        calls += 1
        elapsed = time.perf_counter() - start
        if elapsed >= seconds:
            cpu = time.process_time() - cpu_start
            return calls * batch / elapsed, calls * batch / cpu


def vector_stepper(mode: str, num_envs: int, kwargs: dict[str, Any]) -> Callable[[], None]:
    venv = gym.make_vec(
        ENV_ID, num_envs=num_envs, vectorization_mode=mode, n_agents=N_AGENTS, **kwargs
    )
    venv.reset(seed=0)
    rng = np.random.default_rng(1)
    actions = rng.uniform(-0.5, 0.5, (8, num_envs, N_AGENTS)).astype(np.float32)
    counter = iter(range(10**12))

    def step() -> None:
        venv.step(actions[next(counter) % len(actions)])

    return step


def bench_env_steps(batches: list[int], seconds: float, repeats: int) -> None:
    print(f"## env-steps/s, N = {N_AGENTS}, 1 path, m = 50 (best of {repeats})\n")
    print("Rates per CPU second (per wall second in brackets).\n")
    print("| integrator | B | native | SyncVectorEnv | native / sync (CPU) | (wall) |")
    print("|---|---|---|---|---|---|")
    for name, kwargs in ENV_CONFIGS.items():
        for b in batches:
            steppers = {
                mode: vector_stepper(mode, b, kwargs) for mode in ("vector_entry_point", "sync")
            }
            wall, cpu = dict.fromkeys(steppers, 0.0), dict.fromkeys(steppers, 0.0)
            for _ in range(repeats):
                for mode, step in steppers.items():
                    rate_wall, rate_cpu = steps_per_second(step, b, seconds)
                    wall[mode], cpu[mode] = max(wall[mode], rate_wall), max(cpu[mode], rate_cpu)
            native, sync = "vector_entry_point", "sync"
            print(
                f"| {name} | {b} | {cpu[native]:,.0f} ({wall[native]:,.0f}) | "
                f"{cpu[sync]:,.0f} ({wall[sync]:,.0f}) | {cpu[native] / cpu[sync]:.2f} | "
                f"{wall[native] / wall[sync]:.2f} |"
            )
    print()


def ppo_steps_per_second(
    vec_env: str, n_envs: int, n_steps: int, timesteps: int
) -> tuple[float, float]:
    """PPO timesteps per wall second and per CPU second of `model.learn`."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    from agent_envs.training.commands.train import make_training_env, resolve_hyperparams
    from agent_envs.training.config import GYM_ENV_ID, TrainConfig

    config = TrainConfig(env_id=GYM_ENV_ID, n_envs=n_envs, vec_env=vec_env, seed=0)
    kwargs, n_envs, normalize_kwargs, policy = resolve_hyperparams(config)
    kwargs = {**kwargs, "n_steps": n_steps}
    torch.set_num_threads(1)
    venv = make_training_env(config, n_envs)
    venv = VecNormalize(venv, **(normalize_kwargs or {}))
    model = PPO(policy, venv, seed=0, device="cpu", **kwargs)
    start, cpu_start = time.perf_counter(), time.process_time()
    model.learn(total_timesteps=timesteps)
    elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    venv.close()
    return model.num_timesteps / elapsed, model.num_timesteps / cpu


def bench_ppo(timesteps: int) -> None:
    print(f"## PPO timesteps/s, N = {N_AGENTS}, project hyperparameters, {timesteps} timesteps\n")
    print("Rates per CPU second (per wall second in brackets).\n")
    print("| n_envs | n_steps | NativeVecEnv | DummyVecEnv | native / dummy (CPU) | (wall) |")
    print("|---|---|---|---|---|---|")
    for n_envs, n_steps in ((4, 256), (16, 64)):
        native_wall, native_cpu = ppo_steps_per_second("native", n_envs, n_steps, timesteps)
        dummy_wall, dummy_cpu = ppo_steps_per_second("dummy", n_envs, n_steps, timesteps)
        print(
            f"| {n_envs} | {n_steps} | {native_cpu:,.0f} ({native_wall:,.0f}) | "
            f"{dummy_cpu:,.0f} ({dummy_wall:,.0f}) | {native_cpu / dummy_cpu:.2f} | "
            f"{native_wall / dummy_wall:.2f} |"
        )
    print()


def bench_device(device: str, num_envs: int, seconds: float) -> None:
    """B = num_envs native envs on a torch device against numpy on the CPU, same B."""
    import torch

    if device.startswith("cuda") and not torch.cuda.is_available():
        print(f"## {device}: no CUDA device here; skipped\n")
        return
    name = torch.cuda.get_device_name(device) if device.startswith("cuda") else device
    print(f"## native env on {name} (torch) vs numpy on the CPU, B = {num_envs}, N = {N_AGENTS}\n")
    print("| integrator | device env-steps/s | CPU env-steps/s | device / CPU |")
    print("|---|---|---|---|")
    for label, kwargs in ENV_CONFIGS.items():
        on_device = vector_stepper("vector_entry_point", num_envs, {**kwargs, "device": device})
        on_cpu = vector_stepper("vector_entry_point", num_envs, kwargs)
        on_device()  # warm-up: CUDA context, kernels
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        dev, _ = steps_per_second(on_device, num_envs, seconds)
        cpu, _ = steps_per_second(on_cpu, num_envs, seconds)
        print(f"| {label} | {dev:,.0f} | {cpu:,.0f} | {dev / cpu:.1f} |")
    print()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="B = 16, short blocks, no PPO")
    parser.add_argument("--batches", type=int, nargs="+", default=None, help="[16, 64, 256]")
    parser.add_argument("--seconds", type=float, default=None, help="0.8 (quick: 0.1)")
    parser.add_argument("--repeats", type=int, default=None, help="3 (quick: 1)")
    parser.add_argument("--ppo-timesteps", type=int, default=2048)
    parser.add_argument("--skip-ppo", action="store_true")
    parser.add_argument("--device", default=None, help="also time B = --gpu-envs on this device")
    parser.add_argument("--gpu-envs", type=int, default=4096)
    args = parser.parse_args()
    args.batches = args.batches or ([16] if args.quick else [16, 64, 256])
    args.seconds = args.seconds or (0.1 if args.quick else 0.8)
    args.repeats = args.repeats or (1 if args.quick else 3)
    args.skip_ppo = args.skip_ppo or args.quick
    print(f"CPU cores available: {len(os.sched_getaffinity(0))}, load average {os.getloadavg()}\n")
    bench_env_steps(args.batches, args.seconds, args.repeats)
    if not args.skip_ppo:
        bench_ppo(args.ppo_timesteps)
    if args.device:
        bench_device(args.device, args.gpu_envs, args.seconds)


if __name__ == "__main__":
    main()
