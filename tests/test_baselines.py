"""Turnpike controller and baselines: formulas, tbar pins, SB3/VecEnv/PettingZoo behaviour."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import agent_envs  # noqa: F401  (registers the env id)
from agent_envs.baselines import (
    CheapClosedLoopModel,
    ProportionalController,
    TurnpikeController,
    ZeroController,
    cheap_control,
    cheap_control_from_model,
    make_baseline,
    turnpike_time,
)
from agent_envs.draws import uniform_positions
from agent_envs.dynamics.swarm import SwarmModel
from agent_envs.envs.observation import split_observation
from agent_envs.params import SwarmParams

ENV_ID = "agent_envs/Swarm-v0"
#: the paper's tbar (Section 5.2) for N = 100 uniform on [-1, 1], beta = 12, delta = 2e-4
PAPER_TBAR = {0.7: 0.54, -1.7: 0.60, 2.3: 0.62}


def small_env(**kw):
    kwargs = {"n_agents": 6, "n_steps": 8, "n_paths": 3, **kw}
    return gym.make(ENV_ID, **kwargs)


# ------------------------------------------------------------------------------------------
# eq:tptime
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("target", sorted(PAPER_TBAR))
def test_turnpike_time_paper_values_evenly_spaced(target):
    x0 = np.linspace(-1.0, 1.0, 100)
    tbar = turnpike_time(x0, target, beta=12.0, delta=2e-4)
    assert round(tbar, 2) == PAPER_TBAR[target]


@pytest.mark.parametrize("target", sorted(PAPER_TBAR))
def test_turnpike_time_paper_values_seeded_uniform(target):
    draws = [uniform_positions(np.random.default_rng(s), 100, 1) for s in range(50)]
    tbars = np.array([turnpike_time(x, target, 12.0, 2e-4) for x in draws])
    assert round(float(tbars.mean()), 2) == PAPER_TBAR[target]
    assert np.all(np.abs(tbars - PAPER_TBAR[target]) < 0.015)


def test_turnpike_time_from_env_reset_seed0():
    # The env's seeded start (seed 0) is the uniform draw of default_rng(0): pinned values.
    env = gym.make(ENV_ID)
    env.reset(seed=0)
    x0 = env.unwrapped.positions.mean(axis=0)
    got = [turnpike_time(x0, t) for t in (0.7, -1.7, 2.3)]
    np.testing.assert_allclose(got, [0.5337, 0.6001, 0.6156], atol=1e-4)


def test_turnpike_time_formula_clamps_and_batch():
    x0 = np.array([[0.0], [1.0]])  # ||x0 - 0.5||^2 = 0.5
    expected = np.log(1e-3 / 0.5) / (-2 * 3.0)
    assert turnpike_time(x0, 0.5, beta=3.0, delta=1e-3) == pytest.approx(expected)
    assert turnpike_time(x0, 0.5, beta=3.0, delta=1e-3, horizon=0.5) == 0.5
    assert turnpike_time(np.full((2, 1), 0.5), 0.5) == 0.0  # at the target: no cheap phase
    assert turnpike_time(x0, 0.5, beta=3.0, delta=1.0) == 0.0  # already within delta
    batch = np.stack([x0, x0 + 1.0])
    out = turnpike_time(batch, 0.5, beta=3.0, delta=1e-3)
    assert out.shape == (2,) and out[0] == pytest.approx(expected)
    with pytest.raises(ValueError, match="beta"):
        turnpike_time(x0, 0.5, beta=0.0)


# ------------------------------------------------------------------------------------------
# eq:cheap_ctr on a hand-computed example
# ------------------------------------------------------------------------------------------


def test_cheap_control_hand_computed():
    # N = 3, d = 1, p(x, y) = 1/(eps (alpha^2 + |x-y|^2)) with eps = 0.5, alpha = 1:
    # p = 2/(1 + r^2); x = (0, 1, 3):
    #   drift_0 = (1/3)(1 * 1 + 0.2 * 3)   =  1.6/3
    #   drift_1 = (1/3)(1 * -1 + 0.4 * 2)  = -0.2/3
    #   drift_2 = (1/3)(0.2 * -3 + 0.4 * -2) = -1.4/3
    # beta = 2, xbar = 1: u = 2 (1 - x) - drift
    params = SwarmParams(n_agents=3, epsilon=0.5, alpha=1.0, target=1.0)
    model = SwarmModel(params)
    x = np.array([0.0, 1.0, 3.0])[:, None]
    drift = np.array([1.6, -0.2, -1.4])[:, None] / 3
    np.testing.assert_allclose(model.interaction_drift(x), drift, rtol=1e-12)
    expected = np.array([2.0 - 1.6 / 3, 0.2 / 3, -4.0 + 1.4 / 3])[:, None]
    np.testing.assert_allclose(cheap_control(x, drift, np.array([1.0]), 2.0), expected)
    np.testing.assert_allclose(cheap_control_from_model(model, x[None], [1.0], 2.0), expected)
    # proportional: no cancellation
    np.testing.assert_allclose(
        cheap_control(x, drift, np.array([1.0]), 2.0, cancel_interaction=False), 2 * (1 - x)
    )


def test_cheap_control_mean_over_paths():
    params = SwarmParams(n_agents=4, epsilon=0.1)
    model = SwarmModel(params)
    x = np.random.default_rng(0).uniform(-1, 1, (5, 4, 1))  # 5 paths
    u = cheap_control_from_model(model, x, [0.7], 12.0)
    per_path = 12.0 * (0.7 - x) - model.interaction_drift(x)
    np.testing.assert_allclose(u, per_path.mean(axis=0))


def test_closed_loop_model_mean_is_eq_expint_mean():
    # SERB on the closed loop: the path mean follows eq:expint_mean (exact exp(-beta tau) decay).
    from agent_envs.integrators import make_integrator

    params = SwarmParams(n_agents=5, epsilon=0.05, sigma=0.01, target=0.7)
    model = CheapClosedLoopModel(SwarmModel(params), [0.7], beta=12.0)
    x = np.broadcast_to(np.linspace(-1, 1, 5)[:, None], (4, 5, 1)).copy()
    dw = np.random.default_rng(1).standard_normal(x.shape) * np.sqrt(0.02)
    dw -= dw.mean(axis=0)  # zero-mean noise so the mean is deterministic
    x1 = make_integrator("serb").step(model, x, None, 0.0, 0.02, dw)
    np.testing.assert_allclose(
        x1.mean(0) - 0.7, np.exp(-12.0 * 0.02) * (x.mean(0) - 0.7), atol=1e-12
    )


# ------------------------------------------------------------------------------------------
# The controller on the Gymnasium env
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("kernel", ["symmetric", "nonsymmetric"])
def test_controller_action_matches_formula_with_env_model(kernel):
    env = small_env(kernel=kernel, target=0.4)
    obs, _ = env.reset(seed=3)
    ctrl = TurnpikeController(env)
    inner = env.unwrapped
    action, state = ctrl.predict(obs)
    assert action.shape == (6,) and action.dtype == np.float32
    u = 12.0 * (0.4 - inner.positions.mean(0)) - inner.model.interaction_drift(
        inner.positions
    ).mean(0)
    np.testing.assert_allclose(action, (u / inner.max_control).ravel(), rtol=1e-5, atol=1e-6)
    tbar = turnpike_time(inner.positions.mean(0), 0.4, horizon=1.0)
    assert state[0][0] == pytest.approx(tbar, abs=1e-5)


def test_controller_switches_off_after_tbar():
    env = small_env(n_steps=10)
    obs, _ = env.reset(seed=0)
    ctrl = TurnpikeController(env, turnpike_time=0.35)  # fixed tbar: steps 0..3 cheap
    actions, state = [], None
    for _ in range(10):
        a, state = ctrl.predict(obs, state)
        actions.append(a)
        obs, *_ = env.step(a)
    norms = [float(np.abs(a).max()) for a in actions]
    assert all(n > 0 for n in norms[:4]) and all(n == 0 for n in norms[4:])


def test_controller_needs_first_observation():
    env = small_env()
    obs, _ = env.reset(seed=0)
    obs, *_ = env.step(env.action_space.sample())
    with pytest.raises(RuntimeError, match="tbar"):
        TurnpikeController(env).predict(obs)


def test_controller_clips_and_warns():
    env = small_env(max_control=0.5, target=2.0)
    obs, _ = env.reset(seed=0)
    ctrl = TurnpikeController(env)
    with pytest.warns(RuntimeWarning, match="clipped"):
        action, _ = ctrl.predict(obs)
    assert np.all(np.abs(action) <= 1.0) and ctrl.n_clipped > 0


def test_zero_and_proportional():
    env = small_env(target=0.2)
    obs, _ = env.reset(seed=1)
    zero, _ = ZeroController(env).predict(obs)
    assert np.all(zero == 0.0) and zero.shape == (6,)
    prop, _ = ProportionalController(env, beta=5.0).predict(obs)
    x = split_observation(obs, 6, 1)["positions"]
    np.testing.assert_allclose(
        prop, (5.0 * (0.2 - x) / env.unwrapped.max_control).ravel(), rtol=1e-6
    )
    assert isinstance(make_baseline("turnpike", env), TurnpikeController)
    with pytest.raises(ValueError, match="unknown baseline"):
        make_baseline("optimum", env)


def test_vecenv_rows_reset_at_different_times():
    # Row 0 mid-episode keeps its own tbar; row 1 just reset recomputes from its t/T = 0 obs.
    env_a, env_b = small_env(target=0.9), small_env(target=-0.5)
    obs_a, _ = env_a.reset(seed=1)
    obs_b, _ = env_b.reset(seed=2)
    ctrl, single = TurnpikeController(env_a), TurnpikeController(env_a)
    single.predict(obs_a)
    acts, state = ctrl.predict(np.stack([obs_a, obs_b]))
    tbar_a = state[0][0]
    for _ in range(2):
        obs_a, *_ = env_a.step(acts[0])
        obs_b, *_ = env_b.step(acts[1])
        acts, state = ctrl.predict(np.stack([obs_a, obs_b]), state)
    obs_b, _ = env_b.reset(seed=5)
    acts, state = ctrl.predict(np.stack([obs_a, obs_b]), state)
    assert state[0][0] == tbar_a
    x_b = split_observation(obs_b, 6, 1)["positions"]
    assert state[0][1] == pytest.approx(turnpike_time(x_b, -0.5, horizon=1.0))
    single.predict(obs_a)  # the single-env controller gives the same action for row 0
    np.testing.assert_array_equal(acts[0], single.predict(obs_a)[0])
    # Without passing state back, the controller's cache gives the same result.
    acts2, _ = ctrl.predict(np.stack([obs_a, obs_b]))
    np.testing.assert_array_equal(acts, acts2)


def test_evaluate_policy_on_dummy_vec_env_with_different_seeds():
    from stable_baselines3.common.evaluation import evaluate_policy
    from stable_baselines3.common.vec_env import DummyVecEnv

    from agent_envs.training.results.rollout import rollout

    # env 0 is truncated after 5 of its 8 steps, so the two envs reset at different times.
    venv = DummyVecEnv([lambda: small_env(max_episode_steps=5), lambda: small_env(target=-0.3)])
    venv.seed(11)  # env i resets with seed 11 + i
    ctrl = TurnpikeController(venv)
    seen: list[tuple[np.ndarray, np.ndarray]] = []
    original = ctrl.predict

    def recording_predict(obs, state=None, episode_start=None, deterministic=True):
        action, new_state = original(obs, state, episode_start, deterministic)
        seen.append((np.array(obs), np.array(new_state[0])))
        return action, new_state

    ctrl.predict = recording_predict  # type: ignore[method-assign]
    rewards, lengths = evaluate_policy(
        ctrl, venv, n_eval_episodes=6, return_episode_rewards=True, warn=False
    )
    assert len(rewards) == 6 and np.all(np.isfinite(rewards))
    assert sorted(set(lengths)) == [5, 8]
    # every row's tbar is the one of its own latest episode start
    start_obs: dict[int, np.ndarray] = {}
    for obs, tbar in seen:
        for i in range(2):
            if obs[i, -1] == 0.0:
                start_obs[i] = obs[i]
            parts = split_observation(start_obs[i], 6, 1)
            expected = turnpike_time(parts["positions"], parts["target"], horizon=1.0)
            assert tbar[i] == pytest.approx(expected)
    # the first full episode of env 1 equals a plain rollout with seed 12
    env1 = small_env(target=-0.3)
    ep = rollout(TurnpikeController(env1), env1, seed=12)
    first_env1 = next(r for r, n in zip(rewards, lengths, strict=True) if n == 8)
    assert first_env1 == pytest.approx(-ep.total_cost, rel=1e-6)


# ------------------------------------------------------------------------------------------
# PettingZoo
# ------------------------------------------------------------------------------------------


def test_controller_drives_pettingzoo_parallel_env():
    from agent_envs import swarm_v0

    par = swarm_v0.parallel_env(n_agents=5, n_steps=8, n_paths=2, target=1.2)
    gym_ctrl = TurnpikeController(par)
    ctrl = TurnpikeController(par)
    obs, _ = par.reset(seed=4)
    x0 = split_observation(par.state(), 5, 1)["positions"]
    tbar = turnpike_time(x0, 1.2, horizon=1.0)
    gym_ctrl.predict(par.state())
    steps, total = 0, 0.0
    while par.agents:
        actions = ctrl.act(obs)
        assert set(actions) == set(par.agents)
        assert all(a.shape == (1,) and a.dtype == np.float32 for a in actions.values())
        # same actions as the controller on the global state (Gym layout)
        global_action, _ = gym_ctrl.predict(par.state())
        np.testing.assert_allclose(
            np.concatenate([actions[a] for a in par.possible_agents]), global_action, atol=1e-6
        )
        # and as on the stacked per-agent rows (a SuperSuit-style batch)
        rows = np.stack([obs[a] for a in par.possible_agents])
        batch_action, _ = TurnpikeController(par, turnpike_time=tbar).predict(rows)
        np.testing.assert_allclose(batch_action.ravel(), global_action, atol=1e-6)
        obs, rewards, _, _, _ = par.step(actions)
        total += sum(rewards.values())
        steps += 1
    assert steps == 8 and np.isfinite(total)
    assert ctrl._agent_episode_tbar == pytest.approx(tbar)
    # predict() with the dict returns a dict of actions too
    obs, _ = par.reset(seed=4)
    actions, _ = TurnpikeController(par).predict(obs)
    assert set(actions) == set(par.agents)


def test_evaluate_policy_on_supersuit_vec_env_of_pettingzoo():
    # Parameter-sharing layout: each row is one agent, N rows per env; tbar per group of N.
    import supersuit as ss
    from stable_baselines3.common.evaluation import evaluate_policy

    from agent_envs import swarm_v0

    kw = {"n_agents": 5, "n_steps": 8, "n_paths": 2}
    venv = ss.concat_vec_envs_v1(
        ss.pettingzoo_env_to_vec_env_v1(swarm_v0.parallel_env(**kw)),
        2,
        num_cpus=1,
        base_class="stable_baselines3",
    )
    ctrl = TurnpikeController(swarm_v0.parallel_env(**kw))
    rewards, lengths = evaluate_policy(
        ctrl, venv, n_eval_episodes=10, return_episode_rewards=True, warn=False
    )
    assert len(rewards) == 10 and np.all(np.isfinite(rewards)) and set(lengths) == {8}
    tbar = ctrl.turnpike_times
    assert tbar.shape == (10,) and np.all(tbar > 0)
    assert np.all(tbar[:5] == tbar[0]) and np.all(tbar[5:] == tbar[5])
    venv.close()


def test_closed_loop_model_switches_off_at_until_inside_simulate():
    # Feedback on for t < 2 tau, then the open-loop swarm: the run equals a closed-loop run
    # for 2 steps continued by an open-loop run from there, on the same increments.
    from dataclasses import replace

    from agent_envs import make_integrator, simulate

    params = SwarmParams(n_agents=8, epsilon=0.05, sigma=0.01, target=0.7)
    dt, m = 0.02, 5
    x0 = np.linspace(-1, 1, 8)
    dw = np.random.default_rng(3).standard_normal((m, 2, 8, 1)) * np.sqrt(dt)
    kw = dict(integrator="serb", n_paths=2, initial_positions=x0)
    params_m = replace(params, horizon=m * dt)
    model = CheapClosedLoopModel(SwarmModel(params), [0.7], beta=12.0, until=2 * dt)
    both = simulate(params_m, n_steps=m, model=model, increments=dw, **kw)
    closed = simulate(
        replace(params, horizon=2 * dt),
        n_steps=2,
        model=CheapClosedLoopModel(SwarmModel(params), [0.7], beta=12.0),
        increments=dw[:2],
        **kw,
    )
    np.testing.assert_array_equal(both.positions[:3], closed.positions)
    x, scheme, plain = both.positions[2], make_integrator("serb"), SwarmModel(params)
    for n in range(2, m):
        x = scheme.step(plain, x, None, n * dt, dt, dw[n])
        np.testing.assert_allclose(both.positions[n + 1], x, rtol=1e-13, atol=1e-15)
