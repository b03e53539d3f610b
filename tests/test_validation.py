"""The accepted ranges of `agent_envs.validation` at their edges.

The largest (and smallest) accepted values give finite rewards and observations inside the
declared spaces; the first value past each edge raises an error naming the input and its range;
huge ints, NaN, bools, strings and complex numbers are rejected with a named error.
"""

from __future__ import annotations

import copy
import math
import pickle

import gymnasium as gym
import numpy as np
import pytest

from agent_envs import SwarmParams, swarm_v0
from agent_envs.envs import SwarmEnv
from agent_envs.envs.swarm_env import ENV_ID
from agent_envs.simulator import simulate
from agent_envs.validation import (
    ALPHA_RANGE,
    DIVERGENCE_THRESHOLD_RANGE,
    EPSILON_RANGE,
    GAMMA_RANGE,
    HORIZON_RANGE,
    MAX_AGENTS,
    MAX_BATCH_SIZE,
    MAX_CONTROL_RANGE,
    MAX_PATHS,
    MAX_POSITION,
    MAX_STATE_SIZE,
    MAX_STEPS,
    SIGMA_RANGE,
    real_array,
)

BELOW = -math.inf
ABOVE = math.inf


def first_outside(value: float, direction: float) -> float:
    """The float next to `value` in `direction` (the first rejected value past an edge)."""
    return float(np.nextafter(value, direction))


# ----------------------------------------------------------- the largest values
STIFFEST = {
    "alpha": ALPHA_RANGE.low,
    "epsilon": EPSILON_RANGE.low,
    "epsilon_min": EPSILON_RANGE.low,
    "epsilon_max": EPSILON_RANGE.low,
}
LARGEST = {
    "sigma": SIGMA_RANGE.high,
    "horizon": HORIZON_RANGE.high,
    "gamma": GAMMA_RANGE.high,
    "max_control": MAX_CONTROL_RANGE.high,
    "divergence_threshold": DIVERGENCE_THRESHOLD_RANGE.high,
    "target": first_outside(MAX_POSITION, BELOW),
}


def check_finite_step(env, obs, reward, info) -> None:
    assert np.all(np.isfinite(obs)) and obs in env.observation_space
    assert math.isfinite(reward)
    assert math.isfinite(info["running_cost"])


@pytest.mark.parametrize("kernel", ["symmetric", "nonsymmetric"])
@pytest.mark.parametrize(
    ("integrator", "jacobian"),
    [("em", "frozen"), ("heun", "frozen"), ("ee", "frozen"), ("serb", "frozen"), ("erb", "exact")],
)
def test_extreme_accepted_values_give_finite_rewards_and_observations(kernel, integrator, jacobian):
    """All range edges at once: the stiffest kernel, the largest R, M, gamma, T, sigma, xbar.

    The agents start at -R, R and two points alpha apart (where the drift |r| p(r) is largest),
    and the controls are the largest, so the reward is near its bound d (4 R^2 + gamma M^2) T.
    """
    env = SwarmEnv(
        n_agents=4,
        dim=1,
        kernel=kernel,
        integrator=integrator,
        jacobian=jacobian,
        n_steps=1,
        **STIFFEST,
        **LARGEST,
    )
    space = env.observation_space
    assert np.all(np.isfinite(space.low)) and np.all(np.isfinite(space.high))
    radius = env.config.divergence_threshold
    x0 = np.array([-radius, radius, 0.0, ALPHA_RANGE.low])
    obs, info = env.reset(seed=0, options={"initial_positions": x0})
    assert np.all(np.isfinite(obs)) and obs in space
    assert np.max(np.abs(env.unwrapped.episode.mean_interaction_drift)) > 1e16  # near its bound
    obs, reward, terminated, _, info = env.step(-np.ones(4, dtype=np.float32))
    check_finite_step(env, obs, reward, info)
    assert reward < -1e20  # the bound is ~ -T (4 R^2 + gamma M^2) ~ -1e24: near it, finite
    assert terminated == info["diverged"]


def test_extreme_values_in_the_pettingzoo_env_stay_finite():
    par_env = swarm_v0.parallel_env(n_agents=3, dim=2, n_steps=2, **STIFFEST, **LARGEST)
    obs, infos = par_env.reset(seed=1)
    actions = {a: np.ones(2, dtype=np.float32) for a in par_env.agents}
    while par_env.agents:
        obs, rewards, _, _, infos = par_env.step(actions)
        for agent, o in obs.items():
            assert o in par_env.observation_space(agent) and np.all(np.isfinite(o))
            assert math.isfinite(rewards[agent]) and math.isfinite(infos[agent]["running_cost"])
        assert par_env.state() in par_env.state_space


def test_largest_sizes_are_accepted_and_the_next_rejected():
    assert SwarmParams(n_agents=MAX_AGENTS, dim=1).n_agents == MAX_AGENTS
    assert SwarmParams(n_agents=2, dim=MAX_STATE_SIZE // 2).dim == MAX_STATE_SIZE // 2
    with pytest.raises(ValueError, match="n_agents"):
        SwarmParams(n_agents=MAX_AGENTS + 1)
    with pytest.raises(ValueError, match=r"dim.*n_agents \* dim"):
        SwarmParams(n_agents=2, dim=MAX_STATE_SIZE // 2 + 1)
    with pytest.raises(ValueError, match="dim"):
        SwarmEnv(dim=2**40)  # was a MemoryError
    params = SwarmParams(n_agents=100)
    n_paths = MAX_BATCH_SIZE // 100
    with pytest.raises(ValueError, match="n_paths"):
        SwarmEnv(n_agents=100, n_paths=n_paths + 1)
    with pytest.raises(ValueError, match="n_paths"):
        simulate(params, n_paths=n_paths + 1)
    with pytest.raises(ValueError, match="n_paths"):
        SwarmEnv(n_agents=2, n_paths=MAX_PATHS + 1)
    with pytest.raises(ValueError, match="n_steps"):
        SwarmEnv(n_steps=MAX_STEPS + 1)
    env = SwarmEnv(n_agents=2, n_steps=MAX_STEPS)
    env.reset(seed=0)
    obs, reward, *_ = env.step(np.ones(2, dtype=np.float32))
    assert obs in env.observation_space and math.isfinite(reward)


# --------------------------------------------------------- the first rejected
EDGES = [
    ("alpha", ALPHA_RANGE.low, BELOW),
    ("alpha", ALPHA_RANGE.high, ABOVE),
    ("epsilon", EPSILON_RANGE.low, BELOW),
    ("epsilon", EPSILON_RANGE.high, ABOVE),
    ("epsilon_min", EPSILON_RANGE.low, BELOW),
    ("epsilon_max", EPSILON_RANGE.high, ABOVE),
    ("sigma", SIGMA_RANGE.low, BELOW),
    ("sigma", SIGMA_RANGE.high, ABOVE),
    ("horizon", HORIZON_RANGE.low, BELOW),
    ("horizon", HORIZON_RANGE.high, ABOVE),
    ("gamma", GAMMA_RANGE.low, BELOW),
    ("gamma", GAMMA_RANGE.high, ABOVE),
    ("max_control", MAX_CONTROL_RANGE.high, ABOVE),
    ("divergence_threshold", DIVERGENCE_THRESHOLD_RANGE.low, BELOW),
    ("divergence_threshold", DIVERGENCE_THRESHOLD_RANGE.high, ABOVE),
]


def edge_kwargs(name: str, value: float) -> dict:
    kwargs = {"n_agents": 3, name: value}
    if name == "epsilon_min":
        kwargs["epsilon_max"] = max(value, 1e-1)
    if name == "epsilon_max":
        kwargs["epsilon_min"] = 1e-2
    return kwargs


@pytest.mark.parametrize(("name", "edge", "direction"), EDGES)
def test_edge_is_accepted_and_the_next_float_rejected(name, edge, direction):
    env = SwarmEnv(**edge_kwargs(name, edge))
    obs, _ = env.reset(seed=0)
    obs, reward, _, _, info = env.step(env.action_space.sample())
    check_finite_step(env, obs, reward, info)
    outside = first_outside(edge, direction)
    with pytest.raises(ValueError, match=rf"{name} must be .*\[|{name} must be .*\("):
        SwarmEnv(**edge_kwargs(name, outside))


def test_max_control_must_be_positive():
    with pytest.raises(ValueError, match=r"max_control must be a real number in \(0, "):
        SwarmEnv(max_control=0.0)
    assert SwarmEnv(max_control=5e-324).max_control == 5e-324


def test_target_range():
    assert SwarmParams(target=-MAX_POSITION).target == -MAX_POSITION
    with pytest.raises(ValueError, match="target"):
        SwarmParams(target=first_outside(MAX_POSITION, ABOVE))
    with pytest.raises(ValueError, match="target must lie inside the divergence threshold"):
        SwarmEnv(divergence_threshold=2.0, target=2.0)


# ------------------------------------------------------------------ junk types
JUNK = [
    (True, TypeError),
    (np.bool_(False), TypeError),
    ("0.5", TypeError),
    (None, TypeError),
    (1 + 2j, TypeError),
    (math.nan, ValueError),
    (math.inf, ValueError),
    (10**400, ValueError),  # was an OverflowError
    (-(10**5000), ValueError),  # str() of it would fail: the message gives its size
]
JUNK_IDS = ["True", "np.False_", "str", "None", "complex", "nan", "inf", "10**400", "-10**5000"]
REAL_FIELDS = ["alpha", "epsilon", "sigma", "horizon", "gamma", "max_control"]
INT_FIELDS = ["n_agents", "dim", "n_steps", "n_paths"]


@pytest.mark.parametrize(("value", "error"), JUNK, ids=JUNK_IDS)
@pytest.mark.parametrize("name", [*REAL_FIELDS, "divergence_threshold", *INT_FIELDS])
def test_junk_values_raise_a_named_error(name, value, error):
    if name in INT_FIELDS and value in (math.nan, math.inf):
        error = TypeError  # a float is not an integer
    with pytest.raises(error, match=name):
        SwarmEnv(**{name: value})


@pytest.mark.parametrize(
    ("value", "error"),
    [(True, TypeError), ("0.5", TypeError), ([0.5, "a"], TypeError), (10**400, ValueError)],
)
def test_bad_target_is_named_in_params_and_reset(value, error):
    with pytest.raises(error, match="target"):
        SwarmParams(target=value)
    env = SwarmEnv(n_agents=3)
    with pytest.raises(error, match="target"):
        env.reset(options={"target": value})


def test_simulate_arguments_are_checked():
    params = SwarmParams(n_agents=3)
    for kwargs, error, name in [
        ({"n_steps": 10**400}, ValueError, "n_steps"),
        ({"n_paths": True}, TypeError, "n_paths"),
        ({"divergence_threshold": "1e4"}, TypeError, "divergence_threshold"),
        ({"divergence_threshold": 1e40}, ValueError, "divergence_threshold"),
        ({"initial_positions": ["0.1", "0.2", "0.3"]}, TypeError, "initial_positions"),
        ({"initial_positions": [True, False, True]}, TypeError, "initial_positions"),
        ({"initial_positions": [0.0, 0.0, 2e4]}, ValueError, "initial_positions"),
        ({"control": np.full((2, 3, 1), 1j)}, TypeError, "control"),
        ({"control": lambda t, x: np.full(x.shape, "a")}, TypeError, "control"),
    ]:
        with pytest.raises(error, match=name):
            simulate(params, n_steps=kwargs.pop("n_steps", 2), **kwargs)


@pytest.mark.parametrize("make", [SwarmEnv, swarm_v0.parallel_env])
@pytest.mark.parametrize(
    ("seed", "error"),
    [
        (True, TypeError),
        (1.5, TypeError),
        ("1", TypeError),
        (-1, ValueError),
        (-(10**5000), ValueError),
    ],
    ids=["True", "1.5", "str", "-1", "-10**5000"],
)
def test_bad_seed_is_a_named_error_not_gymnasiums(make, seed, error):
    """Gymnasium raises its own `gymnasium.error.Error` (and accepts True): checked first."""
    env = make(n_agents=3)
    with pytest.raises(error, match="seed must be None or an integer >= 0"):
        env.reset(seed=seed)
    with pytest.raises(error, match="seed"):
        simulate(SwarmParams(n_agents=3), n_steps=1, seed=seed)
    env.reset(seed=2**200)  # any size of non-negative int is a seed


# ---------------------------------------------------------------------- actions
@pytest.mark.parametrize(
    ("action", "error"),
    [
        (np.array(["0.1", "0.2", "0.3"]), TypeError),
        (np.array([True, False, True]), TypeError),
        (np.array([0.1 + 1j, 0.0, 0.0]), TypeError),  # the imaginary part was dropped
        ([10**400, 0, 0], ValueError),  # was an OverflowError
        (np.array([1e4000, 0, 0], dtype=np.longdouble), ValueError),
        (np.array([0.1, "a", 0.0], dtype=object), TypeError),
        (np.array([0.1, True, 0.0], dtype=object), TypeError),
        ([[0.1], [0.2, 0.3]], TypeError),  # ragged
    ],
)
def test_actions_must_be_real_numbers(action, error):
    env = SwarmEnv(n_agents=3)
    env.reset(seed=0)
    with pytest.raises(error, match="action"):
        env.step(action)
    assert env.step_index == 0


def test_object_and_integer_actions_are_their_float_values():
    """An object array of ints/floats, or an integer array, acts as its float64 values."""
    rewards = []
    for action in (
        np.array([1.0, 0.0, -1.0]),
        np.array([1, 0, -1], dtype=object),
        np.array([1, 0, -1], dtype=np.int8),
        [2**70, 0, -(2**70)],  # clipped to [-1, 1] like any large action
    ):
        env = SwarmEnv(n_agents=3)
        env.reset(seed=0)
        rewards.append(env.step(action)[1])
    assert rewards == [rewards[0]] * 4


def test_pettingzoo_actions_name_the_agent():
    par_env = swarm_v0.parallel_env(n_agents=3)
    par_env.reset(seed=0)
    actions = {a: np.zeros(1, dtype=np.float32) for a in par_env.agents}
    for bad, error in [("0.5", TypeError), (np.array([True]), TypeError), ([1j], TypeError)]:
        with pytest.raises(error, match="agent_1"):
            par_env.step({**actions, "agent_1": bad})
    with pytest.raises(ValueError, match="actions"):
        par_env.step({**actions, "agent_2": np.array([np.nan])})


def test_real_array_converts_only_real_numbers():
    np.testing.assert_array_equal(real_array("x", [1, 2.5]), [1.0, 2.5])
    assert real_array("x", np.array([3], dtype=np.uint64)).dtype == np.float64
    with pytest.raises(TypeError, match="x must hold real numbers"):
        real_array("x", np.array(["1"]))


# ---------------------------------------------------------------------- clients
def test_unknown_keyword_is_pythons_standard_type_error():
    """TorchRL's GymEnv retries gym.make only on Python's own message."""
    with pytest.raises(TypeError) as info:
        SwarmEnv(n_agentz=5)
    assert str(info.value) == "SwarmEnv.__init__() got an unexpected keyword argument 'n_agentz'"
    with pytest.raises(TypeError, match=r"got an unexpected keyword argument 'frameskip'"):
        gym.make(ENV_ID, frameskip=4)
    with pytest.raises(TypeError) as info:
        swarm_v0.parallel_env(bogus=1)
    assert str(info.value) == (
        "SwarmParallelEnv.__init__() got an unexpected keyword argument 'bogus'"
    )


def test_reset_and_step_infos_have_the_same_keys_per_agent():
    par_env = swarm_v0.parallel_env(n_agents=3, n_steps=2)
    _, reset_infos = par_env.reset(seed=0)
    _, _, _, _, step_infos = par_env.step({a: np.zeros(1) for a in par_env.agents})
    assert set(reset_infos) == set(step_infos)
    for agent, info in reset_infos.items():
        assert set(info) == set(step_infos[agent])
        for key, value in info.items():
            assert type(value) is type(step_infos[agent][key])


@pytest.mark.parametrize("make", [SwarmEnv, swarm_v0.parallel_env])
def test_env_that_has_rendered_pickles_and_deep_copies(make):
    env = make(n_agents=3, n_steps=3, render_mode="rgb_array")
    env.reset(seed=0)
    if isinstance(env, SwarmEnv):
        env.step(np.ones(3, dtype=np.float32))
    else:
        env.step({a: np.ones(1, dtype=np.float32) for a in env.agents})
    frame = env.render()
    for twin in (copy.deepcopy(env), pickle.loads(pickle.dumps(env))):
        np.testing.assert_array_equal(twin.render(), frame)  # same history, new figure
        np.testing.assert_array_equal(twin.positions, env.positions)
        twin.close()
    assert env.render().shape == frame.shape  # the original keeps its figure
