"""Property-based tests of every input contract (hypothesis).

Contract: an input is either rejected with a `ValueError`/`TypeError` whose message names it,
or accepted, and then everything that comes out is finite and inside the declared spaces
(observations, rewards, infos, `simulate`'s trajectory up to a flagged divergence).

Inputs are drawn from a mix of in-range values (edges included), out-of-range numbers, NaN, inf,
huge ints, bools, strings, complex numbers and None. Sizes stay small (N <= 4, m <= 3) so the
whole module runs in seconds; the examples are derandomized so CI sees the same ones each run.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from agent_envs import SwarmParams, swarm_v0
from agent_envs.envs import SwarmEnv
from agent_envs.simulator import simulate
from agent_envs.validation import (
    ALPHA_RANGE,
    DIVERGENCE_THRESHOLD_RANGE,
    EPSILON_RANGE,
    GAMMA_RANGE,
    HORIZON_RANGE,
    MAX_AGENTS,
    MAX_CONTROL_RANGE,
    MAX_STATE_SIZE,
    SIGMA_RANGE,
    TARGET_RANGE,
    Range,
)

PROPERTY = settings(
    max_examples=300,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow],
)

JUNK = st.one_of(
    st.booleans(),
    st.text(max_size=3),
    st.none(),
    st.complex_numbers(allow_nan=False, max_magnitude=10),
    st.just(math.nan),
    st.sampled_from([math.inf, -math.inf]),
    st.integers(min_value=-(2**3000), max_value=2**3000),
    st.lists(st.floats(-1, 1), min_size=0, max_size=2),
)


def reals(accepted: Range) -> st.SearchStrategy:
    """In-range floats (edges and numpy scalars too), out-of-range floats and junk."""
    inside = st.floats(accepted.low, accepted.high, exclude_min=accepted.low_open)
    return st.one_of(
        inside,
        inside,
        st.sampled_from([accepted.high, *(() if accepted.low_open else (accepted.low,))]),
        inside.map(np.float64),
        st.floats(allow_nan=False, allow_infinity=False),
        JUNK,
    )


def ints(low: int, small: int, high: int) -> st.SearchStrategy:
    """Small in-range ints (cheap to simulate), the range's edges, out-of-range ints and junk."""
    return st.one_of(
        st.integers(low, small),
        st.integers(low, small),
        st.integers(low, small).map(np.int64),
        st.sampled_from([low - 1, high + 1, -1, 0]),
        st.floats(low, small),
        JUNK,
    )


def targets() -> st.SearchStrategy:
    inside = st.floats(-2.0, 2.0)
    return st.one_of(
        inside,
        st.lists(inside, min_size=1, max_size=3),
        st.sampled_from([TARGET_RANGE.high, TARGET_RANGE.low]),
        st.floats(allow_nan=False, allow_infinity=False),
        JUNK,
        st.lists(JUNK, min_size=1, max_size=2),
    )


PARAM_FIELDS = {
    "n_agents": ints(2, 4, MAX_AGENTS),
    "dim": ints(1, 3, MAX_STATE_SIZE // 2),
    "alpha": reals(ALPHA_RANGE),
    "epsilon": reals(EPSILON_RANGE),
    "epsilon_min": reals(EPSILON_RANGE),
    "epsilon_max": reals(EPSILON_RANGE),
    "sigma": reals(SIGMA_RANGE),
    "horizon": reals(HORIZON_RANGE),
    "target": targets(),
    "gamma": reals(GAMMA_RANGE),
    "kernel": st.sampled_from(["symmetric", "nonsymmetric", "banana", 1, None]),
}
ENV_FIELDS = {
    **PARAM_FIELDS,
    "n_steps": ints(1, 3, 10**9),
    "n_paths": ints(1, 3, 10**6),
    "max_control": reals(MAX_CONTROL_RANGE),
    "divergence_threshold": reals(DIVERGENCE_THRESHOLD_RANGE),
    "integrator": st.sampled_from(["em", "ee", "heun", "erb", "serb", "rk4", 3]),
}


def draw_kwargs(data, fields: dict, max_size: int = 4) -> dict:
    names = data.draw(st.lists(st.sampled_from(sorted(fields)), max_size=max_size, unique=True))
    return {name: data.draw(fields[name], label=name) for name in names}


def assert_names_one_of(error: Exception, names) -> None:
    event(f"rejected: {type(error).__name__}")
    message = str(error)
    assert isinstance(error, (ValueError, TypeError)), repr(error)
    assert any(name in message for name in names), f"{message!r} names none of {list(names)}"


def bad_arguments(build, base: dict, kwargs: dict) -> list[str]:
    """The drawn arguments that are rejected on their own (with `base` for the others)."""
    bad = []
    for name, value in kwargs.items():
        try:
            build(**{**base, name: value})
        except (TypeError, ValueError):
            bad.append(name)
    return bad


def assert_names_a_bad_argument(error: Exception, build, base: dict, kwargs: dict) -> None:
    """The error names an argument that is bad on its own, when one is; only when every
    argument passes alone (a bad combination: epsilon_min > epsilon_max, N d too large) may it
    name any of the drawn ones. Naming a good argument beside a bad one fails."""
    drawn = {k: v for k, v in kwargs.items() if k not in base or base[k] is not v}
    bad = bad_arguments(build, base, drawn)
    assert_names_one_of(error, bad or kwargs)


def assert_params_in_ranges(p: SwarmParams) -> None:
    event("accepted")
    assert 2 <= p.n_agents and p.n_agents * p.dim <= MAX_STATE_SIZE
    assert p.alpha in ALPHA_RANGE and p.sigma in SIGMA_RANGE and p.gamma in GAMMA_RANGE
    for eps in (p.epsilon, p.epsilon_min, p.epsilon_max):
        assert eps in EPSILON_RANGE
    assert p.epsilon_min <= p.epsilon_max and p.horizon in HORIZON_RANGE
    assert np.all(np.abs(p.target_vector) <= TARGET_RANGE.high)


def assert_gym_outputs_finite(env, obs, reward=0.0, info=None) -> None:
    event("accepted")
    assert obs in env.observation_space and np.all(np.isfinite(obs))
    assert math.isfinite(reward)
    if info is not None:
        assert math.isfinite(info["running_cost"]) and np.all(np.isfinite(info["positions"]))


# ------------------------------------------------------------------ SwarmParams
@PROPERTY
@given(st.data())
def test_swarm_params_named_error_or_in_range(data):
    kwargs = draw_kwargs(data, PARAM_FIELDS, max_size=5)
    try:
        params = SwarmParams(**kwargs)
    except Exception as error:  # the contract is checked on the error itself
        assert_names_a_bad_argument(error, SwarmParams, {}, kwargs)
        return
    assert_params_in_ranges(params)


# --------------------------------------------------------------------- env kwargs
@PROPERTY
@given(st.data())
def test_env_kwargs_named_error_or_finite_episode(data):
    base = {"n_agents": 3, "n_steps": 2}
    kwargs = {**base, **draw_kwargs(data, ENV_FIELDS)}
    try:
        env = SwarmEnv(**kwargs)
    except Exception as error:
        assert_names_a_bad_argument(error, SwarmEnv, base, kwargs)
        return
    assert np.all(np.isfinite(env.observation_space.low))
    assert np.all(np.isfinite(env.observation_space.high))
    obs, _ = env.reset(seed=data.draw(st.integers(0, 2**32)))
    assert_gym_outputs_finite(env, obs)
    env.action_space.seed(0)
    done = False
    while not done:
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert_gym_outputs_finite(env, obs, reward, info)
        done = terminated or truncated


# -------------------------------------------------------------------------- actions
ACTION_DTYPES = st.one_of(
    hnp.floating_dtypes(),
    hnp.integer_dtypes(),
    hnp.unsigned_integer_dtypes(),
    hnp.boolean_dtypes(),
    hnp.complex_number_dtypes(),
    hnp.unicode_string_dtypes(max_len=2),
)


def arrays_and_junk(shape_choices) -> st.SearchStrategy:
    """Arrays of any dtype and of the given shapes (the first is the valid one), lists, junk."""
    valid = hnp.arrays(np.float64, shape_choices[0], elements=st.floats(-1e6, 1e6))
    return st.one_of(
        valid,
        hnp.arrays(ACTION_DTYPES, st.sampled_from(shape_choices)),
        hnp.arrays(np.float32, st.sampled_from(shape_choices), elements=st.floats(-3, 3, width=32)),
        st.lists(st.one_of(st.floats(), st.integers(-(2**80), 2**80)), max_size=7),
        JUNK,
    )


@PROPERTY
@given(action=arrays_and_junk([(6,), (3, 2), (5,), (6, 1), ()]), dim=st.sampled_from([1, 2]))
def test_action_named_error_or_finite_step(action, dim):
    env = SwarmEnv(n_agents=6 // dim, dim=dim, n_steps=2)
    env.reset(seed=0)
    try:
        obs, reward, _, _, info = env.step(action)
    except (TypeError, ValueError) as error:
        assert_names_one_of(error, ["action"])
        assert env.step_index == 0
        return
    assert_gym_outputs_finite(env, obs, reward, info)
    assert np.all(np.abs(info["control"]) <= env.max_control)


# -------------------------------------------------------------------- reset options
@PROPERTY
@given(
    positions=arrays_and_junk([(3,), (3, 1), (2,)]) | st.just(np.array([0.0, 1e4, -1e4])),
    target=targets(),
    use=st.sampled_from(["initial_positions", "target", "both"]),
)
def test_reset_options_named_error_or_finite_observation(positions, target, use):
    options = {
        "initial_positions": {"initial_positions": positions},
        "target": {"target": target},
        "both": {"initial_positions": positions, "target": target},
    }[use]
    env = SwarmEnv(n_agents=3, n_steps=2)
    try:
        obs, _ = env.reset(seed=0, options=options)
    except (TypeError, ValueError) as error:
        assert_names_one_of(error, options)
        return
    assert_gym_outputs_finite(env, obs)
    obs, reward, _, _, info = env.step(np.ones(3, dtype=np.float32))
    assert_gym_outputs_finite(env, obs, reward, info)


# ------------------------------------------------------------ PettingZoo action dicts
@PROPERTY
@given(
    entries=st.lists(
        st.one_of(
            *[hnp.arrays(np.float32, (2,), elements=st.floats(-2, 2, width=32))] * 3,
            arrays_and_junk([(2,), (1,), (), (2, 1)]),
        ),
        min_size=3,
        max_size=3,
    ),
    keep=st.lists(st.sampled_from([True] * 6 + [False]), min_size=3, max_size=3),
    extra=st.sampled_from([False] * 6 + [True]),
)
def test_pettingzoo_action_dict_named_error_or_finite_step(entries, keep, extra):
    par_env = swarm_v0.parallel_env(n_agents=3, dim=2, n_steps=2)
    par_env.reset(seed=0)
    actions = {a: v for a, v, k in zip(par_env.agents, entries, keep, strict=True) if k}
    if extra:
        actions["agent_9"] = np.zeros(2)
    try:
        obs, rewards, _, _, infos = par_env.step(actions)
    except (TypeError, ValueError) as error:
        assert_names_one_of(error, ["actions"])
        assert par_env.step_index == 0
        return
    event("accepted")
    for agent, o in obs.items():
        assert o in par_env.observation_space(agent) and np.all(np.isfinite(o))
        assert math.isfinite(rewards[agent]) and math.isfinite(infos[agent]["running_cost"])


# ------------------------------------------------------------------------- simulate
SIMULATE_FIELDS = {
    "n_steps": ints(1, 3, 10**9),
    "n_paths": ints(1, 3, 10**6),
    "divergence_threshold": reals(DIVERGENCE_THRESHOLD_RANGE),
    "seed": st.one_of(st.integers(0, 2**70), st.integers(-5, -1), JUNK),
    "integrator": st.sampled_from(["em", "serb", "heun", "rk4", None]),
    "initial_positions": arrays_and_junk([(3,), (3, 1), (4,)]),
    "control": st.one_of(
        st.none(),
        hnp.arrays(np.float64, (2, 3, 1), elements=st.floats(allow_nan=True, allow_infinity=True)),
        hnp.arrays(ACTION_DTYPES, (2, 3)),
    ),
}


@PROPERTY
@given(st.data())
def test_simulate_named_error_or_finite_trajectory(data):
    base = {"n_steps": 2, "n_paths": 2, "seed": 0}
    kwargs = {**base, **draw_kwargs(data, SIMULATE_FIELDS)}
    params = SwarmParams(n_agents=3, epsilon=data.draw(st.sampled_from([0.05, 1e-12])))
    try:
        traj = simulate(params, **kwargs)
    except (TypeError, ValueError) as error:
        assert_names_a_bad_argument(error, lambda **kw: simulate(params, **kw), base, kwargs)
        return
    event("accepted, diverged" if traj.diverged else "accepted")
    kept = traj.positions[: traj.divergence_step or None]
    assert np.all(np.isfinite(kept)) and np.all(np.isfinite(traj.controls))
    assert np.all(np.abs(kept) <= kwargs.get("divergence_threshold", 1e4))
    if not traj.diverged:
        assert np.all(np.isfinite(traj.positions))


@pytest.mark.parametrize("kwargs", [{"n_steps": 2.0}, {"seed": "1"}, {"integrator": 3}])
def test_simulate_examples_the_properties_rely_on(kwargs):
    """A few named errors the strategies above must be able to hit."""
    with pytest.raises((TypeError, ValueError), match=next(iter(kwargs))):
        simulate(SwarmParams(n_agents=3), **kwargs)
