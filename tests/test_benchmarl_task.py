"""The BenchMARL task (training/learners/benchmarl_task.py) and the group policy's `predict`.

Needs the optional `marl` extra (BenchMARL, TorchRL); skipped without it. The fast tests build
the env as BenchMARL's `Experiment` does and check its specs and kwargs; the slow one trains
MAPPO for a few thousand frames and checks the swarm cost falls on fixed validation seeds.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

pytest.importorskip("benchmarl", reason="BenchMARL is in the optional `marl` extra")
import torch
from tensordict import TensorDict
from torchrl.envs.utils import check_env_specs

from agent_envs import swarm_v0
from agent_envs.training.learners.benchmarl_policy import GroupPolicy
from agent_envs.training.learners.benchmarl_task import (
    DEFAULT_CONFIG_PATH,
    GROUP,
    SwarmTask,
    SwarmTaskClass,
    SwarmTaskConfig,
)
from agent_envs.training.learners.multiagent import evaluate_per_agent

#: the slow test's budget (frames, in batches of 1,000), action scale, and the fall it asks of J
SLOW_FRAMES = 3000
SLOW_MAX_CONTROL = 25.0
SLOW_DECREASE = 0.5


def _task(**config) -> SwarmTaskClass:
    task = SwarmTask.SWARM.get_task()
    task.config.update(config)
    return task


def _env(task: SwarmTaskClass, seed: int = 0):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return task.get_env_fun(num_envs=1, continuous_actions=True, seed=seed, device="cpu")()


def test_default_config_is_the_shipped_yaml_and_the_dataclass():
    task = SwarmTask.SWARM.get_task()
    assert isinstance(task, SwarmTaskClass)
    assert task.config == {f.name: f.default for f in SwarmTaskConfig.__dataclass_fields__.values()}
    assert DEFAULT_CONFIG_PATH.is_file()
    assert task.supports_continuous_actions() and not task.supports_discrete_actions()
    assert SwarmTask.SWARM.env_name() == "agent_envs"


def test_a_config_file_with_an_unknown_key_is_refused(tmp_path):
    path = tmp_path / "task.yaml"
    path.write_text("n_agents: 4\nmax_cycles: 20\n")
    with pytest.raises(TypeError, match="max_cycles"):
        SwarmTask.SWARM.get_from_yaml(str(path))
    path.write_text("n_agents: 4\nn_steps: 7\n")
    assert SwarmTask.SWARM.get_from_yaml(str(path)).config["n_steps"] == 7


@pytest.mark.parametrize(
    ("config", "obs_dim"),
    [
        ({"n_agents": 4, "n_steps": 5}, 4),  # relative: 3 d + 1 (d = 1)
        (
            {"n_agents": 3, "n_steps": 6, "observation": "local", "neighbours": 2},
            6,
        ),  # local: (K+1)(d+1)
        ({"n_agents": 5, "n_steps": 4, "observation": "swarm", "agent_reward": "team"}, 6),
    ],
)
def test_the_env_has_the_task_kwargs_and_passes_torchrl_spec_checks(config, obs_dim):
    task = _task(epsilon=0.5, max_control=7.0, **config)
    env = _env(task)
    check_env_specs(env, seed=0)
    n = config["n_agents"]
    assert task.group_map(env) == {GROUP: [f"agent_{k}" for k in range(n)]}
    assert task.max_steps(env) == config["n_steps"]
    assert task.observation_spec(env)[GROUP, "observation"].shape == (n, obs_dim)
    assert set(task.info_spec(env)[GROUP, "info"].keys()) == {"time", "running_cost", "diverged"}
    action = task.action_spec(env)[GROUP, "action"]
    assert action.shape == (n, 1)
    assert np.all(action.space.low.numpy() == -1.0) and np.all(action.space.high.numpy() == 1.0)
    assert task.state_spec(env) is None and task.action_mask_spec(env) is None
    inner = env._env  # the wrapped swarm_v0 parallel env
    assert isinstance(inner, swarm_v0.SwarmParallelEnv)
    assert inner.config.params.epsilon == 0.5 and inner.config.params.n_agents == n
    assert inner.max_control == 7.0
    assert inner.config.observation == config.get("observation", "relative")
    assert inner.config.agent_reward == config.get("agent_reward", "own")
    rollout = env.rollout(config["n_steps"] + 3, break_when_any_done=True)
    assert rollout.batch_size == (config["n_steps"],)  # max_steps = n_steps
    env.close()


@pytest.mark.parametrize("agent_reward", ["own", "team"])
def test_log_info_gives_the_swarm_cost_of_the_ended_episodes(agent_reward):
    """-sum_k R_k ("own") or -R_k ("team") of the episodes ending in a batch: the swarm cost
    that `evaluate_per_agent` measures for the same actions."""
    n, m = 3, 4
    rng = np.random.default_rng(0)
    actions = rng.uniform(-0.2, 0.2, (m, n, 1))
    kwargs = {"n_agents": n, "n_steps": m, "max_control": 5.0, "agent_reward": agent_reward}

    class Replay:
        step = 0

        def predict(self, obs, state, episode_start, deterministic):
            self.step += 1
            return actions[self.step - 1], None

    expected = evaluate_per_agent(Replay(), {**kwargs, "agent_reward": "own"}, [3]).sum()
    par_env = swarm_v0.parallel_env(**kwargs)
    par_env.reset(seed=3)
    totals = np.zeros((m, n, 1))
    for step in range(m):
        _, rewards, *_ = par_env.step({f"agent_{k}": actions[step, k] for k in range(n)})
        totals[step:] += np.array([rewards[f"agent_{k}"] for k in range(n)])[:, None]
    done = torch.zeros(m, 1, dtype=torch.bool)
    done[-1] = True
    batch = TensorDict(
        {
            ("next", GROUP, "episode_reward"): torch.as_tensor(totals, dtype=torch.float64),
            ("next", "done"): done,
        },
        batch_size=[m],
    )
    logged = _task(**kwargs).log_info(batch)
    assert logged["collection/swarm_cost"] == pytest.approx(expected, rel=1e-9)
    assert _task(**kwargs).log_info(batch[:-1]) == {}  # no episode ends


def test_group_policy_predicts_bounded_actions_per_agent():
    class Module:
        def __call__(self, td):
            obs = td.get((GROUP, "observation"))
            td.set((GROUP, "action"), torch.tanh(obs[:, :1] * 3.0))
            return td

    policy = GroupPolicy(Module())
    actions, state = policy.predict(np.ones((5, 4)))
    assert state is None and actions.shape == (5, 1) and actions.dtype == np.float64
    assert np.allclose(actions, np.tanh(3.0))


@pytest.mark.slow
def test_mappo_with_benchmarl_defaults_lowers_the_swarm_cost(tmp_path):
    """BenchMARL's MAPPO (its default algorithm, model and experiment configs but for the
    budget: three batches of 1,000 frames): the deterministic policy's swarm cost on validation
    seeds falls to under half (measured: 14.5 to 0.62 on seeds 1000-1004; about 25 s alone).

    At max_control = 25 a fresh policy costs about 20x the zero control, and MAPPO's first
    updates cut that (docs/learners/marl-libraries.md, "The action scale"): a fall that a wrong
    reward sign, unit or spec would turn into a rise. At the task's default, 5, a fresh policy
    is already below the zero control and a few thousand frames move J less than its noise.
    """
    from benchmarl.algorithms import MappoConfig
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models.mlp import MlpConfig

    task = _task(max_control=SLOW_MAX_CONTROL)
    config = ExperimentConfig.get_from_yaml()
    config.max_n_frames = SLOW_FRAMES
    config.on_policy_collected_frames_per_batch = 1000
    config.loggers = []
    config.evaluation = False
    config.render = False
    config.create_json = False
    config.save_folder = str(tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        experiment = Experiment(
            task=task,
            algorithm_config=MappoConfig.get_from_yaml(),
            model_config=MlpConfig.get_from_yaml(),
            critic_model_config=MlpConfig.get_from_yaml(),
            seed=0,
            config=config,
        )
        policy = GroupPolicy(experiment.policy)
        seeds = list(range(1000, 1005))  # validation seeds
        before = evaluate_per_agent(policy, task.config, seeds).sum(axis=1)
        experiment.run()
        after = evaluate_per_agent(policy, task.config, seeds).sum(axis=1)
    print(before.mean(), after.mean())
    assert after.mean() < SLOW_DECREASE * before.mean(), (before, after)
