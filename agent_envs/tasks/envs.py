"""The tasks as environments: Gymnasium ids (single and native vector env) and PettingZoo twins.

Every task id is registered with Gymnasium on ``import agent_envs`` (`register_tasks`), with an
`entry_point` (the single env in a `TimeLimit` of the task's m) and a `vector_entry_point` (the
native `SwarmVectorEnv`), like `agent_envs/Swarm-v0`. Keyword arguments given to `gym.make`
are the interface only (`catalog.INTERFACE_KWARGS`); anything the task fixes raises ValueError.
`parallel_env(task_id, ...)` is the task's PettingZoo twin: the same dynamics, cost and draws
per seed, one agent per swarm member.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym

from agent_envs.envs.swarm_env import SwarmEnv
from agent_envs.envs.swarm_parallel import SwarmParallelEnv
from agent_envs.envs.vector_env import SwarmVectorEnv
from agent_envs.tasks.catalog import TASK_LIST, get_task


def make_task_env(task_id: str, **interface: Any) -> SwarmEnv:
    """Entry point of a task id: `agent_envs/Swarm-v0`'s env with the task's kwargs.

    `gym.make` adds the `TimeLimit` of the task's m (registered as its `max_episode_steps`);
    the env also truncates at m itself.

    Args:
        task_id: the task (``agent_envs/Name-vN``).
        **interface: observation, action_basis, render_mode, num_threads (agent_reward is the
            PettingZoo twin's); anything else raises ValueError naming it.
    """
    task = get_task(task_id)
    return SwarmEnv(**task.make_kwargs(interface))


make_task_env.metadata = SwarmEnv.metadata  # type: ignore[attr-defined]


def make_task_vector_env(task_id: str, num_envs: int = 1, **interface: Any) -> SwarmVectorEnv:
    """`vector_entry_point` of a task id: the native vector env with the task's kwargs.

    `gym.make_vec` passes the registered `max_episode_steps` along: it must be the task's m
    (the native env truncates at m itself).
    """
    task = get_task(task_id)
    steps = interface.pop("max_episode_steps", task.n_steps)
    if steps != task.n_steps:
        raise ValueError(
            f"{task.id} fixes its horizon: max_episode_steps must be {task.n_steps}, got {steps!r}"
        )
    return SwarmVectorEnv(num_envs, **task.make_kwargs(interface))


def parallel_env(task_id: str, **interface: Any) -> SwarmParallelEnv:
    """The task's PettingZoo twin (`agent_envs.swarm_v0.parallel_env` with the task's kwargs).

    `interface` may set observation ("absolute", "relative", "swarm", "local" with its
    `neighbours`), agent_reward ("own", "team"), render_mode and num_threads; the dynamics,
    cost and seeds are the task's.
    """
    task = get_task(task_id)
    kwargs = task.make_kwargs(interface)
    kwargs.pop("action_basis", None)  # the PettingZoo env acts per agent
    return SwarmParallelEnv(**kwargs)


def aec_env(task_id: str, **interface: Any) -> Any:
    """The task's PettingZoo AEC env: PettingZoo's `parallel_to_aec` of `parallel_env`."""
    from pettingzoo.utils.conversions import parallel_to_aec

    return parallel_to_aec(parallel_env(task_id, **interface))


def register_tasks() -> None:
    """Register every task id with Gymnasium (idempotent)."""
    for task in TASK_LIST:
        if task.id in gym.registry:
            continue
        gym.register(
            id=task.id,
            entry_point="agent_envs.tasks.envs:make_task_env",
            vector_entry_point="agent_envs.tasks.envs:make_task_vector_env",
            max_episode_steps=task.n_steps,
            kwargs={"task_id": task.id},
        )


__all__ = ["aec_env", "make_task_env", "make_task_vector_env", "parallel_env", "register_tasks"]
