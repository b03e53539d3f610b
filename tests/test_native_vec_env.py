"""The SB3 adapter over the native vector env (`agent_envs.training.learners.native_vec_env`)
against SB3's DummyVecEnv: same observations, rewards, dones and infos; PPO learns the same
parameters.

Skipped without the `train` extra (stable-baselines3); the vector env's own tests are in
tests/test_vector_env.py and run without it.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_vector_env import DIVERGING, actions  # the same scenario as the vector env tests

import agent_envs  # noqa: F401  (registers agent_envs/Swarm-v0)
from agent_envs.envs import ENV_ID

sb3 = pytest.importorskip("stable_baselines3")


def dummy_and_native(n_envs: int, seed: int, horizon_as_termination: bool, **kwargs):
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv

    from agent_envs.training.learners.native_vec_env import NativeVecEnv
    from agent_envs.training.learners.wrappers import HorizonAsTermination

    dummy = make_vec_env(
        ENV_ID,
        n_envs=n_envs,
        seed=seed,
        env_kwargs=kwargs,
        vec_env_cls=DummyVecEnv,
        wrapper_class=HorizonAsTermination if horizon_as_termination else None,
    )
    adapter = NativeVecEnv(n_envs, kwargs, horizon_as_termination=horizon_as_termination)
    adapter.seed(seed)
    return dummy, adapter


@pytest.mark.parametrize("horizon_as_termination", [False, True])
def test_sb3_adapter_matches_dummy_vec_env(horizon_as_termination):
    dummy, adapter = dummy_and_native(3, 7, horizon_as_termination, n_agents=10, **DIVERGING)
    np.testing.assert_array_equal(adapter.reset(), dummy.reset())
    rng = np.random.default_rng(1)
    n_done = 0
    for _ in range(300):
        a = actions(rng, 3, 10)
        dummy.step_async(a)
        adapter.step_async(a)
        out_d, out_a = dummy.step_wait(), adapter.step_wait()
        for got, want in zip(out_a[:3], out_d[:3], strict=True):
            np.testing.assert_array_equal(got, want)
            assert got.dtype == want.dtype
        for got, want in zip(out_a[3], out_d[3], strict=True):
            assert set(got) == set(want)
            for key, value in want.items():
                if key == "episode":
                    assert (got[key]["r"], got[key]["l"]) == (value["r"], value["l"])
                else:
                    np.testing.assert_array_equal(got[key], value, err_msg=key)
        for got, want in zip(adapter.reset_infos, dummy.reset_infos, strict=True):
            assert set(got) == set(want)
            for key, value in want.items():
                np.testing.assert_array_equal(got[key], value, err_msg=key)
        n_done += int(out_d[2].sum())
    assert n_done >= 60
    assert adapter.get_attr("n_steps") == dummy.get_attr("n_steps")
    assert adapter.get_attr("step_index") == dummy.get_attr("step_index")
    assert adapter.get_attr("max_control", indices=[0]) == [10.0]
    # env_method calls the native env's method once per index (the module's contract): three
    # batched resets with seed 0, each the reset a fresh native env gives for seed 0
    results = adapter.env_method("reset", seed=0)
    assert len(results) == 3
    fresh_obs, _ = adapter.venv.reset(seed=0)
    for obs, info in results:
        np.testing.assert_array_equal(obs, fresh_obs)
        assert set(info) >= {"positions"}
    assert len(adapter.env_method("reset", seed=0, indices=[1])) == 1
    assert adapter.env_is_wrapped(sb3.common.monitor.Monitor) == [True] * 3
    with pytest.raises(AttributeError):
        adapter.get_attr("no_such_attribute")


def _ppo_parameters(venv) -> dict[str, np.ndarray]:
    from stable_baselines3 import PPO

    model = PPO(
        "MlpPolicy",
        venv,
        n_steps=32,
        batch_size=32,
        n_epochs=2,
        seed=3,
        device="cpu",
        policy_kwargs={"net_arch": [16]},
    )
    model.learn(total_timesteps=192)
    return {k: v.detach().numpy().copy() for k, v in model.policy.state_dict().items()}


@pytest.mark.slow
def test_ppo_learns_the_same_parameters_on_native_and_dummy():
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        dummy, adapter = dummy_and_native(2, 0, True, n_agents=10, **DIVERGING)
        from_dummy = _ppo_parameters(dummy)
        from_native = _ppo_parameters(adapter)
    finally:
        torch.set_num_threads(threads)
    assert from_dummy.keys() == from_native.keys()
    for key, value in from_dummy.items():
        np.testing.assert_array_equal(from_native[key], value, err_msg=key)
