"""Third-party clients run the envs unchanged: TorchRL's `GymEnv` and `PettingZooWrapper`.

Needs the optional `clients` extra (``pip install -c constraints.txt -e ".[clients]"``; CI
installs it). `GymEnv` first calls ``gym.make(..., frameskip=1)`` and retries without it only on
Python's standard "unexpected keyword argument" message; `PettingZooWrapper` builds its info
specs from the reset infos, so they need the step infos' keys.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

torchrl = pytest.importorskip(
    "torchrl", reason="TorchRL is in the optional `clients` extra (pip install -e '.[clients]')"
)
from torchrl.envs import GymEnv, PettingZooWrapper  # noqa: E402
from torchrl.envs.utils import check_env_specs  # noqa: E402

from agent_envs import swarm_v0  # noqa: E402
from agent_envs.envs.swarm_env import ENV_ID  # noqa: E402

pytestmark = pytest.mark.slow


def test_torchrl_gym_env_checks_specs_and_rolls_out():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # TorchRL's own deprecation chatter
        env = GymEnv(ENV_ID, n_agents=4, n_steps=5)
    check_env_specs(env, seed=0)
    rollout = env.rollout(5)
    assert rollout.batch_size == (5,)
    reward = rollout["next", "reward"].numpy()
    assert np.all(np.isfinite(reward)) and np.all(reward <= 0.0)
    assert bool(rollout["next", "truncated"][-1])  # the horizon m = n_steps = 5
    env.close()


def test_torchrl_pettingzoo_wrapper_checks_specs_and_rolls_out():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        env = PettingZooWrapper(swarm_v0.parallel_env(n_agents=3, n_steps=4), use_mask=True)
    check_env_specs(env, seed=0)
    rollout = env.rollout(4)
    assert rollout["agent", "observation"].shape == (4, 3, 4)
    info = rollout["next", "agent", "info"]
    assert set(info.keys()) == {"time", "running_cost", "diverged"}
    assert np.all(info["running_cost"].numpy() > 0.0)
    assert np.all(rollout["agent", "info", "running_cost"][0].numpy() == 0.0)  # reset's value
    env.close()
