"""Parameter-shared training on the PettingZoo swarm env through SuperSuit.

Every swarm member is one agent of `agent_envs.swarm_v0`; SuperSuit turns the parallel env into
a vector env with one sub-env per agent (`pettingzoo_env_to_vec_env_v1`) and stacks copies of
the swarm (`concat_vec_envs_v1(..., base_class="stable_baselines3")`). A single SB3 policy then
acts for every agent from its own observation ``[x_k | drift_k | target | t/T]``: parameter
sharing, decentralized execution. SB3 counts one timestep per agent-step.

Evaluation: the trained shared policy runs on the Gymnasium env through
`agent_envs.training.learners.policies.PerAgentPolicy` (same seeds, same cost units as every other
policy), and `evaluate_per_agent` runs it on the PettingZoo env itself to report each agent's
cost (the agents' costs add up to the swarm's cost).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecMonitor

from agent_envs.training.defaults import PETTINGZOO_ENV_ID


def parallel_env(env_kwargs: dict[str, Any] | None = None):
    """The PettingZoo parallel swarm env (`agent_envs.swarm_v0.parallel_env`)."""
    import importlib

    module = importlib.import_module(PETTINGZOO_ENV_ID)
    return module.parallel_env(**(env_kwargs or {}))


def _seedable_wrapper_class():
    from supersuit.vector.sb3_vector_wrapper import SB3VecEnvWrapper

    class SeedableSB3VecEnv(SB3VecEnvWrapper):
        """SuperSuit's SB3 wrapper with SB3's seeding convention.

        SB3 seeds a VecEnv with ``venv.seed(seed)`` and expects the seed to be used at the
        next ``reset()`` (SB3 >= 2.0). SuperSuit's wrapper forwards ``seed`` to the Gymnasium
        vector env, which has no such method in Gymnasium 1.x; here the seed is kept and passed
        to the next reset (SuperSuit then resets swarm copy i with ``seed + i``).
        """

        def __init__(self, venv: Any) -> None:
            super().__init__(venv)
            self._pending_seed: int | None = None

        def seed(self, seed: int | None = None) -> list[int | None]:
            self._pending_seed = None if seed is None else int(seed)
            return [seed] * self.num_envs

        def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
            # SB3's VecEnv asks every sub-env for render_mode; the PettingZoo env's is shared
            if attr_name == "render_mode":
                return [self.render_mode] * self.num_envs
            return super().get_attr(attr_name, indices)

        def reset(self, seed: int | None = None, options: dict | None = None):
            if seed is None:
                seed, self._pending_seed = self._pending_seed, None
            observations, self.reset_infos = self.venv.reset(seed=seed, options=options)
            return observations

    return SeedableSB3VecEnv


def make_shared_vec_env(
    env_kwargs: dict[str, Any] | None, n_copies: int = 1, num_cpus: int = 0
) -> VecEnv:
    """SB3 VecEnv with one sub-env per agent of `n_copies` swarms (VecMonitor-wrapped).

    `num_cpus` > 0 steps the copies in worker processes (SuperSuit >= 3.11 is needed for more
    than one; 0 keeps everything in this process, the right choice on 2 cores).
    """
    import supersuit as ss

    env = parallel_env(env_kwargs)
    vec = ss.pettingzoo_env_to_vec_env_v1(env)
    vec = ss.concat_vec_envs_v1(vec, n_copies, num_cpus=num_cpus, base_class="stable_baselines3")
    # concat_vec_envs_v1 returns SuperSuit's SB3VecEnvWrapper around the Gymnasium vector env;
    # re-wrap that vector env with the seeding fix.
    return VecMonitor(_seedable_wrapper_class()(vec.venv))


def evaluate_per_agent(
    policy: Any, env_kwargs: dict[str, Any] | None, seeds: Sequence[int]
) -> np.ndarray:
    """Each agent's cost on the PettingZoo env: array (len(seeds), N).

    `policy` is the per-agent policy (a model, or one behind its frozen VecNormalize statistics):
    its `predict` maps a batch of per-agent observations (M, 3d + 1) to controls (M, d). The
    cost of agent k is minus its summed reward ``-tau/N sum_n (|x_k - xbar|^2 + gamma |u_k|^2)``;
    summing over agents gives the swarm's cost on that seed.
    """
    env = parallel_env(env_kwargs)
    try:
        agents = list(env.possible_agents)
        costs = np.zeros((len(seeds), len(agents)))
        for row, seed in enumerate(seeds):
            observations, _ = env.reset(seed=int(seed))
            while env.agents:
                live = [a for a in agents if a in observations]
                stacked = np.stack([observations[a] for a in live])
                controls, _ = policy.predict(stacked, None, None, True)
                controls = np.asarray(controls).reshape(len(live), -1)
                actions = {a: controls[i] for i, a in enumerate(live)}
                observations, rewards, _, _, _ = env.step(actions)
                for i, agent in enumerate(agents):
                    costs[row, i] -= float(rewards.get(agent, 0.0))
        return costs
    finally:
        env.close()
