"""How fast is the native vector env on a GPU (torch) against numpy on this host's CPU?

Question: with `device="cuda"` the native vector env keeps its B envs' states and kernel
matrices on the device (torch, float64). At B = `--device-envs` (4096), the paper setting
(N = 100, m = 50) and the quick one (N = 10, m = 20), SERB and EM, 1 and 20 paths: how many
env-steps/s, how much slower are the first steps of a fresh process (cold/warm), and where
does a warm step go?

Baseline in the same run: the numpy native env on this host's CPU (one BLAS thread) at
B = min(`--device-envs`, `--device-cpu-envs`), halved until its dense matrices fit
`agent_envs.dynamics.operators.DENSE_MEMORY_BUDGET_BYTES` (numpy steps its systems one by one,
so its env-steps/s hardly depend on B past a few envs). Each side runs in a fresh process:
setup = import + CUDA context + make + reset; cold = seconds per step of the first `--steps`
steps; warm = the median of `--rounds` blocks of the same steps (reset with seed 0 first);
shares of the warm step: the host's Brownian draws (`fill_brownian_increments`, each env's
numpy generator) and the batched integrator step (`advance_paths`, synchronized with the
device), both timed by wrapping those public functions where the env calls them
(`agent_envs.envs.vector_env.fill_brownian_increments`, `vector_blocks.advance_paths`); the
device memory peak torch allocated. The device rates are absolute and name the GPU (the
project's standard for GPU figures); the CPU side is shown as the ratio device / CPU.

    python benchmarks/bench_device.py --device cuda            # the full table (minutes)
    python benchmarks/bench_device.py --device cuda --quick    # B = 256, quick setting, 1 path

Without a CUDA device (torch sees none) the script says so and prints nothing else.
"""

from __future__ import annotations

import _timing  # isort: skip  (first: pins the BLAS pools before numpy loads)

import argparse
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from _timing import SETTINGS, env_kwargs


def worker_device(
    device: str, num_envs: int, setting: str, integrator: str, n_paths: int, steps: int, rounds: int
) -> dict[str, float]:
    """The native vector env on `device` ("cpu": numpy; else torch there), B = `num_envs`, in
    this fresh process: setup, cold and warm seconds, the draws' and advance's shares."""
    start = time.perf_counter()
    import agent_envs  # noqa: F401
    from agent_envs.envs import vector_blocks, vector_env

    sync: Callable[[], None] = lambda: None  # noqa: E731
    if device != "cpu":
        import torch

        torch.zeros(1, device=device)  # the CUDA context, in the setup time
        if device.startswith("cuda"):
            sync = torch.cuda.synchronize
    extra = {} if device == "cpu" else {"device": device}
    env = _timing.make_native(env_kwargs(setting, integrator, n_paths=n_paths, **extra), num_envs)
    sync()
    setup = time.perf_counter() - start
    times = _timing.CallTimes()
    times.wrap(vector_env, "fill_brownian_increments", "draws")
    advance = vector_blocks.advance_paths  # (the one the env's blocks call)

    def synchronized(*args: Any, **kwargs: Any) -> Any:
        out = advance(*args, **kwargs)
        sync()
        return out

    vector_blocks.advance_paths = synchronized
    times.wrap(vector_blocks, "advance_paths", "advance")
    actions = _timing.batch_actions(num_envs, SETTINGS[setting]["n_agents"])

    def block() -> float:
        t0 = time.perf_counter()
        for _ in range(steps):
            env.step(actions)
        return (time.perf_counter() - t0) / steps

    cold = block()
    warm, shares = [], {"draws": [], "advance": []}
    for _ in range(rounds):
        env.reset(seed=0)
        times.seconds = {}
        seconds = block()
        warm.append(seconds)
        for key in shares:
            shares[key].append(times.seconds.get(key, 0.0) / (steps * seconds))
    times.restore()
    vector_env.advance_paths = advance
    out = {"setup": setup, "cold": cold, "warm": float(np.median(warm))}
    out.update({key: float(np.median(values)) for key, values in shares.items()})
    if device.startswith("cuda"):
        import torch

        out["peak_gib"] = torch.cuda.max_memory_allocated(device) / 2**30
    return out


WORKERS = {"device": worker_device}


def cpu_envs_that_fit(n: int, n_paths: int, most: int) -> int:
    """B of the CPU baseline: `most`, halved until its dense matrices fit the budget."""
    from agent_envs.dynamics.operators import DENSE_MEMORY_BUDGET_BYTES, dense_bytes

    b = most
    while b > 1 and dense_bytes(n, 1, b * n_paths, "frozen") > DENSE_MEMORY_BUDGET_BYTES:
        b //= 2
    return b


def device_row(args: argparse.Namespace, setting: str, integrator: str, n_paths: int) -> tuple:
    """One table row: the device and CPU workers of one case (a failure is its row)."""
    cpu_envs = cpu_envs_that_fit(
        SETTINGS[setting]["n_agents"], n_paths, min(args.device_envs, args.device_cpu_envs)
    )
    common = {"setting": setting, "integrator": integrator, "n_paths": n_paths}
    common.update(steps=args.steps, rounds=args.rounds)
    try:
        dev = _timing.run_fresh(__file__, "device", device=args.device,
                                num_envs=args.device_envs, **common)  # fmt: skip
        cpu = _timing.run_fresh(__file__, "device", device="cpu", num_envs=cpu_envs, **common)
    except RuntimeError as err:  # one failed row (out of memory, say) is reported
        return (setting, integrator, n_paths, "failed: " + str(err).strip().splitlines()[-1][:200])
    dev_rate, cpu_rate = args.device_envs / dev["warm"], cpu_envs / cpu["warm"]
    peak = dev.get("peak_gib", float("nan"))
    return (setting, integrator, n_paths, f"{dev_rate:,.0f}", f"{dev['cold'] / dev['warm']:.2f}",
            f"{dev['setup']:.1f}", f"{100 * dev['draws']:.0f} %", f"{100 * dev['advance']:.0f} %",
            f"{peak:.1f}", cpu_envs, f"{dev_rate / cpu_rate:.1f}")  # fmt: skip


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda", help="the torch device")
    parser.add_argument("--quick", action="store_true", help="B = 256, quick setting, 1 path")
    parser.add_argument("--device-envs", type=int, default=None, help="B on the device")
    parser.add_argument("--device-cpu-envs", type=int, default=512, help="B on the CPU, at most")
    parser.add_argument("--steps", type=int, default=None, help="steps per block")
    parser.add_argument("--rounds", type=int, default=None, help="warm blocks (median)")
    _timing.add_worker_arguments(parser, WORKERS)
    args = parser.parse_args()
    if _timing.serve_worker(args, WORKERS):
        return 0
    import torch

    if args.device.startswith("cuda") and not torch.cuda.is_available():
        print(f"{args.device}: torch sees no CUDA device here; nothing to measure")
        return 0
    args.device_envs = args.device_envs or (256 if args.quick else 4096)
    args.steps, args.rounds = (
        args.steps or (3 if args.quick else 10),
        args.rounds or (2 if args.quick else 5),
    )
    name = (
        torch.cuda.get_device_name(args.device) if args.device.startswith("cuda") else args.device
    )
    print(f"Native vector env on {name} (torch, float64), B = {args.device_envs}, against numpy"
          f" on this host's CPU (one thread); medians of {args.rounds} blocks\n")  # fmt: skip
    cases = [("quick", "serb", 1)] if args.quick else [
        (setting, integrator, n_paths)
        for setting in SETTINGS for n_paths in (1, 20) for integrator in ("serb", "em")
    ]  # fmt: skip
    rows = [device_row(args, *case) for case in cases]
    _timing.print_table(
        ("setting", "integrator", "paths", "device env-steps/s (warm)", "cold/warm", "setup (s)",
         "draws", "integrator step", "peak GiB", "CPU B", "device / CPU"),
        rows,
    )  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
