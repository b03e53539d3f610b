"""Gymnasium and PettingZoo environments of the controlled swarm.

- `SwarmEnv` (`gymnasium.make("agent_envs/Swarm-v0", **kwargs)`): one controller, action
  (N d,), reward -tau c(x^n, u^n).
- `SwarmVectorEnv` (`gymnasium.make_vec("agent_envs/Swarm-v0", num_envs=B,
  vectorization_mode="vector_entry_point", **kwargs)`): B Gymnasium envs stepped as one batch.
- `SwarmParallelEnv` (`agent_envs.swarm_v0.parallel_env(**kwargs)`): one agent per swarm
  member, per-agent rewards adding up to the Gymnasium reward.

Both adapt `agent_envs.envs.episode.SwarmEpisode`. `register_envs()` registers the Gymnasium
id; `import agent_envs` calls it.
"""

from __future__ import annotations

import gymnasium as gym

from agent_envs.envs.episode import SwarmEpisode
from agent_envs.envs.episode_config import EpisodeConfig
from agent_envs.envs.observation import split_agent_observation, split_observation
from agent_envs.envs.swarm_env import ENV_ID, SwarmEnv, make_swarm_env
from agent_envs.envs.swarm_parallel import SwarmParallelEnv
from agent_envs.envs.vector_env import SwarmVectorEnv, make_swarm_vector_env
from agent_envs.simulator import DEFAULT_MAX_CONTROL


def register_envs() -> None:
    """Register `agent_envs/Swarm-v0` (idempotent).

    No `max_episode_steps` is registered: the entry point `make_swarm_env` wraps the env in a
    `TimeLimit` of its own `n_steps`, so any m works and `env.spec.max_episode_steps == m`.
    """
    if ENV_ID in gym.registry:
        return
    gym.register(
        id=ENV_ID,
        entry_point="agent_envs.envs.swarm_env:make_swarm_env",
        vector_entry_point="agent_envs.envs.vector_env:make_swarm_vector_env",
    )


__all__ = [
    "DEFAULT_MAX_CONTROL",
    "ENV_ID",
    "EpisodeConfig",
    "SwarmEnv",
    "SwarmEpisode",
    "SwarmParallelEnv",
    "SwarmVectorEnv",
    "make_swarm_env",
    "make_swarm_vector_env",
    "register_envs",
    "split_agent_observation",
    "split_observation",
]
