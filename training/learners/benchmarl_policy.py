"""A BenchMARL (TorchRL) group policy as a per-agent `predict`, to score it on `swarm_v0`.

    from agent_envs.training.learners.benchmarl_policy import GroupPolicy
    from agent_envs.training.learners.multiagent import evaluate_per_agent

    policy = GroupPolicy(experiment.policy)            # a trained BenchMARL Experiment's
    costs = evaluate_per_agent(policy, env_kwargs, seeds=range(1000, 1010))  # (seeds, N)
    swarm_cost = costs.sum(axis=1)                    # J per seed

`predict` maps the live agents' observations (M, obs_dim) to actions (M, d) in [-1, 1] the way
`evaluate_per_agent` calls an SB3 model, so a BenchMARL policy is scored by the same code, on
the same seeds, as the parameter-shared SB3 learner. ``scale`` s multiplies the actions: a policy
trained on an env with max_control = M s acts on one with max_control = M through
u_k = M (s a_k) = (M s) a_k, the same controls (bit for bit when s is a power of two). Needs
torch and tensordict (the `marl` extra); imported by `benchmarl_runs` only.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

#: the group the BenchMARL task puts the N agents in (benchmarl_task.GROUP)
DEFAULT_GROUP = "agents"


class GroupPolicy:
    """`predict(obs, state, episode_start, deterministic)` -> (actions, None) over a TorchRL
    module that reads (group, "observation"), shape (M, obs_dim), and writes (group, "action"),
    shape (M, d). deterministic=True runs it in TorchRL's DETERMINISTIC exploration mode
    (BenchMARL's evaluation default; for its TanhNormal policies tanh(loc), not the mean action),
    False samples (from torch's global generator: seed it for repeatable costs). ``sample=True``
    samples whatever `predict` is asked (`evaluate_per_agent` asks for deterministic actions).
    ``scale`` s in (0, 1] multiplies every action (the module's a in [-1, 1] becomes s a)."""

    def __init__(
        self, module: Any, group: str = DEFAULT_GROUP, sample: bool = False, scale: float = 1.0
    ) -> None:
        if not 0.0 < scale <= 1.0:
            raise ValueError(f"scale must be in (0, 1], got {scale!r}")
        self.module = module
        self.group = group
        self.sample = sample
        self.scale = float(scale)

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, None]:
        obs = torch.as_tensor(np.asarray(observation, dtype=np.float32))
        td = TensorDict({(self.group, "observation"): obs}, batch_size=[])
        random = self.sample or not deterministic
        mode = ExplorationType.RANDOM if random else ExplorationType.DETERMINISTIC
        with torch.no_grad(), set_exploration_type(mode):
            out = self.module(td)
        actions = out.get((self.group, "action")).numpy().astype(np.float64)
        return (actions if self.scale == 1.0 else self.scale * actions), None
