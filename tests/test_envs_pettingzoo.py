"""PettingZoo env `agent_envs.swarm_v0`: API/seed tests, reward and observation consistency."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from gymnasium.utils.env_checker import data_equivalence
from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test, seed_test
from pettingzoo.test.state_test import state_test

from agent_envs import swarm_v0
from agent_envs.envs import SwarmEnv, SwarmParallelEnv, split_agent_observation, split_observation

SMALL = {"n_agents": 5, "n_steps": 8}


def all_actions(par_env: SwarmParallelEnv, values: np.ndarray) -> dict[str, np.ndarray]:
    """Agent k gets values[k] (shape (d,)), as float32."""
    return {
        agent: np.asarray(values[k], dtype=np.float32).reshape(par_env.params.dim)
        for k, agent in enumerate(par_env.possible_agents)
    }


# --------------------------------------------------------------------- modules
def test_module_exposes_parallel_env_env_and_raw_env():
    par_env = swarm_v0.parallel_env(**SMALL)
    assert isinstance(par_env, SwarmParallelEnv)
    assert par_env.possible_agents == [f"agent_{k}" for k in range(5)]
    for aec in (swarm_v0.env(**SMALL), swarm_v0.raw_env(**SMALL)):
        assert isinstance(aec.unwrapped, SwarmParallelEnv)
        assert aec.possible_agents == par_env.possible_agents
    assert par_env.metadata["name"] == "swarm_v0"


# ------------------------------------------------------------------ PZ checkers
@pytest.mark.parametrize("dim", [1, 2])
def test_parallel_api_test(dim):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        parallel_api_test(swarm_v0.parallel_env(dim=dim, **SMALL), num_cycles=20)


@pytest.mark.parametrize("integrator", ["serb", "em"])
def test_parallel_seed_test(integrator):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        parallel_seed_test(lambda: swarm_v0.parallel_env(integrator=integrator, **SMALL))


def test_aec_api_test():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        api_test(swarm_v0.env(**SMALL), num_cycles=20)


def test_aec_seed_test():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        seed_test(lambda: swarm_v0.env(**SMALL), num_cycles=20)


def test_state_test():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        state_test(swarm_v0.env(**SMALL), swarm_v0.parallel_env(**SMALL), num_cycles=10)


def test_spaces_are_cached_per_agent():
    par_env = swarm_v0.parallel_env(dim=2, **SMALL)
    a0, a1 = par_env.possible_agents[:2]
    assert par_env.observation_space(a0) is par_env.observation_space(a0)
    assert par_env.action_space(a0) is par_env.action_space(a0)
    assert par_env.action_space(a0) is not par_env.action_space(a1)  # seeded independently
    assert par_env.observation_space(a0).shape == (3 * 2 + 1,)
    assert par_env.action_space(a0).shape == (2,)
    assert par_env.action_space(a0).dtype == np.float32
    assert par_env.state_space.shape == (2 * 5 * 2 + 2 + 1,)


# ------------------------------------------------- consistency with the Gym env
@pytest.mark.parametrize(("dim", "n_paths"), [(1, 1), (1, 3), (2, 2)])
def test_agent_rewards_add_up_to_the_gym_reward(dim, n_paths):
    """Same seed, same controls: same states; sum_k r_k = r (Gym); state() = Gym observation."""
    kwargs = {"dim": dim, "n_paths": n_paths, **SMALL}
    gym_env, par_env = SwarmEnv(**kwargs), swarm_v0.parallel_env(**kwargs)
    gym_obs, _ = gym_env.reset(seed=21)
    obs, infos = par_env.reset(seed=21)
    rng = np.random.default_rng(0)
    for _ in range(par_env.n_steps):
        assert data_equivalence(par_env.state(), gym_obs, exact=True)
        parts = split_observation(gym_obs, 5, dim)
        for k, agent in enumerate(par_env.possible_agents):
            own = split_agent_observation(obs[agent], dim)
            np.testing.assert_array_equal(own["position"], parts["positions"][k])
            np.testing.assert_array_equal(own["interaction_drift"], parts["interaction_drift"][k])
            np.testing.assert_array_equal(own["target"], parts["target"])
            assert own["time_fraction"] == parts["time_fraction"]
        values = rng.uniform(-1.2, 1.2, (5, dim)).astype(np.float32)
        gym_obs, reward, terminated, truncated, info = gym_env.step(values.reshape(-1))
        obs, rewards, terms, truncs, infos = par_env.step(all_actions(par_env, values))
        np.testing.assert_array_equal(par_env.positions, info["positions"])
        np.testing.assert_array_equal(par_env.last_control, info["control"])
        assert all(type(r) is float for r in rewards.values())
        assert math.fsum(rewards.values()) == pytest.approx(reward, rel=1e-12)
        costs = [infos[a]["running_cost"] for a in par_env.possible_agents]
        assert np.mean(costs) == pytest.approx(info["running_cost"], rel=1e-12)
        assert set(terms.values()) == {terminated} and set(truncs.values()) == {truncated}
    assert truncated and par_env.agents == []


def test_decentralized_turnpike_equals_the_centralized_one():
    """The baselines' TurnpikeController, acting on each agent's own PettingZoo observation
    (`act`), returns the actions it returns on the Gym observation (`predict`), step after step
    of both envs from the same seed; and both are the cheap control of `eq:cheap_ctr`
    computed here from the true state: u_k = beta (xbar - E x_k) - E[(1/N) sum_l p(x_k, x_l)
    (x_l - x_k)], until the controller switches off at tbar (then u = 0)."""
    from agent_envs.baselines import TurnpikeController
    from agent_envs.dynamics.swarm import SwarmModel

    kwargs = {"n_agents": 8, "n_steps": 10, "n_paths": 2}
    gym_env, par_env = SwarmEnv(**kwargs), swarm_v0.parallel_env(**kwargs)
    gym_obs, _ = gym_env.reset(seed=3)
    obs, _ = par_env.reset(seed=3)
    gym_ctrl, par_ctrl = TurnpikeController(gym_env), TurnpikeController(par_env)
    model, beta = SwarmModel(par_env.params), 12.0
    switched = 0
    for _ in range(10):
        gym_action, _ = gym_ctrl.predict(gym_obs, deterministic=True)
        actions = par_ctrl.act(obs)
        stacked = np.stack([actions[a] for a in par_env.possible_agents])
        np.testing.assert_array_equal(stacked.reshape(-1), gym_action)
        x = par_env.positions  # (n_paths, N, d): the state itself, not the observation
        cheap = beta * (0.7 - x.mean(axis=0)) - model.interaction_drift(x).mean(axis=0)
        want = np.clip(cheap / par_env.max_control, -1, 1).astype(np.float32)
        if np.all(stacked == 0):
            switched += 1  # after tbar
        else:
            np.testing.assert_allclose(stacked, want, rtol=1e-5, atol=1e-6)
        gym_obs, *_ = gym_env.step(gym_action)
        obs, *_ = par_env.step(actions)
        np.testing.assert_array_equal(par_env.positions, gym_env.unwrapped.positions)
    assert 0 < switched < 10  # the control was on, then off (tbar inside the horizon)


# ------------------------------------------------------------- episode end
def test_truncation_ends_every_agent():
    par_env = swarm_v0.parallel_env(**SMALL)
    par_env.reset(seed=0)
    zeros = all_actions(par_env, np.zeros((5, 1)))
    for n in range(SMALL["n_steps"]):
        assert par_env.agents == par_env.possible_agents
        _, _, terms, truncs, infos = par_env.step(zeros)
        last = n == SMALL["n_steps"] - 1
        assert all(t is last for t in truncs.values())
        assert not any(terms.values())
    assert par_env.agents == []
    assert infos["agent_0"]["time"] == pytest.approx(1.0)
    with pytest.raises(RuntimeError, match="reset"):
        par_env.step(zeros)


def test_divergence_terminates_every_agent():
    par_env = swarm_v0.parallel_env(divergence_threshold=2.0, **SMALL)
    obs, _ = par_env.reset(seed=0)
    ones = all_actions(par_env, np.ones((5, 1)))
    while par_env.agents:
        obs, rewards, terms, truncs, infos = par_env.step(ones)
    assert all(terms.values()) and not any(truncs.values())
    assert all(info["diverged"] for info in infos.values())
    assert all(math.isfinite(r) for r in rewards.values())
    assert all(np.all(np.isfinite(o)) for o in obs.values())
    assert np.all(np.isfinite(par_env.state()))


def test_step_dicts_are_fresh_each_step_in_agent_order():
    """The step copies kept dicts of the agents (`_agent_dict`, `_agent_flags`): each step's
    five dicts and the N infos are new objects keyed in agent order, so a caller that edits
    one step's dicts changes neither the next step's nor the env's agents."""
    par_env = swarm_v0.parallel_env(**SMALL)
    par_env.reset(seed=0)
    zeros = all_actions(par_env, np.zeros((5, 1)))
    first = par_env.step(zeros)
    for found in first:
        assert list(found) == par_env.possible_agents
        found["agent_0"] = "edited"
        found["extra"] = None
    infos = par_env.step(zeros)[-1]
    assert len({id(info) for info in infos.values()}) == len(infos)
    second = par_env.step(zeros)
    for found in second:
        assert list(found) == par_env.possible_agents
        assert not isinstance(found["agent_0"], str) and "extra" not in found
    assert type(second[2]["agent_1"]) is bool and type(second[3]["agent_1"]) is bool
    assert list(second[4]["agent_1"]) == ["time", "running_cost", "diverged"]
    assert par_env.agents == par_env.possible_agents


# ---------------------------------------------------------------- bad input
def test_bad_actions_and_kwargs():
    with pytest.raises(ValueError, match="integrator"):
        swarm_v0.parallel_env(integrator="rk45")
    with pytest.raises(ValueError, match="epsilon"):
        swarm_v0.env(epsilon=-1.0)
    par_env = swarm_v0.parallel_env(**SMALL)
    par_env.reset(seed=0)
    actions = all_actions(par_env, np.zeros((5, 1)))
    with pytest.raises(ValueError, match="agent_4"):
        par_env.step({a: v for a, v in actions.items() if a != "agent_4"})
    with pytest.raises(ValueError, match="agent_9"):
        par_env.step({**actions, "agent_9": np.zeros(1, np.float32)})
    with pytest.raises(ValueError, match="agent_2"):
        par_env.step({**actions, "agent_2": np.zeros(3, np.float32)})
    with pytest.raises(ValueError, match="actions"):
        par_env.step({**actions, "agent_1": np.array([np.nan], np.float32)})
    with pytest.raises(ValueError, match="initial_positions"):
        par_env.reset(options={"initial_positions": np.zeros((4, 1))})
    assert par_env.step_index == 0


def test_out_of_range_actions_are_clipped_and_options_apply():
    par_env = swarm_v0.parallel_env(**SMALL)
    x0 = np.linspace(-1, 1, 5)
    obs, _ = par_env.reset(seed=2, options={"initial_positions": x0, "target": 2.3})
    assert split_agent_observation(obs["agent_4"], 1)["position"][0] == pytest.approx(1.0)
    assert split_agent_observation(obs["agent_0"], 1)["target"][0] == pytest.approx(2.3)
    par_env.step(all_actions(par_env, np.full((5, 1), -4.0)))
    np.testing.assert_array_equal(par_env.last_control, -par_env.max_control)


# ------------------------------------------------------------------ rendering
def test_rgb_array_render_two_dimensions():
    par_env = swarm_v0.parallel_env(dim=2, render_mode="rgb_array", **SMALL)
    par_env.reset(seed=0)
    par_env.step(all_actions(par_env, np.zeros((5, 2))))
    frame = par_env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    aec = swarm_v0.env(render_mode="rgb_array", **SMALL)
    aec.reset(seed=0)
    assert aec.render().shape[2] == 3
    aec.close()
    par_env.close()


@pytest.mark.parametrize("dim", [1, 2])
def test_agent_rows_of_the_global_observation_are_the_agents_observations(dim):
    """`agent_observations_from_global` reads the per-agent layout out of the Gymnasium one."""
    from agent_envs.envs.observation import agent_observations_from_global

    par_env = swarm_v0.parallel_env(**SMALL, dim=dim)
    observations, _ = par_env.reset(seed=3)
    for _ in range(2):
        rows = agent_observations_from_global(par_env.state(), SMALL["n_agents"], dim)
        expected = np.stack([observations[a] for a in par_env.agents])
        assert rows.shape == (SMALL["n_agents"], 3 * dim + 1) and rows.dtype == np.float32
        np.testing.assert_array_equal(rows, expected)
        batch = agent_observations_from_global(np.stack([par_env.state()] * 3), 5, dim)
        assert batch.shape == (3, SMALL["n_agents"], 3 * dim + 1)
        observations, *_ = par_env.step(all_actions(par_env, np.full((5, dim), 0.1)))
