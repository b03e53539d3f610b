"""The learner's interface options (`agent_envs.envs.interface`): observation layouts, action
bases, agent reward.

What must hold: the modes are the Helmert coordinates (checked against the explicit matrix);
every option passes the official checkers; no option changes the dynamics, the cost or the
draws (same seed and same controls -> the same rewards and states); the vector env still equals
SyncVectorEnv bit for bit; a policy trained with options acts identically on the default env
through `InterfacePolicy` / `PerAgentPolicy`; bad values name the option.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from episodes import episode_cost
from gymnasium.utils.env_checker import check_env
from hypothesis import given, settings
from hypothesis import strategies as st
from pettingzoo.test import parallel_api_test

import agent_envs  # noqa: F401  (registers the env)
from agent_envs import swarm_v0
from agent_envs.baselines import ProportionalController
from agent_envs.envs.interface import (
    ACTION_BASES,
    AGENT_OBSERVATIONS,
    OBSERVATIONS,
    actions_from_controls,
    controls_from_actions,
    from_modes,
    swarm_summary,
    to_modes,
)
from agent_envs.envs.observation import agent_observations_from_global

ENV = "agent_envs/Swarm-v0"
SMALL = {"n_agents": 6, "n_steps": 6, "n_paths": 2}


def helmert(n: int) -> np.ndarray:
    """The explicit (N - 1, N) Helmert difference rows, from their definition."""
    rows = np.zeros((n - 1, n))
    for j in range(1, n):
        rows[j - 1, :j] = 1.0
        rows[j - 1, j] = -j
        rows[j - 1] /= np.sqrt(j * (j + 1.0))
    return rows


@given(
    n=st.integers(1, 40),
    d=st.integers(1, 3),
    seed=st.integers(0, 2**32 - 1),
)
@settings(max_examples=40, deadline=None)
def test_modes_are_the_mean_and_the_orthonormal_helmert_coordinates(n, d, seed):
    v = np.random.default_rng(seed).normal(size=(2, n, d))
    m = to_modes(v)
    np.testing.assert_allclose(m[:, 0], v.mean(axis=1), rtol=0, atol=1e-12)
    if n > 1:
        h = helmert(n)
        np.testing.assert_allclose(h @ h.T, np.eye(n - 1), atol=1e-12)
        np.testing.assert_allclose(h @ np.ones(n), 0.0, atol=1e-12)
        np.testing.assert_allclose(m[:, 1:], np.einsum("jn,bnd->bjd", h, v), atol=1e-12)
    np.testing.assert_allclose(from_modes(m), v, atol=1e-12)


def test_modes_of_a_batch_row_are_its_own_bits_and_torch_agrees():
    v = np.random.default_rng(0).normal(size=(3, 7, 2))
    for i in range(3):
        assert np.array_equal(to_modes(v)[i], to_modes(v[i]))
        assert np.array_equal(from_modes(v)[i], from_modes(v[i]))
    torch = pytest.importorskip("torch")
    np.testing.assert_allclose(to_modes(torch.tensor(v)).numpy(), to_modes(v), atol=1e-14)
    np.testing.assert_allclose(from_modes(torch.tensor(v)).numpy(), from_modes(v), atol=1e-14)


def test_action_bases_map_actions_to_the_stated_controls():
    a = np.random.default_rng(1).uniform(-0.3, 0.3, size=(5, 1))
    np.testing.assert_allclose(controls_from_actions(a, "agents", 2.0), 2.0 * a)
    u = controls_from_actions(a, "modes", 2.0)
    np.testing.assert_allclose(u.mean(axis=0), 2.0 * a[0])  # mode 0 moves every agent alike
    np.testing.assert_allclose(actions_from_controls(u, "modes", 2.0), a, atol=1e-12)
    common = controls_from_actions(np.array([[0.4]]), "common", 2.0, 5)
    np.testing.assert_array_equal(common, np.full((5, 1), 0.8))
    np.testing.assert_allclose(actions_from_controls(common, "common", 2.0), [[0.4]])
    # out-of-range actions are clipped first, then the controls
    np.testing.assert_array_equal(controls_from_actions(np.array([[3.0]]), "agents", 2.0), [[2.0]])


@pytest.mark.parametrize("observation", OBSERVATIONS)
@pytest.mark.parametrize("basis", ACTION_BASES)
def test_every_gymnasium_option_passes_the_env_checker(observation, basis):
    env = gym.make(ENV, **SMALL, observation=observation, action_basis=basis)
    check_env(env.unwrapped, skip_render_check=True)
    rows = 1 if basis == "common" else SMALL["n_agents"]
    assert env.action_space.shape == (rows,)


@pytest.mark.parametrize("observation", AGENT_OBSERVATIONS)
@pytest.mark.parametrize("reward", ["own", "team"])
def test_every_pettingzoo_option_passes_the_parallel_api_test(observation, reward):
    env = swarm_v0.parallel_env(**SMALL, observation=observation, agent_reward=reward)
    parallel_api_test(env, num_cycles=8)


def _rollout(env, controls_of, seed=7):
    """Rewards and final positions of one episode where controls_of(obs) gives u (N, 1)."""
    base = env.unwrapped
    env.reset(seed=seed)
    rewards, done = [], False
    while not done:
        u = controls_of(base)
        action = actions_from_controls(u, base.config.action_basis, base.max_control)
        _, reward, terminated, truncated, _ = env.step(action.reshape(-1))
        rewards.append(reward)
        done = terminated or truncated
    return np.array(rewards), base.positions.copy()


def _proportional_controls(base):
    x = base.positions.mean(axis=0)
    return np.clip(2.0 * (base.params.target_vector - x), -20, 20)


@pytest.mark.parametrize("observation", OBSERVATIONS)
@pytest.mark.parametrize("basis", ["agents", "modes"])
def test_no_option_changes_dynamics_cost_or_draws(observation, basis):
    plain = gym.make(ENV, **SMALL)
    other = gym.make(ENV, **SMALL, observation=observation, action_basis=basis)
    r0, x0 = _rollout(plain, _proportional_controls)
    r1, x1 = _rollout(other, _proportional_controls)
    np.testing.assert_allclose(r1, r0, rtol=1e-12, atol=0)
    np.testing.assert_allclose(x1, x0, rtol=0, atol=1e-12)


def test_layouts_hold_what_the_docstring_says():
    kwargs = {**SMALL, "target": 0.3}
    envs = {o: gym.make(ENV, **kwargs, observation=o) for o in OBSERVATIONS}
    obs = {o: env.reset(seed=3)[0] for o, env in envs.items()}
    x = envs["absolute"].unwrapped.positions.mean(axis=0)  # (N, 1)
    n = kwargs["n_agents"]
    np.testing.assert_allclose(obs["relative"][:n], x[:, 0] - 0.3, atol=1e-6)
    np.testing.assert_allclose(obs["modes"][0], x.mean() - 0.3, atol=1e-6)
    spread = np.sqrt(np.mean((x - x.mean()) ** 2))
    np.testing.assert_allclose(obs["summary"], [x.mean() - 0.3, spread, 0.3, 0.0], atol=1e-6)
    for o in OBSERVATIONS:
        assert envs[o].observation_space.contains(obs[o])


def test_team_reward_is_the_swarm_reward_for_every_agent():
    own = swarm_v0.parallel_env(**SMALL)
    team = swarm_v0.parallel_env(**SMALL, agent_reward="team")
    gym_env = gym.make(ENV, **SMALL)
    own.reset(seed=2)
    team.reset(seed=2)
    gym_env.reset(seed=2)
    actions = {a: np.array([0.1], np.float32) for a in own.agents}
    _, own_r, *_ = own.step(actions)
    _, team_r, *_ = team.step(actions)
    _, reward, *_ = gym_env.step(np.full(SMALL["n_agents"], 0.1, np.float32))
    assert sum(own_r.values()) == pytest.approx(reward, rel=1e-12)
    assert list(team_r.values()) == [pytest.approx(reward, rel=1e-12)] * SMALL["n_agents"]


def test_swarm_layout_rebuilt_from_the_gymnasium_observation_matches_the_pettingzoo_env():
    pz = swarm_v0.parallel_env(**SMALL, observation="swarm")
    gym_env = gym.make(ENV, **SMALL)
    pz_obs, _ = pz.reset(seed=4)
    gym_obs, _ = gym_env.reset(seed=4)
    rows = agent_observations_from_global(gym_obs, SMALL["n_agents"], 1, "swarm")
    expected = np.stack([pz_obs[a] for a in pz.possible_agents])
    np.testing.assert_allclose(rows, expected, atol=1e-6)
    centre, spread = swarm_summary(pz.positions.mean(axis=0), pz.params.target_vector)
    np.testing.assert_allclose(expected[:, 3], centre[0], atol=1e-6)
    np.testing.assert_allclose(expected[:, 4], spread[0], atol=1e-6)


@pytest.mark.parametrize(
    ("observation", "basis"), [("modes", "modes"), ("summary", "common"), ("relative", "agents")]
)
def test_vector_env_equals_sync_vector_env_with_options(observation, basis):
    kwargs = {**SMALL, "observation": observation, "action_basis": basis}
    native = gym.make_vec(ENV, num_envs=3, vectorization_mode="vector_entry_point", **kwargs)
    sync = gym.vector.SyncVectorEnv([lambda: gym.make(ENV, **kwargs)] * 3)
    o1, _ = native.reset(seed=5)
    o2, _ = sync.reset(seed=5)
    assert np.array_equal(o1, o2)
    rng = np.random.default_rng(0)
    for _ in range(8):
        action = rng.uniform(-0.5, 0.5, size=native.action_space.shape).astype(np.float32)
        s1, s2 = native.step(action), sync.step(action)
        for a, b in zip(s1[:4], s2[:4], strict=True):
            assert np.array_equal(a, b)


def test_interface_policy_acts_on_the_default_env_as_in_its_own():
    from agent_envs.training.learners.policies import InterfacePolicy

    kwargs = {**SMALL, "n_paths": 1}
    own = gym.make(ENV, **kwargs, observation="summary", action_basis="common")

    class CentreFeedback:  # a policy of the summary/common interface
        def predict(self, obs, state=None, episode_start=None, deterministic=True):
            obs = np.asarray(obs)
            return np.clip(-0.2 * obs[..., :1], -1, 1).astype(np.float32), state

    wrapped = InterfacePolicy(
        CentreFeedback(),
        6,
        1,
        "summary",
        "common",
        own.unwrapped.max_control,
        own.observation_space,
    )
    assert episode_cost(wrapped, gym.make(ENV, **kwargs), 11) == pytest.approx(
        episode_cost(CentreFeedback(), own, 11), rel=1e-6
    )


def test_references_act_alike_under_every_action_basis():
    costs = []
    for basis in ("agents", "modes"):
        env = gym.make(ENV, **SMALL, observation="modes", action_basis=basis)
        costs.append(episode_cost(ProportionalController(env), env, 1))
    assert costs[1] == pytest.approx(costs[0], rel=1e-7)  # float32 actions, other basis


@pytest.mark.parametrize(
    ("make", "kwargs", "match"),
    [
        # the env's own values, not both envs' ("swarm" is the PettingZoo env's)
        (
            lambda **k: gym.make(ENV, **k),
            {"observation": "velocity"},
            r"observation='velocity' .* 'absolute', 'relative', 'modes', 'summary'$",
        ),
        (
            swarm_v0.parallel_env,
            {"observation": "velocity"},
            r"observation='velocity' .* 'absolute', 'relative', 'swarm', 'local'$",
        ),
        (lambda **k: gym.make(ENV, **k), {"action_basis": 3}, "action_basis must be a str"),
        (lambda **k: gym.make(ENV, **k), {"observation": "swarm"}, "observation='swarm'"),
        (lambda **k: gym.make(ENV, **k), {"agent_reward": "team"}, "agent_reward='team'"),
        (swarm_v0.parallel_env, {"action_basis": "modes"}, "action_basis='modes'"),
        (swarm_v0.parallel_env, {"observation": "summary"}, "observation='summary'"),
    ],
)
def test_bad_option_values_name_the_option(make, kwargs, match):
    with pytest.raises((ValueError, TypeError), match=match):
        make(**SMALL, **kwargs)


def test_a_controller_that_needs_positions_refuses_the_summary_layout():
    env = gym.make(ENV, **SMALL, observation="summary")
    with pytest.raises(ValueError, match="summary"):
        ProportionalController(env)


def test_a_controller_that_needs_positions_refuses_the_local_layout():
    from agent_envs import swarm_v0

    env = swarm_v0.parallel_env(**SMALL, observation="local", neighbours=2)
    with pytest.raises(ValueError, match="observation='local'"):
        ProportionalController(env)


@pytest.mark.parametrize(("observation", "basis"), [("summary", "common"), ("modes", "modes")])
def test_torch_vector_env_follows_the_numpy_one_with_options(observation, basis):
    pytest.importorskip("torch")
    kwargs = {**SMALL, "observation": observation, "action_basis": basis}
    make = {"num_envs": 2, "vectorization_mode": "vector_entry_point"}
    numpy_env = gym.make_vec(ENV, **make, **kwargs)
    torch_env = gym.make_vec(ENV, **make, backend="torch", **kwargs)
    o1, _ = numpy_env.reset(seed=1)
    o2, _ = torch_env.reset(seed=1)
    np.testing.assert_allclose(o2, o1, rtol=1e-6, atol=1e-9)
    for _ in range(5):
        action = np.full(numpy_env.action_space.shape, 0.1, np.float32)
        s1, s2 = numpy_env.step(action), torch_env.step(action)
        np.testing.assert_allclose(s2[0], s1[0], rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(s2[1], s1[1], rtol=1e-10)


def test_controls_are_clipped_agent_by_agent_before_the_change_of_basis():
    u = np.array([[2.0], [0.0]])  # agent 0 beyond the bound max_control = 1
    agents = controls_from_actions(actions_from_controls(u, "agents", 1.0), "agents", 1.0)
    modes = controls_from_actions(actions_from_controls(u, "modes", 1.0), "modes", 1.0)
    np.testing.assert_allclose(agents, [[1.0], [0.0]])
    np.testing.assert_allclose(modes, agents, atol=1e-12)  # its coordinates fit the box here
    common = actions_from_controls(u, "common", 1.0)
    np.testing.assert_allclose(common, [[0.5]])  # the mean of the clipped controls


def test_bad_basis_or_layout_in_the_helpers_names_the_option():
    from agent_envs.envs.observation import observation_size, split_observation

    with pytest.raises(ValueError, match="action_basis must be one of"):
        controls_from_actions(np.zeros((3, 1)), "agent", 1.0)
    with pytest.raises(ValueError, match="action_basis must be one of"):
        actions_from_controls(np.zeros((3, 1)), "mode", 1.0)
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 1, d\)"):
        controls_from_actions(np.zeros((3, 1)), "common", 1.0, 3)  # (N, d): not one control
    with pytest.raises(ValueError, match="observation must be one of"):
        observation_size(3, 1, "relativ")
    with pytest.raises(ValueError, match="observation must be one of"):
        split_observation(np.zeros(8), 3, 1, "swarm")  # a PettingZoo layout
    with pytest.raises(ValueError, match="observation must be one of"):
        agent_observations_from_global(np.zeros(8), 3, 1, "modes")  # a Gymnasium layout


def test_baselines_count_clipped_controls_in_every_basis():
    counts = []
    for basis in ACTION_BASES:
        env = gym.make(ENV, **SMALL, max_control=2.0, action_basis=basis)
        policy = ProportionalController(env)
        obs, _ = env.reset(seed=1)
        with pytest.warns(RuntimeWarning, match="exceeds max_control"):
            policy.predict(obs)
        counts.append(policy.n_clipped)
    assert counts[0] > 0 and len(set(counts)) == 1
