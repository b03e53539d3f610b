"""Experiment, measured and not kept: the native vector env's whole step as one compiled call.

The native env's compiled step (`SwarmVectorEnv._step_compiled`) makes four compiled calls per
batch step: the prologue, the Brownian draws, the integrator's fused pass and the epilogue,
with the integrator's fused-step wrapper and the model's bookkeeping in Python between them.
This script composes the same four compiled functions into one numba function and steps a
second env with it, with everything the step needs built in Python around that one call, so
as to measure how much a step with the least interpreter time would gain (issue 18's native /
Sync target). It checks that both envs give the same outputs bit for bit, then times them in
alternating rounds in one process:

- ref/new: the current step's time over the one-call step's (median and quartiles over the
  rounds);
- the interpreter time left around the one call, before it (from the state's checks on) and
  after it, per batch step (medians over single steps).

Paper SERB env (N = 100, m = 50, eps = 0.05, frozen Jacobian, max_control = 25), B envs of
P paths, the "absolute" observation; numba required. It reaches into the env's private
attributes, as a throwaway prototype would: it documents a measurement (docs/benchmarks.md,
"Where the two ratio targets end"), it is not an API.

    OPENBLAS_NUM_THREADS=1 python benchmarks/one_call_step.py [--envs 64] [--paths 1]
"""

from __future__ import annotations

import argparse
import os
import time
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import gymnasium as gym
import numpy as np
from numba import njit

import agent_envs  # noqa: F401  (registers the id)
from agent_envs.dynamics.laplacian import readonly_view
from agent_envs.envs import ENV_ID
from agent_envs.native.lanczos import frozen_advance
from agent_envs.native.lanczos_rule import MAX_CHECK_STEP
from agent_envs.native.noise import fill_standard_normal
from agent_envs.native.step import epilogue, prologue


@njit(error_model="numpy")
def one_call(pro, draw, sigma, noise, advance, epi) -> int:  # type: ignore[no-untyped-def]
    """prologue, draws, noise = sigma dW, fused pass, epilogue; 0, or 1 (a non-finite action:
    nothing drawn) or 2 (a member's Lanczos gave up)."""
    if not prologue(*pro):
        return 1
    fill_standard_normal(*draw)
    dw = draw[5].reshape(-1)
    flat = noise.reshape(-1)
    for i in range(dw.shape[0]):
        flat[i] = sigma * dw[i]
    if frozen_advance(*advance) > 0:
        return 2
    epilogue(*epi)
    return 0


def step_one_call(env: Any, actions: np.ndarray, marks: list[float]) -> Any:
    """One step of the native env `env` (unwrapped) through `one_call`, where the env's own
    compiled step would run (else its own step); `marks` gets the times around the call."""
    model, x = env.model, env._positions
    cached = model.cached_linearization(x)
    if env._autoreset.any() or cached is None or not (env.plan.compiled_step and env.plan.fused):
        return env.step(actions)
    marks.append(time.perf_counter())
    operator, drift = cached
    target = model.fused_relinearization(x)
    if target is None:
        raise RuntimeError("the model's compiled kernel pass does not serve this state")
    p_next, weight, alpha2 = target
    b, (n, d) = env.num_envs, x.shape[-2:]
    members = b * x.shape[1]
    rows = 1 if env.config.action_basis == "common" else n
    controls, costs, rhs = np.empty((b, n, d)), np.empty(b), np.empty(x.shape)
    dw, noise = np.empty(x.shape), np.empty(x.shape)
    out, x_next = np.empty((members, n, d)), np.empty(x.shape)
    s_next, drift_next = np.empty((members, n)), np.empty((members, n, d))
    _, row_sums = operator.parts()
    noise_members = readonly_view(noise.reshape(members, n, d))
    advance = (
        p_next.reshape(members, n, n), readonly_view(row_sums.reshape(members, n)),
        operator.scale * env.dt, readonly_view(rhs.reshape(members, n, d)), 1e-10, 100,
        MAX_CHECK_STEP, operator.peak, out, noise_members, 1.0 / env.dt, x.reshape(members, n, d),
        env.dt, noise_members, float(weight), float(alpha2), x_next.reshape(members, n, d),
        s_next, drift_next,
    )  # fmt: skip
    low, high = env._observation_bounds
    means = np.empty((b, n, d)), np.empty((b, n, d))
    observations = np.empty((b, low.shape[0]), dtype=np.float32)
    diverged = np.empty(b, dtype=np.bool_)
    fractions = (env.step_index + 1) / env.config.n_steps
    epi = (
        readonly_view(x_next), readonly_view(drift_next.reshape(x.shape)),
        env.config.divergence_threshold, env._targets, fractions, low, high, True, *means,
        observations, diverged,
    )  # fmt: skip
    a = np.ascontiguousarray(actions).reshape(b, rows, d)
    params = env.config.params
    pro = (a, env.config.max_control, x, drift, env._targets, params.gamma, controls, costs, rhs)
    h = env._generator_handles()
    draw = (h.states, h.next_uint64, h.next_double, h.sources, env._all_rows, dw.reshape(b, -1),
            float(np.sqrt(env.dt)))  # fmt: skip
    marks.append(time.perf_counter())
    status = one_call(pro, draw, model.sigma, noise, advance, epi)
    marks.append(time.perf_counter())
    if status != 0 or diverged.any():
        raise RuntimeError(f"the experiment covers the common case only (status {status})")
    model.adopt_linearization(x_next, s_next, drift_next)
    env._positions, env._mean_drift = x_next, means[1]
    env.step_index += 1
    truncated = env.step_index >= env.config.n_steps
    info = env._state_info(controls, costs)
    env._autoreset = truncated.copy()
    result = observations, -env.dt * costs, diverged, truncated, info
    marks.append(time.perf_counter())
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", type=int, default=64)
    parser.add_argument("--paths", type=int, default=1)
    parser.add_argument("--rounds", type=int, default=40)
    args = parser.parse_args()
    for name in ("envs", "paths", "rounds"):
        if getattr(args, name) < 1:
            parser.error(f"--{name} must be an integer >= 1, got {getattr(args, name)}")
    kwargs = {"n_agents": 100, "n_steps": 50, "n_paths": args.paths, "epsilon": 0.05,
              "jacobian": "frozen", "max_control": 25.0, "integrator": "serb"}  # fmt: skip
    envs = []
    for _ in range(2):
        env = gym.make_vec(ENV_ID, args.envs, vectorization_mode="vector_entry_point", **kwargs)
        env.reset(seed=0)
        envs.append(env)
    ref, new = envs[0], envs[1].unwrapped
    if not (new.plan.compiled_step and new.plan.fused):
        raise SystemExit("this env takes no compiled fused step here (numba missing?)")
    actions = np.random.default_rng(1).uniform(-0.5, 0.5, (args.envs, 100)).astype(np.float32)
    marks: list[float] = []
    for k in range(120):  # (two episodes and a half: two autoresets, which take env.step)
        want, got = ref.step(actions), step_one_call(new, actions, marks)
        same = all(np.array_equal(w, g) for w, g in zip(want[:4], got[:4], strict=True))
        same &= want[4].keys() == got[4].keys()
        same &= all(np.array_equal(want[4][key], got[4][key]) for key in want[4])
        if not same:
            raise SystemExit(f"the one-call step differs from the env's step at step {k}")
    taken = len(marks) // 4  # (four marks per step through the one call)
    if taken != 118:
        raise SystemExit(f"only {taken} of the 120 steps went through the one call (118 should)")
    print(
        f"B = {args.envs}, {args.paths} path(s): the same outputs bit for bit over 120 steps,"
        f" {taken} of them through the one call"
    )
    ratios, times = [], {"ref": [], "new": []}
    for _ in range(args.rounds):
        for name, fn in (("ref", lambda: ref.step(actions)),
                         ("new", lambda: step_one_call(new, actions, marks))):  # fmt: skip
            start = time.perf_counter()
            for _ in range(25):
                fn()
            times[name].append((time.perf_counter() - start) / 25)
        ratios.append(times["ref"][-1] / times["new"][-1])
    q1, q3 = np.percentile(ratios, [25, 75])
    print(
        f"us per batch step: current {1e6 * np.median(times['ref']):.0f}, one call"
        f" {1e6 * np.median(times['new']):.0f}; current / one call {np.median(ratios):.3f}"
        f" (quartiles {q1:.3f}-{q3:.3f}, {args.rounds} alternating rounds)"
    )
    before, after = [], []
    for _ in range(500):
        marks.clear()
        step_one_call(new, actions, marks)
        if len(marks) == 4:
            before.append(marks[1] - marks[0])
            after.append(marks[3] - marks[2])
    print(
        f"interpreter time around the one call, per batch step: {1e6 * np.median(before):.0f} us"
        f" before it, {1e6 * np.median(after):.0f} us after it (medians)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
