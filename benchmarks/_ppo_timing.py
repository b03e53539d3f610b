"""Shared by the benchmarks that time SB3's PPO end to end on the swarm envs (public names only).

One measurement, `ppo_rates`: build a vector env, `PPO("MlpPolicy", venv, n_steps=...)` with
SB3's other defaults (unless `batch_size` is given), torch on one thread, `model.learn` for a
fixed budget; then step the same vector env alone (fixed actions) for as many steps: the
env's own time in `learn`, the floor an end-to-end speed-up is bounded by.

Vector envs (`VEC_ENVS`), each over `gym.make` keyword arguments `kwargs`:

- "dummy": SB3's `DummyVecEnv` of `n_envs` `Monitor(gym.make("agent_envs/Swarm-v0"))`;
- "native": `NativeVecEnv(n_envs, kwargs)` (`agent_envs.training.learners.native_vec_env`),
  the native vector env behind SB3's VecEnv protocol;
- "supersuit": parameter-shared PPO on the PettingZoo env: one sub-env per agent of
  `n_envs` swarm copies through SuperSuit (`pettingzoo_env_to_vec_env_v1` +
  `concat_vec_envs_v1`), by `agent_envs.training.learners.multiagent.make_shared_vec_env`,
  the builder `agent-envs train` uses. SB3 counts one timestep per agent-step; the rates
  here are swarm env-steps (timesteps / N).

Env-steps: one step of one swarm (N agents), whatever the vector env; budgets and rates count
them.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np


def dummy_vec_env(kwargs: dict[str, Any], n_envs: int) -> Any:
    """SB3's DummyVecEnv of `n_envs` Monitor-wrapped `gym.make` envs."""
    import gymnasium as gym
    from stable_baselines3.common.monitor import Monitor
    from stable_baselines3.common.vec_env import DummyVecEnv

    import agent_envs  # noqa: F401  (registers the id)
    from agent_envs.envs import ENV_ID

    return DummyVecEnv([lambda: Monitor(gym.make(ENV_ID, **kwargs)) for _ in range(n_envs)])


def native_vec_env(kwargs: dict[str, Any], n_envs: int) -> Any:
    """The native vector env of `n_envs` envs behind SB3's VecEnv protocol."""
    try:
        from agent_envs.training.learners.native_vec_env import NativeVecEnv
    except ImportError:  # (an A/B baseline from before the training rooms, issue 39)
        from agent_envs.training.native_vec_env import NativeVecEnv  # type: ignore[no-redef]

    return NativeVecEnv(n_envs, kwargs)


def supersuit_vec_env(kwargs: dict[str, Any], n_envs: int) -> Any:
    """One SB3 sub-env per agent of `n_envs` PettingZoo swarms, through SuperSuit."""
    try:
        from agent_envs.training.learners.multiagent import make_shared_vec_env
    except ImportError:  # (an A/B baseline from before the training rooms, issue 39)
        from agent_envs.training.multiagent import make_shared_vec_env  # type: ignore[no-redef]

    return make_shared_vec_env(kwargs, n_copies=n_envs)


#: vector env name -> its builder (kwargs, n_envs)
VEC_ENVS: dict[str, Callable[[dict[str, Any], int], Any]] = {
    "dummy": dummy_vec_env,
    "native": native_vec_env,
    "supersuit": supersuit_vec_env,
}


def step_alone(venv: Any, calls: int) -> float:
    """Seconds of `calls` `venv.step` calls with fixed actions (uniform in [-0.5, 0.5],
    default_rng(1)); SB3's vector envs reset their ended envs themselves."""
    shape = (venv.num_envs, *venv.action_space.shape)
    actions = np.random.default_rng(1).uniform(-0.5, 0.5, shape).astype(np.float32)
    venv.reset()
    start = time.perf_counter()
    for _ in range(calls):
        venv.step(actions)
    return time.perf_counter() - start


def ppo_rates(
    vec_env: str,
    kwargs: dict[str, Any],
    n_envs: int,
    n_steps: int,
    env_steps: int,
    batch_size: int | None = None,
) -> dict[str, float]:
    """PPO end to end on `VEC_ENVS[vec_env]`: swarm env-steps per second of `model.learn` for a
    budget of `env_steps` swarm env-steps ("learn"), and of the same vector env stepped alone
    for the steps `learn` took ("alone"), torch on one thread.

    `n_steps` is SB3's rollout length per sub-env; `batch_size` (SB3's 64 when None) the
    minibatch. A SuperSuit vector env has N sub-envs per swarm, so its SB3 budget is
    `env_steps` * N timesteps.
    """
    import torch
    from stable_baselines3 import PPO

    torch.set_num_threads(1)
    venv = VEC_ENVS[vec_env](kwargs, n_envs)
    per_swarm = venv.num_envs // n_envs  # sub-envs per swarm: N for SuperSuit, else 1
    extra = {} if batch_size is None else {"batch_size": batch_size}
    model = PPO("MlpPolicy", venv, n_steps=n_steps, seed=0, device="cpu", verbose=0, **extra)
    start = time.perf_counter()
    model.learn(total_timesteps=env_steps * per_swarm)
    learn = time.perf_counter() - start
    done = model.num_timesteps / per_swarm
    calls = int(model.num_timesteps // venv.num_envs)
    alone = step_alone(venv, calls)
    venv.close()
    return {"learn": done / learn, "alone": calls * n_envs / alone, "env_steps": done}
