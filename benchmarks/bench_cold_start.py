"""How much slower are an env's first steps in a fresh process than the same steps warm?

Question: a user who makes `agent_envs/Swarm-v0` in a new process and steps it at once: how
do the first steps compare with the same steps once the process is warm, and what does the
process pay before its first step (import, make, reset)?

Baseline in the same run: the warm steps of the same process. **cold** = the first
`--steps` (100) steps of a fresh process (env made and reset first; resets with seed 0, 1, ...
at each episode end, inside the timing); **warm** = the same steps (same seeds) again in that
process, the median of `--rounds` rounds; the figure is cold/warm, the median over `--rounds`
fresh processes (100 quick steps take ~10 ms, so one preemption moves a single process's ratio
by 10-40 %). Settings (`_timing.SETTINGS`): paper = N 100, m 50, 20 paths; quick = N 10, m 20,
20 paths; SERB and EM. The last column is the fresh process's one-time cost before its first
step in seconds (with numba: importing it and loading the compiled code from numba's cache;
compiling it instead, a few seconds, the first time in a cache directory): an absolute time on
this host, shown only beside the ratio.

    python benchmarks/bench_cold_start.py            # both settings, 5 processes each
    python benchmarks/bench_cold_start.py --quick    # quick setting, 2 processes (~30 s)
    python benchmarks/bench_cold_start.py --python OTHER/.venv/bin/python   # another checkout
"""

from __future__ import annotations

import _timing  # isort: skip  (first: pins the BLAS pools before numpy loads)

import argparse
import time

import numpy as np
from _timing import SETTINGS, env_kwargs, single_env_stepper


def worker_cold(setting: str, integrator: str, steps: int, rounds: int) -> dict[str, float]:
    """Seconds per step of this fresh process's first `steps` steps ("cold"), of the same steps
    again (median of `rounds`, "warm"), and to import, make and reset ("setup")."""
    start = time.perf_counter()
    step = single_env_stepper(env_kwargs(setting, integrator))
    setup = time.perf_counter() - start

    def block() -> float:
        start = time.perf_counter()
        for _ in range(steps):
            step()
        return (time.perf_counter() - start) / steps

    cold = block()
    warm = []
    for _ in range(rounds):
        step.restart()  # type: ignore[attr-defined]
        warm.append(block())
    return {"cold": cold, "warm": float(np.median(warm)), "setup": setup}


WORKERS = {"cold": worker_cold}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="quick setting, 2 processes")
    parser.add_argument("--rounds", type=int, default=None, help="processes and warm rounds")
    parser.add_argument("--steps", type=int, default=100, help="steps per block")
    parser.add_argument("--python", default=None, help="run the processes with this interpreter")
    _timing.add_worker_arguments(parser, WORKERS)
    args = parser.parse_args()
    if _timing.serve_worker(args, WORKERS):
        return 0
    rounds = args.rounds or (2 if args.quick else 5)
    settings = ["quick"] if args.quick else list(SETTINGS)
    print(f"Cold vs warm env steps, one BLAS thread, medians of {rounds} fresh processes\n")
    rows, per_run = [], {"steps": args.steps, "rounds": rounds}
    for setting in settings:
        for integrator in ("serb", "em"):
            runs = [
                _timing.run_fresh(
                    __file__, "cold", args.python, setting=setting, integrator=integrator, **per_run
                )
                for _ in range(rounds)
            ]
            ratio = float(np.median([run["cold"] / run["warm"] for run in runs]))
            setup = float(np.median([run["setup"] for run in runs]))
            rows.append((setting, integrator, f"{ratio:.2f}", f"{setup:.2f}"))
    _timing.print_table(
        ("setting", "integrator", f"cold/warm (first {args.steps} steps)",
         "import + make + reset (s, this host)"),
        rows,
    )  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
