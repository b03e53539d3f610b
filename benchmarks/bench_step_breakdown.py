"""Where does an env step's time go, call by call?

Question: of one step of the paper single env (N = 100, m = 50, 20 paths, eps = 0.05, frozen
Jacobian, max_control = 25), SERB and EM, and of one batch step of the native vector env
(B = 64, 1 path, SERB), what share goes to each public call the step makes, and how much is
compiled code (numba) against interpreter and numpy?

Baseline in the same run: the step's own total (the shares are of it). `time.perf_counter`
around each wrapped call (about 0.3 us per call, included), inclusive (a call's time holds the
calls inside it); the compiled calls (`agent_envs.native`'s public entry points) are also
charged to the innermost wrapped call they ran in ("compiled in ..."). Wrapped: the episode
core's `advance_paths`, `mean_interaction_drift`, `diverged_paths` (`agent_envs.simulator`),
the integrator's `step` and `fused_step`, the model's `drift_and_linearization`, `drift` and
`adopt_linearization`, and the native env's `fill_brownian_increments` (where its numpy and
compiled steps call it: `vector_env`, `fast_step`), `mean_running_cost` (`vector_env`),
`advance_paths` and `mean_interaction_drift` (`vector_blocks`). The env's private
per-step helpers (its actions, observation and info arrays) are not wrapped: they are in the
rest. SERB and EM episodes alternate, `--episodes` of each after two warm-up episodes.

    python benchmarks/bench_step_breakdown.py            # 20 episodes each (~30 s)
    python benchmarks/bench_step_breakdown.py --quick    # 3 episodes, 30 batch steps
"""

from __future__ import annotations

import _timing  # isort: skip  (first: pins the BLAS pools before numpy loads)

import argparse
import time
from typing import Any

from _timing import CallTimes, env_kwargs


def wrap_single(times: CallTimes, env: Any) -> None:
    """Time the public calls a single env's step makes."""
    from agent_envs import simulator
    from agent_envs.envs import episode

    times.wrap(episode, "advance_paths", "advance_paths")
    times.wrap(env.episode.integrator, "step", "integrator step")
    if hasattr(env.episode.integrator, "fused_step"):  # (the exponential schemes only)
        times.wrap(env.episode.integrator, "fused_step", "fused step")
    for owner in (episode, simulator):  # (where the step's caller finds it)
        times.wrap(owner, "diverged_paths", "diverged_paths")
    times.wrap(episode, "mean_interaction_drift", "mean drift")
    for name in ("drift_and_linearization", "adopt_linearization", "drift"):
        times.wrap(env.episode.model, name, name)
    _timing.wrap_compiled(times)


def single_env_shares(episodes: int) -> dict[str, dict[str, float]]:
    """Seconds per step of each wrapped call and the step total, SERB and EM alternating."""
    steppers = {k: _timing.single_env_stepper(env_kwargs("paper", k)) for k in ("serb", "em")}
    timers = {k: CallTimes() for k in steppers}
    totals = dict.fromkeys(steppers, 0.0)
    steps = steppers["serb"].env.config.n_steps  # type: ignore[attr-defined]
    for episode in range(episodes + 2):
        for name, step in steppers.items():
            times = timers[name]
            wrap_single(times, step.env)  # type: ignore[attr-defined]
            kept = dict(times.seconds)
            start = time.perf_counter()
            for _ in range(steps):  # (the env resets with the next seed inside the last step)
                step()
            if episode >= 2:
                totals[name] += time.perf_counter() - start
            else:
                kept = {}
            times.restore()
            times.seconds = kept if episode < 2 else times.seconds
    return {
        name: {"total": totals[name], **timers[name].seconds} for name in steppers
    }  # (seconds over `episodes` episodes)


def native_shares(batch: int, batch_steps: int) -> dict[str, float]:
    """Seconds per batch step of each wrapped call of the native vector env."""
    from agent_envs.envs import episode, fast_step, vector_blocks, vector_env

    step = _timing.native_stepper(env_kwargs("paper", "serb", n_paths=1), batch)
    env = step.env  # type: ignore[attr-defined]
    for _ in range(100):
        step()
    times = CallTimes()
    times.wrap(env.integrator, "fused_step", "fused step")
    times.wrap(vector_blocks, "advance_paths", "advance_paths (numpy step)")
    times.wrap(vector_env, "mean_running_cost", "running cost")
    for owner in (vector_env, fast_step):  # (the numpy step's draws, the compiled step's)
        times.wrap(owner, "fill_brownian_increments", "draws")
    for owner in (episode, fast_step):
        times.wrap(owner, "diverged_paths", "diverged_paths")
    for owner in (episode, vector_blocks):
        times.wrap(owner, "mean_interaction_drift", "mean drift")
    _timing.wrap_compiled(times)
    start = time.perf_counter()
    for _ in range(batch_steps):
        step()
    total = time.perf_counter() - start
    times.restore()
    return {"total": total / batch_steps, **{k: v / batch_steps for k, v in times.seconds.items()}}


def print_shares(title: str, columns: dict[str, dict[str, float]]) -> None:
    """One row per wrapped call: its share of each column's total."""
    first = next(iter(columns.values()))
    keys: list[str] = []
    for found in columns.values():
        keys += [k for k in found if k != "total" and k not in keys]
    keys.sort(key=lambda k: -first.get(k, 0.0) / first["total"])
    rows = [
        (
            key,
            *(f"{100 * found.get(key, 0.0) / found['total']:.0f} %" for found in columns.values()),
        )
        for key in keys
    ]
    print(title + "\n")
    _timing.print_table(("call (share of the step)", *columns), rows)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="3 episodes, 30 batch steps")
    parser.add_argument("--episodes", type=int, default=None, help="timed episodes of each")
    args = parser.parse_args()
    episodes = args.episodes or (3 if args.quick else 20)
    print(f"Where a step's time goes ({_timing.compiled_paths()})\n")
    single = single_env_shares(episodes)
    print_shares(
        f"Paper single env, SERB and EM episodes alternating, {episodes} episodes each",
        {"SERB": single["serb"], "EM": single["em"]},
    )
    native = native_shares(64, 30 if args.quick else 300)
    print_shares("Native vector env, B = 64, 1 path, SERB", {"native": native})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
