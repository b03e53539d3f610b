"""PettingZoo swarm environment, version 0: one agent per swarm member.

    from agent_envs import swarm_v0
    par_env = swarm_v0.parallel_env(n_agents=10, n_steps=25)   # ParallelEnv
    aec_env = swarm_v0.env(n_agents=10)                          # AEC (standard conversion)

Same keyword arguments as `gymnasium.make("agent_envs/Swarm-v0", ...)`; see
`agent_envs.envs.swarm_parallel.SwarmParallelEnv` for spaces, rewards and episode end.
`raw_env` is the AEC conversion `pettingzoo.utils.parallel_to_aec(parallel_env(...))` (which
enforces the call order); `env` is the same: no out-of-bounds assertion wrapper is added,
because out-of-range actions are clipped by design.
"""

from __future__ import annotations

from typing import Any

from pettingzoo import AECEnv
from pettingzoo.utils.conversions import parallel_to_aec

from agent_envs.envs.swarm_parallel import SwarmParallelEnv

__all__ = ["SwarmParallelEnv", "env", "parallel_env", "raw_env"]


def parallel_env(**kwargs: Any) -> SwarmParallelEnv:
    """The native parallel env: `SwarmParallelEnv(**kwargs)`."""
    return SwarmParallelEnv(**kwargs)


def raw_env(**kwargs: Any) -> AECEnv:
    """The AEC env obtained with PettingZoo's standard `parallel_to_aec` conversion."""
    return parallel_to_aec(parallel_env(**kwargs))


def env(**kwargs: Any) -> AECEnv:
    """The AEC env (agents act in turn; the swarm steps once all have acted)."""
    return raw_env(**kwargs)
