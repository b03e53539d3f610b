"""The PettingZoo env's ``observation="local"`` (issue 41): rows against a brute-force neighbour
search (ties, N < K + 1, the matrix-free k-d tree path), the env's spaces and steps, the
bad-input contract of ``neighbours``, and ``render(mode=...)``."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import agent_envs  # noqa: F401  (registers agent_envs/Swarm-v0)
from agent_envs import swarm_v0
from agent_envs.envs import local_observation as local
from agent_envs.envs.episode_config import EpisodeConfig
from agent_envs.envs.observation import agent_observations, split_agent_observation


def brute_force_neighbours(x: np.ndarray, k: int) -> list[list[int]]:
    """For each agent, the other agents sorted by (squared distance, index), first k: Python."""
    n, d = x.shape
    result = []
    for a in range(n):
        keyed = []
        for b in range(n):
            if b == a:
                continue
            dist = 0.0
            for i in range(d):
                dist += (x[b, i] - x[a, i]) ** 2
            keyed.append((dist, b))
        result.append([b for _, b in sorted(keyed)[:k]])
    return result


def expected_rows(x: np.ndarray, target: np.ndarray, t: float, k: int) -> np.ndarray:
    n, d = x.shape
    rows = np.zeros((n, (k + 1) * (d + 1)), dtype=np.float32)
    for a, nearest in enumerate(brute_force_neighbours(x, k)):
        rows[a, :d] = x[a] - target
        for j, b in enumerate(nearest):
            rows[a, d + j * d : d + (j + 1) * d] = x[b] - x[a]
            rows[a, (k + 1) * d + j] = 1.0
        rows[a, -1] = t
    return rows


POSITIONS = {
    "random-1d": np.random.default_rng(0).uniform(-3, 3, (40, 1)),
    "random-3d": np.random.default_rng(1).uniform(-3, 3, (30, 3)),
    # ties: a lattice (many equal distances), duplicates (distance 0), a symmetric line
    "lattice-2d": np.stack(np.meshgrid(np.arange(5.0), np.arange(5.0)), -1).reshape(-1, 2),
    "duplicates": np.repeat(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), 4, axis=0),
    "line-ties": np.array([[2.0], [1.0], [3.0], [0.0], [4.0], [2.0], [1.0], [3.0]]),
}


@pytest.mark.parametrize("name", sorted(POSITIONS))
@pytest.mark.parametrize("k", [1, 3, 6])
def test_rows_equal_brute_force(name, k):
    x = POSITIONS[name]
    d = x.shape[1]
    target = np.full(d, 0.25)
    space = local.local_observation_space(d, 100.0, k)
    rows = agent_observations(x, None, target, 0.4, space, "local", k)
    np.testing.assert_array_equal(rows, expected_rows(x, target, 0.4, k))
    assert rows.dtype == np.float32 and rows.shape == (x.shape[0], (k + 1) * (d + 1))


@pytest.mark.parametrize("n", [1, 2, 3, 6, 7])
def test_fewer_agents_than_neighbours_pads_with_mask_zero(n):
    """N < K + 1: the first N - 1 slots hold every other agent, the rest zeros with mask 0."""
    k, d = 6, 2
    x = np.random.default_rng(n).uniform(-1, 1, (n, d))
    space = local.local_observation_space(d, 10.0, k)
    rows = agent_observations(x, None, np.zeros(d), 0.0, space, "local", k)
    np.testing.assert_array_equal(rows, expected_rows(x, np.zeros(d), 0.0, k))
    parts = split_agent_observation(rows, d, "local", k)
    count = min(k, n - 1)
    assert (parts["neighbour_mask"][:, :count] == 1).all()
    assert (parts["neighbour_mask"][:, count:] == 0).all()
    assert (parts["neighbour_offsets"][:, count:] == 0).all()


@pytest.mark.parametrize("kind", ["random", "ties"])
def test_tree_path_equals_blocks(monkeypatch, kind):
    """Above BRUTE_FORCE_MAX_AGENTS the k-d tree's candidates give the blocks' indices."""
    rng = np.random.default_rng(3)
    if kind == "random":
        x = rng.uniform(-2, 2, (500, 2))
    else:  # a lattice with duplicates: exact ties everywhere
        grid = np.stack(np.meshgrid(np.arange(12.0), np.arange(12.0)), -1).reshape(-1, 2)
        x = np.concatenate([grid, grid[::3]])
    want = local._nearest_blocks(x, 5)
    monkeypatch.setattr(local, "BRUTE_FORCE_MAX_AGENTS", 10)
    got = local.nearest_neighbours(x, 5)
    np.testing.assert_array_equal(got, want)
    assert got.tolist() == brute_force_neighbours(x, 5)


def test_massive_ties_search_the_distinct_positions(monkeypatch):
    """Many agents at one point (a collapsed swarm in float32) overflow the tree's candidate
    budget; the grouped search over the distinct positions gives the blocks' indices."""
    x = np.zeros((300, 1))
    monkeypatch.setattr(local, "BRUTE_FORCE_MAX_AGENTS", 10)
    assert local._nearest_tree(x, 3) is None
    got = local.nearest_neighbours(x, 3)
    np.testing.assert_array_equal(got[:3], [[1, 2, 3], [0, 2, 3], [0, 1, 3]])
    np.testing.assert_array_equal(got, local._nearest_blocks(x, 3))


@pytest.mark.parametrize("d", [1, 2])
@pytest.mark.parametrize("k", [1, 4, 9])
def test_grouped_search_equals_blocks(d, k):
    """Clusters of exactly equal positions, clusters smaller and larger than K, equal distances
    between distinct positions (a lattice), and a lone agent: the same indices as the blocks
    and as a brute-force ranking."""
    rng = np.random.default_rng(d * 10 + k)
    lattice = rng.integers(0, 6, size=(40, d)).astype(float) * 0.25
    sizes = rng.integers(1, 25, size=40)
    x = np.repeat(lattice, sizes, axis=0)
    x = np.concatenate([x, np.full((1, d), 9.0)])[rng.permutation(len(x) + 1)]
    got = local._nearest_grouped(x, k)
    np.testing.assert_array_equal(got, local._nearest_blocks(x, k))
    assert got.tolist() == brute_force_neighbours(x, k)


def test_grouped_search_budget_falls_back_to_blocks(monkeypatch):
    x = np.zeros((300, 1))
    monkeypatch.setattr(local, "BRUTE_FORCE_MAX_AGENTS", 10)
    monkeypatch.setattr(local, "CANDIDATE_BUDGET_PER_AGENT", 0)
    assert local._nearest_grouped(x, 3) is None
    np.testing.assert_array_equal(local.nearest_neighbours(x, 3), local._nearest_blocks(x, 3))


def test_blocks_hold_no_n_by_n_array(monkeypatch):
    """Row blocks of at most BLOCK_ENTRIES distances give the same indices as one block."""
    x = np.random.default_rng(5).uniform(-1, 1, (97, 2))
    want = local._nearest_blocks(x, 4)
    monkeypatch.setattr(local, "BLOCK_ENTRIES", 97 * 7)
    np.testing.assert_array_equal(local._nearest_blocks(x, 4), want)


def test_env_local_rows_match_numpy_and_leave_dynamics_alone():
    """The env's rows are the layout's of its path means; states, rewards and infos are those
    of the default layout bit for bit (the option changes no dynamics, cost or draws)."""
    kwargs = {"n_agents": 9, "dim": 2, "n_steps": 5, "n_paths": 3}
    env = swarm_v0.parallel_env(observation="local", neighbours=4, **kwargs)
    ref = swarm_v0.parallel_env(**kwargs)
    obs, _ = env.reset(seed=7)
    ref.reset(seed=7)
    space = env.observation_space("agent_0")
    assert space.shape == (15,) and obs["agent_0"] in space
    rng = np.random.default_rng(0)
    while env.agents:
        actions = {a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents}
        obs, rew, _, _, info = env.step(actions)
        _, ref_rew, _, _, ref_info = ref.step(actions)
        assert rew == ref_rew and info == ref_info
        np.testing.assert_array_equal(env.episode.positions, ref.episode.positions)
        ep = env.episode
        want = agent_observations(
            ep.mean_positions, None, ep.target, ep.time_fraction, space, "local", 4
        )
        np.testing.assert_array_equal(np.stack(list(obs.values())), want)
    assert env.plan.envelope in ("numpy", "compiled-step+numpy-tail")


def test_default_neighbours_and_replace():
    config = EpisodeConfig.from_kwargs(env_kind="pettingzoo", observation="local")
    assert config.neighbours == 6
    assert config.replace(observation="relative").neighbours is None
    assert EpisodeConfig.from_kwargs(observation="relative").neighbours is None


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"observation": "local", "neighbours": 0}, ValueError, r"neighbours .*\[1, 1024\]"),
        ({"observation": "local", "neighbours": 1025}, ValueError, r"neighbours .*\[1, 1024\]"),
        ({"observation": "local", "neighbours": -3}, ValueError, "neighbours"),
        ({"observation": "local", "neighbours": 2.0}, TypeError, "neighbours"),
        ({"observation": "local", "neighbours": True}, TypeError, "neighbours"),
        ({"observation": "local", "neighbours": "6"}, TypeError, "neighbours"),
        ({"neighbours": 3}, ValueError, "neighbours is an option of .*'local' only"),
        ({"observation": "swarm", "neighbours": 3}, ValueError, "observation='swarm'"),
    ],
)
def test_neighbours_bad_input(kwargs, error, match):
    with pytest.raises(error, match=match):
        swarm_v0.parallel_env(n_agents=4, **kwargs)


def test_gymnasium_env_refuses_local_and_neighbours():
    with pytest.raises(ValueError, match="observation='local' is not an option"):
        gym.make("agent_envs/Swarm-v0", observation="local")
    with pytest.raises(ValueError, match="neighbours"):
        gym.make("agent_envs/Swarm-v0", neighbours=2)


def test_numpy_neighbours_accepted():
    env = swarm_v0.parallel_env(n_agents=4, observation="local", neighbours=np.int64(2))
    assert env.config.neighbours == 2 and type(env.config.neighbours) is int


def test_render_mode_argument():
    """BenchMARL calls render(mode="rgb_array") on an env made without a render mode."""
    env = swarm_v0.parallel_env(n_agents=4, dim=2)
    frame = env.render(mode="rgb_array")  # before reset: the "call reset() first" frame
    assert frame.dtype == np.uint8 and frame.ndim == 3
    env.reset(seed=0)
    assert env.render() is None
    assert env.render(mode="rgb_array").shape == frame.shape
    with pytest.raises(ValueError, match="mode must be None or one of"):
        env.render(mode="ascii")
    made = swarm_v0.parallel_env(n_agents=4, dim=1, render_mode="rgb_array")
    made.reset(seed=0)
    made.step({a: np.zeros(1, np.float32) for a in made.agents})
    np.testing.assert_array_equal(made.render(mode="rgb_array"), made.render())


@pytest.mark.parametrize("dim", [1, 2])
def test_rows_from_the_gymnasium_observation_match_the_pettingzoo_env(dim):
    """A local-observation policy is scored on the Gymnasium env (`PerAgentPolicy`): its rows,
    built from the Gymnasium observation's float32 positions, are the PettingZoo env's (float32
    round-off apart), at reset and after steps, batched or not."""
    from agent_envs.envs.observation import agent_observations_from_global
    from agent_envs.training.learners.policies import PerAgentPolicy

    kwargs = {"n_agents": 9, "n_steps": 4, "dim": dim}
    pz = swarm_v0.parallel_env(**kwargs, observation="local", neighbours=3)
    env = gym.make("agent_envs/Swarm-v0", **kwargs)
    obs, _ = pz.reset(seed=5)
    g, _ = env.reset(seed=5)
    rng = np.random.default_rng(0)
    for _ in range(3):
        rows = agent_observations_from_global(g, 9, dim, "local", 3)
        expected = np.stack([obs[a] for a in pz.agents])
        assert rows.shape == expected.shape == (9, local.local_observation_size(dim, 3))
        np.testing.assert_allclose(rows, expected, atol=1e-6)
        batched = agent_observations_from_global(np.stack([g, g]), 9, dim, "local", 3)
        np.testing.assert_array_equal(batched, np.stack([rows, rows]))
        action = rng.uniform(-0.1, 0.1, size=(9, dim)).astype(np.float32)
        obs, *_ = pz.step({a: action[i] for i, a in enumerate(pz.agents)})
        g, *_ = env.step(action.reshape(-1))

    class Echo:  # returns the first entry of each row: the agent's own offset
        def predict(self, rows, state, start, deterministic):
            return rows[:, :dim], None

    policy = PerAgentPolicy(Echo(), 9, dim, "local", 3)
    action, _ = policy.predict(g)
    own = agent_observations_from_global(g, 9, dim, "local", 3)[:, :dim]
    np.testing.assert_array_equal(action, own.reshape(-1))


def test_default_interface_drops_neighbours():
    """A local-observation run's reference and validation envs (the Gymnasium env, default
    interface) are made from its env kwargs without the interface options, K included: the
    Gymnasium env refuses `neighbours`."""
    from agent_envs.training.defaults import default_interface

    kwargs = {"n_agents": 5, "observation": "local", "neighbours": 3, "agent_reward": "team"}
    assert default_interface(kwargs) == {"n_agents": 5}
    gym.make("agent_envs/Swarm-v0", **default_interface(kwargs)).reset(seed=0)
