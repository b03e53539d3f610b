"""Does the native vector env beat B single envs stepped in a loop, and how compute-bound is it?

Question: at the paper setting (SERB, N = 100, m = 50, eps = 0.05, frozen Jacobian,
max_control = 25) with 1 and 20 Brownian paths per env, how many env-steps/s does
`gym.make_vec(..., vectorization_mode="vector_entry_point")` give at B envs against B single
envs stepped in a Python loop, and how much of its step is the unavoidable compute?

Baselines in the same run (one process, interleaved rounds of about `--seconds` of the slower
side each, medians of `--rounds`):

- B single envs (`gym.make`) stepped in a loop, each with its own seeds;
- at the largest B and 1 path: Gymnasium's SyncVectorEnv (`vectorization_mode="sync"`) and
  the same native env made with its compiled step off (``native.use("step", False)``: the
  plan's envelope "numpy");
- the compute floor: one kernel matrix and drift per system (B x paths systems, by the env's
  own pass: compiled with numba, else in-place numpy, in chunks of at most 100 systems); the
  last column is its time as a share of the native step (near 100 %: compute-bound).

    python benchmarks/bench_vector_batching.py            # B = 1, 16, 64; ~2 min
    python benchmarks/bench_vector_batching.py --quick    # B = 1, 8; seconds
"""

from __future__ import annotations

import _timing  # isort: skip  (first: pins the BLAS pools before numpy loads)

import argparse
from collections.abc import Callable
from typing import Any

import gymnasium as gym
from _timing import env_kwargs

from agent_envs.envs import ENV_ID


def numpy_step_env(kwargs: dict[str, Any], num_envs: int) -> Any:
    """The native vector env made with the compiled step off (its plan's envelope "numpy"),
    or None where it had no compiled step anyway."""
    from agent_envs import native

    before = native.use("step", False)
    try:
        env = _timing.make_native(kwargs, num_envs)
    finally:
        native.use("step", before)
    return env if env.plan.envelope == "numpy" else None


def batch_rates(b: int, n_paths: int, largest: bool, seconds: float, rounds: int) -> dict:
    """env-steps/s of the native env, the loop, the floor (and Sync, the numpy step)."""
    kwargs = env_kwargs("paper", "serb", n_paths=n_paths)
    native_step = _timing.native_stepper(kwargs, b)
    singles = [_timing.single_env_stepper(kwargs, first_seed=1000 * i) for i in range(b)]
    actions = _timing.batch_actions(b, kwargs["n_agents"])
    fns: dict[str, Callable[[], Any]] = {
        "native": native_step,
        "loop": lambda: [s() for s in singles],
    }
    systems = b * n_paths
    chunk = min(systems, 100)
    floor = _timing.kernel_drift_floor(chunk)
    fns["floor"] = lambda: [floor() for _ in range(max(1, round(systems / chunk)))]
    if largest and n_paths == 1:
        sync = gym.make_vec(ENV_ID, num_envs=b, vectorization_mode="sync", **kwargs)
        sync.reset(seed=0)
        fns["sync"] = lambda: sync.step(actions)
        compiled_step = native_step.env.plan.compiled_step  # type: ignore[attr-defined]
        plain = numpy_step_env(kwargs, b) if compiled_step else None
        if plain is not None:
            fns["numpy_step"] = lambda: plain.step(actions)
    calls = min(_timing.calls_for(fns[name], seconds) for name in ("native", "loop"))
    return {name: b / t for name, t in _timing.interleaved(fns, calls, rounds).items()}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="B = 1, 8; 2 rounds of ~0.05 s")
    parser.add_argument("--batches", type=int, nargs="+", default=None, help="B")
    parser.add_argument("--rounds", type=int, default=None, help="interleaved rounds (medians)")
    parser.add_argument("--seconds", type=float, default=None, help="seconds per block")
    args = parser.parse_args()
    batches = args.batches or ([1, 8] if args.quick else [1, 16, 64])
    rounds = args.rounds or (2 if args.quick else 5)
    seconds = args.seconds or (0.05 if args.quick else 0.3)
    print(f"Native vector env vs B single envs, paper setting, SERB, medians of {rounds} rounds")
    print(f"({_timing.compiled_paths()})\n")
    rows, extra = [], []
    for n_paths in (1, 20):
        for b in batches:
            r = batch_rates(b, n_paths, b == max(batches), seconds, rounds)
            rows.append((n_paths, b, f"{r['native'] / r['loop']:.2f}",
                         f"{100 * r['native'] / r['floor']:.0f} %"))  # fmt: skip
            if "sync" in r:
                ratio = r["native"] / r["sync"]
                extra.append(f"B = {b}, 1 path: native / SyncVectorEnv = {ratio:.2f}")
            if "numpy_step" in r:
                extra.append(
                    f"B = {b}, 1 path: compiled step / numpy step (compiled step off) ="
                    f" {r['native'] / r['numpy_step']:.2f}; numpy step / SyncVectorEnv ="
                    f" {r['numpy_step'] / r['sync']:.2f}"
                )
    _timing.print_table(
        ("paths", "B", "native / loop (env-steps/s)", "kernel + drift share of the native step"),
        rows,
    )
    for line in extra:
        print(line)
    print()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
