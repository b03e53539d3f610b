"""One episode of a policy on a swarm env, recorded: `rollout` -> `tables.Episode`.

    env = make_swarm_env("agent_envs/Swarm-v0", {"n_agents": 20})
    episode = rollout(policy, env, seed=10000)

`rollout` records per episode the path-mean positions x^n (shape (m + 1, N, d), NaN after a
divergence), the controls u^n (m, N, d), the running cost and the reward of each step (m,), the
target, and whether and when the episode diverged; `Episode` derives the summary scalars (total
cost = minus the sum of rewards, final distance, Lyapunov value, control energy, saturation).
Used by the evaluations of `agent-envs evaluate` and `compare`, the apg learner's validation and
the paper's turnpike reproduction; it imports only the results' tables and the training layer's
defaults.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

import numpy as np

from agent_envs.training.defaults import GYM_ENV_ID, check_env_id, is_multiagent
from agent_envs.training.results.tables import Episode


def rollout(
    policy: Any,
    env: Any,
    seed: int | None = None,
    reset_options: Mapping[str, Any] | None = None,
    deterministic: bool = True,
) -> Episode:
    """Run one episode of `policy` on a Gymnasium swarm env and record it (see `Episode`).

    The policy is called the way SB3's `evaluate_policy` calls it on a one-env VecEnv: with a
    batch of one observation, the previous `state` and `episode_start`.
    """
    inner = env.unwrapped
    m = int(inner.n_steps)
    start = time.perf_counter()
    obs, _ = env.reset(seed=seed, options=dict(reset_options) if reset_options else None)
    params = inner.params
    n, d = params.n_agents, params.dim
    target = np.asarray(params.target_vector, dtype=float)
    mean_positions = np.full((m + 1, n, d), np.nan)
    mean_positions[0] = np.asarray(inner.positions, dtype=float).mean(axis=0)
    controls = np.zeros((m, n, d))
    running = np.zeros(m)
    rewards = np.zeros(m)
    state = None
    episode_start = np.ones(1, dtype=bool)
    diverged, divergence_step, steps = False, None, 0
    tbar = float("nan")
    for step in range(m):
        action, state = policy.predict(
            np.asarray(obs)[None],
            state=state,
            episode_start=episode_start,
            deterministic=deterministic,
        )
        episode_start[:] = False
        if step == 0:
            tb = getattr(policy, "turnpike_times", None)
            if tb is not None and len(tb):
                tbar = float(tb[0])
        obs, reward, terminated, truncated, info = env.step(np.asarray(action)[0])
        steps = step + 1
        rewards[step] = float(reward)
        controls[step] = np.asarray(info["control"], dtype=float).reshape(n, d)
        running[step] = float(info["running_cost"])
        if info.get("diverged", False):
            diverged, divergence_step = True, step + 1
            break
        mean_positions[step + 1] = np.asarray(info["positions"], dtype=float).mean(axis=0)
        if terminated or truncated:
            break
    return Episode(
        seed=seed,
        times=np.linspace(0.0, params.horizon, m + 1),
        mean_positions=mean_positions,
        controls=controls,
        running_cost=running,
        rewards=rewards,
        target=target,
        dt=float(inner.dt),
        max_control=float(inner.max_control),
        diverged=diverged,
        divergence_step=divergence_step,
        n_steps_run=steps,
        turnpike_time=tbar,
        wall_time=time.perf_counter() - start,
    )


def make_swarm_env(env_id: str, env_kwargs: Mapping[str, Any] | None = None) -> Any:
    """`gym.make(env_id, **env_kwargs)` for a swarm env; ValueError naming the bad input.

    The id must be registered (`check_env_id`) and make an env of this package (one with
    ``unwrapped.params``); an unknown or mistyped keyword is reported as ``--env-kwargs``.
    """
    import gymnasium as gym

    import agent_envs  # noqa: F401  (registers the env ids)

    check_env_id(env_id)
    if is_multiagent(env_id):
        raise ValueError(
            f"--env-id {env_id!r} is the PettingZoo env; policies are evaluated on its Gymnasium "
            f"twin {GYM_ENV_ID!r} (a parameter-shared model acts there agent by agent)"
        )
    try:
        env = gym.make(env_id, **dict(env_kwargs or {}))
    except TypeError as exc:
        # gym.make re-raises the env's TypeError with the kwargs appended; show the env's own
        original = exc.__context__ if isinstance(exc.__context__, TypeError) else exc
        raise ValueError(f"--env-kwargs {dict(env_kwargs or {})}: {original}") from None
    if not hasattr(env.unwrapped, "params"):
        env.close()
        raise ValueError(
            f"--env-id {env_id!r} is not a swarm env (its env has no swarm parameters); "
            f"use {GYM_ENV_ID!r}"
        )
    return env
