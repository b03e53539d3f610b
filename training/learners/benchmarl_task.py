"""A BenchMARL task for `agent_envs.swarm_v0`: MAPPO, IPPO, MASAC ... out of the box.

    from benchmarl.algorithms import MappoConfig
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models.mlp import MlpConfig

    from agent_envs.training.learners.benchmarl_task import SwarmTask

    task = SwarmTask.SWARM.get_task()              # the shipped default (benchmarl_swarm.yaml)
    task.config.update(n_agents=10, n_steps=20)    # any keyword of swarm_v0.parallel_env
    Experiment(task=task, algorithm_config=MappoConfig.get_from_yaml(),
               model_config=MlpConfig.get_from_yaml(),
               critic_model_config=MlpConfig.get_from_yaml(), seed=0,
               config=ExperimentConfig.get_from_yaml()).run()

Needs the `marl` extra (BenchMARL, TorchRL); imported only by `benchmarl_runs` (leaderboard units).
Written as BenchMARL's own task families are (``benchmarl.environments.pettingzoo``): a `Task`
enum (one member, SWARM) whose `TaskClass` builds the env with TorchRL's `PettingZooWrapper`
from the task config, which is the env's keyword arguments (`SwarmTaskConfig`, defaults in
``benchmarl_swarm.yaml`` beside this file).

Specs: one group, "agents" (all N agents, parameter sharing possible), observation
(group, "observation") of shape (N, obs_dim), action (group, "action") in [-1, 1]^(N x d),
u_k = max_control x action_k; info (group, "info") with `time`, `running_cost`, `diverged`;
no global state (MAPPO's critic then reads the N observations). An episode lasts m = n_steps
steps (`max_steps`).

Units: BenchMARL logs per-agent returns averaged over agents. With agent_reward "own" the swarm
cost of an episode is J = -N x ``episode_reward_mean``, with "team" J = -1 x it. `log_info`
logs J itself as ``collection/swarm_cost`` (the sampled episodes of each collected batch), so
no conversion is needed when reading BenchMARL's logs. The `running_cost` info c_k^n has no
tau / N factor: J = sum_n tau/N sum_k c_k^n, tau = T / m.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml
from benchmarl.environments.common import Task, TaskClass
from tensordict import TensorDictBase
from torchrl.data import Composite
from torchrl.envs import EnvBase, PettingZooWrapper

from agent_envs import swarm_v0

#: the task's default config, shipped beside this module
DEFAULT_CONFIG_PATH = Path(__file__).with_name("benchmarl_swarm.yaml")
#: BenchMARL's group of the N agents (its VMAS tasks' name for one shared group)
GROUP = "agents"


@dataclasses.dataclass
class SwarmTaskConfig:
    """The task config: keyword arguments of `swarm_v0.parallel_env` (BenchMARL type-checks a
    task's YAML against such a dataclass). Any other env keyword may be added to
    ``task.config`` after loading (it is passed on unchanged)."""

    n_agents: int = 10
    n_steps: int = 20
    epsilon: float = 0.05
    observation: str = "relative"
    neighbours: int | None = None
    agent_reward: str = "own"
    #: 5, not the env's 150: a fresh policy's controls then cost less than the zero control
    #: (docs/learners/marl-libraries.md, "The action scale"; chosen on validation seeds)
    max_control: float = 5.0


def env_kwargs(config: dict[str, Any]) -> dict[str, Any]:
    """The task config as env keyword arguments: `neighbours` None (no K) left out."""
    return {k: v for k, v in config.items() if not (k == "neighbours" and v is None)}


class SwarmTaskClass(TaskClass):
    """BenchMARL's view of `swarm_v0`: TorchRL's `PettingZooWrapper` around
    ``swarm_v0.parallel_env(**config)``; continuous actions only, no global state."""

    def get_env_fun(
        self,
        num_envs: int,
        continuous_actions: bool,
        seed: int | None,
        device: Any,
    ) -> Callable[[], EnvBase]:
        """A maker of one wrapped env (BenchMARL batches `num_envs` of them in a SerialEnv)."""
        kwargs = env_kwargs(copy.deepcopy(self.config))

        def make() -> EnvBase:
            par_env = swarm_v0.parallel_env(render_mode="rgb_array", **kwargs)
            return PettingZooWrapper(
                par_env,
                group_map={GROUP: list(par_env.possible_agents)},
                categorical_actions=True,
                device=device,
                seed=seed,
                return_state=False,
                use_mask=False,
            )

        return make

    def supports_continuous_actions(self) -> bool:
        return True

    def supports_discrete_actions(self) -> bool:
        return False

    def has_render(self, env: EnvBase) -> bool:
        return True

    def max_steps(self, env: EnvBase) -> int:
        """m = n_steps: every episode is truncated there (or ends earlier on divergence)."""
        return int(self.config.get("n_steps", SwarmTaskConfig.n_steps))

    def group_map(self, env: EnvBase) -> dict[str, list[str]]:
        return env.group_map

    def state_spec(self, env: EnvBase) -> Composite | None:
        return None

    def action_mask_spec(self, env: EnvBase) -> Composite | None:
        return None

    def observation_spec(self, env: EnvBase) -> Composite:
        """The (group, "observation") entry of each group alone."""
        return self._group_entries(env, "observation")

    def info_spec(self, env: EnvBase) -> Composite | None:
        """The (group, "info") entry: `time`, `running_cost`, `diverged`."""
        return self._group_entries(env, "info")

    def action_spec(self, env: EnvBase) -> Composite:
        return env.full_action_spec

    @staticmethod
    def _group_entries(env: EnvBase, key: str) -> Composite:
        spec = env.observation_spec.clone()
        for group in env.group_map:
            for name in list(spec[group].keys()):
                if name != key:
                    del spec[group][name]
        return spec

    def log_info(self, batch: TensorDictBase) -> dict[str, float]:
        """``collection/swarm_cost``: the mean swarm cost J of the episodes that end in `batch`.

        From BenchMARL's per-agent returns (group, "episode_reward"), shape (..., N, 1), at the
        steps where an episode ends: J = -sum_k R_k with agent_reward "own", J = -R_k (the same
        for all k; their mean) with "team". Empty dict when no episode ends in the batch.
        """
        returns = batch.get(("next", GROUP, "episode_reward"), None)
        done = batch.get(("next", "done"), None)
        if returns is None or done is None or not bool(done.any()):
            return {}
        ended = returns[done.squeeze(-1)]  # (episodes, N, 1)
        team = self.config.get("agent_reward", SwarmTaskConfig.agent_reward) == "team"
        per_episode = -(ended.mean(dim=(-2, -1)) if team else ended.sum(dim=(-2, -1)))
        return {"collection/swarm_cost": float(per_episode.mean())}

    @staticmethod
    def env_name() -> str:
        return "agent_envs"


class SwarmTask(Task):
    """BenchMARL's enum of this package's tasks: SWARM, `swarm_v0` (config: `SwarmTaskConfig`)."""

    SWARM = None

    @staticmethod
    def associated_class() -> type[SwarmTaskClass]:
        return SwarmTaskClass

    def get_from_yaml(self, path: str | None = None) -> SwarmTaskClass:
        """The task with its config from `path`, or from the shipped ``benchmarl_swarm.yaml``
        (BenchMARL's own tasks read theirs from its package); keys checked against
        `SwarmTaskConfig` (an unknown key raises TypeError)."""
        text = Path(path or DEFAULT_CONFIG_PATH).read_text()
        loaded = yaml.safe_load(text) or {}
        config = dataclasses.asdict(SwarmTaskConfig(**loaded))
        return self.get_task(config=config)
