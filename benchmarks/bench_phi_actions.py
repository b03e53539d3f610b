"""Which phi-action strategy makes the SERB env step fastest, and by how much?

Question: the SERB step's phi-action phi_1(tau L) v can run as the fused compiled step (the
phi-action, the update and the next kernel pass in one call: the default with numba), the
compiled Lanczos alone, the numpy Lanczos, or dense `eigh` / `expm` per member. What does each
cost per env step at the paper setting (N = 100, m = 50, 20 paths, eps = 0.05, frozen
Jacobian, max_control = 25)?

Baseline in the same run: the EM env step (no phi-action) of the same setting. Each strategy
is an env made while its compiled paths are switched as it needs (`agent_envs.native.use`:
"fused" off for the compiled Lanczos, "fused" and "lanczos" off for the numpy one;
`phi_method="eigh" | "expm"` for the dense ones) and stepped with those switches set; the row
names the phi-action code the env's plan says ran (`env.plan.phi`) and any fallback it
counted (`env.plan_fallbacks`). Alternating blocks of `--calls` steps, medians of `--rounds`.

    python benchmarks/bench_phi_actions.py            # 5 rounds of 50 steps (~1 min)
    python benchmarks/bench_phi_actions.py --quick    # 2 rounds of 10 steps (seconds)
"""

from __future__ import annotations

import _timing  # isort: skip  (first: pins the BLAS pools before numpy loads)

import argparse
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
from _timing import env_kwargs

#: strategy -> (compiled paths switched off while it is made and stepped, env keywords)
STRATEGIES: dict[str, tuple[tuple[str, ...], dict[str, Any]]] = {
    "fused compiled step": ((), {}),
    "compiled Lanczos": (("fused",), {}),
    "numpy Lanczos": (("fused", "lanczos"), {}),
    "eigh per member": ((), {"phi_method": "eigh"}),
    "expm per member": ((), {"phi_method": "expm"}),
}


@contextmanager
def switched_off(paths: tuple[str, ...]) -> Iterator[None]:
    """The compiled `paths` off (`native.use`) inside the block, as they were after it."""
    from agent_envs import native

    before = {name: native.use(name, False) for name in paths}
    try:
        yield
    finally:
        for name, on in reversed(before.items()):
            native.use(name, on)


def strategy_times(calls: int, rounds: int) -> tuple[dict[str, float], dict[str, str]]:
    """Seconds per env step of each strategy and of EM (medians of alternating blocks), and
    each strategy's plan (phi code, fallbacks)."""
    steppers: dict[str, tuple[tuple[str, ...], Callable[[], None]]] = {
        "EM": ((), _timing.single_env_stepper(env_kwargs("paper", "em")))
    }
    for name, (off, extra) in STRATEGIES.items():
        with switched_off(off):
            steppers[name] = (off, _timing.single_env_stepper(env_kwargs("paper", "serb", **extra)))
    times: dict[str, list[float]] = {name: [] for name in steppers}
    for round_ in range(rounds + 1):  # (the first round warms up)
        for name, (off, step) in steppers.items():
            with switched_off(off):
                start = time.perf_counter()
                for _ in range(calls):
                    step()
                if round_:
                    times[name].append((time.perf_counter() - start) / calls)
    plans = {}
    for name, (_, step) in steppers.items():
        env = step.env  # type: ignore[attr-defined]
        fallbacks = ", ".join(f"{k} x{v}" for k, v in env.plan_fallbacks.items()) or "none"
        plans[name] = f"{env.plan.phi}; fallbacks: {fallbacks}"
    return {name: float(np.median(t)) for name, t in times.items()}, plans


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2 rounds of 10 steps")
    parser.add_argument("--rounds", type=int, default=None, help="alternating rounds (medians)")
    parser.add_argument("--calls", type=int, default=None, help="steps per block")
    args = parser.parse_args()
    rounds = args.rounds or (2 if args.quick else 5)
    calls = args.calls or (10 if args.quick else 50)
    seconds, plans = strategy_times(calls, rounds)
    print(f"SERB env step by phi-action strategy, paper setting, medians of {rounds} rounds")
    print(f"({_timing.compiled_paths()}, outside the switched blocks)\n")
    fastest = seconds["fused compiled step"]
    rows = [
        (
            name,
            plans[name],
            f"{seconds[name] / seconds['EM']:.2f}",
            f"{seconds[name] / fastest:.2f}",
        )
        for name in STRATEGIES
    ]
    _timing.print_table(
        ("strategy", "plan.phi; fallbacks", "step / EM step", "step / fused step"), rows
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
