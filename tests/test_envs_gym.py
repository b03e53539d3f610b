"""Gymnasium env `agent_envs/Swarm-v0`: registration, checkers, reward identity, seeding."""

from __future__ import annotations

import math
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env, data_equivalence

import agent_envs
from agent_envs import INTEGRATORS, SwarmModel, make_integrator
from agent_envs.costs import discrete_cost
from agent_envs.draws import brownian_increments, uniform_positions
from agent_envs.envs import DEFAULT_MAX_CONTROL, ENV_ID, SwarmEnv, split_observation

SMALL = {"n_agents": 6, "n_steps": 10}


def rollout(env: gym.Env, seed: int, actions: np.ndarray, options=None):
    """Reset with `seed`, apply `actions` until the episode ends; return everything."""
    obs, info = env.reset(seed=seed, options=options)
    out = {"obs": [obs], "rewards": [], "terminated": [], "truncated": [], "infos": [info]}
    for action in actions:
        obs, reward, terminated, truncated, info = env.step(action)
        out["obs"].append(obs)
        out["rewards"].append(reward)
        out["terminated"].append(terminated)
        out["truncated"].append(truncated)
        out["infos"].append(info)
        if terminated or truncated:
            break
    return out


def random_actions(env: gym.Env, n: int, seed: int = 0, scale: float = 1.5) -> np.ndarray:
    """Actions in [-scale, scale] (some outside the Box on purpose: they are clipped)."""
    rng = np.random.default_rng(seed)
    return rng.uniform(-scale, scale, (n, *env.action_space.shape)).astype(np.float32)


# ----------------------------------------------------------------- registration
def test_registered_on_import():
    assert ENV_ID == "agent_envs/Swarm-v0"
    assert ENV_ID in gym.registry
    assert agent_envs.SwarmEnv is SwarmEnv


@pytest.mark.parametrize("n_steps", [7, 50, 63])
def test_time_limit_follows_n_steps(n_steps):
    """Exactly n_steps steps, truncated only at the last, below and above the default m = 50."""
    env = gym.make(ENV_ID, n_agents=4, n_steps=n_steps)
    assert env.spec.max_episode_steps == n_steps
    assert isinstance(env.unwrapped, SwarmEnv)
    env.reset(seed=0)
    flags = []
    for _ in range(n_steps):
        _, _, terminated, truncated, info = env.step(np.zeros(4, dtype=np.float32))
        flags.append((terminated, truncated))
        if terminated or truncated:
            break
    assert len(flags) == n_steps
    assert flags[-1] == (False, True)
    assert all(f == (False, False) for f in flags[:-1])
    assert info["time"] == pytest.approx(1.0)
    env.close()


def test_defaults_are_the_paper_setting():
    env = SwarmEnv()
    p = env.params
    assert (p.n_agents, p.dim, p.kernel) == (100, 1, "symmetric")
    assert (p.epsilon, p.alpha, p.sigma, p.horizon, p.target) == (0.05, 0.1, 0.01, 1.0, 0.7)
    assert (env.n_steps, env.n_paths, env.integrator_name, env.jacobian) == (
        50,
        1,
        "serb",
        "frozen",
    )
    assert env.max_control == DEFAULT_MAX_CONTROL == 150.0
    assert env.dt == pytest.approx(0.02)
    assert env.action_space.shape == (100,) and env.action_space.dtype == np.float32
    assert env.observation_space.shape == (2 * 100 + 1 + 1,)
    assert env.observation_space.dtype == np.float32
    assert isinstance(env.model, SwarmModel)


# --------------------------------------------------------------------- checkers
@pytest.mark.parametrize("dim", [1, 2])
def test_gymnasium_check_env(dim):
    target = 0.7 if dim == 1 else (0.5, -0.3)
    env = gym.make(ENV_ID, dim=dim, target=target, **SMALL)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)  # also makes the env in every render mode from its spec
    env.close()


def test_stable_baselines3_check_env():
    sb3_checker = pytest.importorskip("stable_baselines3.common.env_checker")
    env = gym.make(ENV_ID, **SMALL)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sb3_checker.check_env(env.unwrapped, warn=True)
    env.close()


def test_step_returns_python_types():
    env = SwarmEnv(**SMALL)
    obs, reset_info = env.reset(seed=1)
    keys = {"positions", "control", "time", "running_cost", "diverged"}
    assert set(reset_info) == keys  # the same keys as a step's info (TorchRL needs them)
    assert reset_info["running_cost"] == 0.0 and not np.any(reset_info["control"])
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert type(reward) is float and type(terminated) is bool and type(truncated) is bool
    assert obs.dtype == np.float32 and obs in env.observation_space
    assert set(info) == keys
    for key in keys:
        assert np.shape(info[key]) == np.shape(reset_info[key])
        assert np.asarray(info[key]).dtype == np.asarray(reset_info[key]).dtype
    assert info["positions"].shape == (1, 6, 1) and info["control"].shape == (6, 1)
    assert type(info["diverged"]) is bool
    assert info["time"] == pytest.approx(env.dt)


# --------------------------------------------------------------- reward identity
@pytest.mark.parametrize("n_paths", [1, 4])
def test_rewards_sum_to_minus_discrete_cost(n_paths):
    """sum_n r^n = -tau sum_n c(x^n, u^n) (eq:discrete_cost_functional) on the env's paths."""
    env = SwarmEnv(n_paths=n_paths, **SMALL)
    actions = random_actions(env, env.n_steps, seed=n_paths)
    out = rollout(env, 11, actions)
    assert out["truncated"][-1] and len(out["rewards"]) == env.n_steps
    positions = np.stack([info["positions"] for info in out["infos"]])  # (m+1, paths, N, d)
    controls = np.stack([info["control"] for info in out["infos"][1:]])  # (m, N, d)
    assert positions.shape == (env.n_steps + 1, n_paths, 6, 1)
    expected_u = env.max_control * np.clip(actions, -1, 1).astype(np.float64)[..., None]
    np.testing.assert_array_equal(controls, expected_u)
    cost = discrete_cost(
        positions,
        controls[:, None],  # same control on every path
        env.params.target_vector,
        env.params.gamma,
        env.dt,
    )
    assert cost.shape == (n_paths,)
    total = math.fsum(out["rewards"])
    assert total == pytest.approx(-float(np.mean(cost)), rel=1e-12)
    running = [info["running_cost"] for info in out["infos"][1:]]
    np.testing.assert_allclose(-env.dt * np.array(running), out["rewards"], rtol=1e-15)


# ------------------------------------------------------------ seeding, dynamics
@pytest.mark.parametrize(
    ("integrator", "jacobian"),
    [(name, "frozen") for name in sorted(INTEGRATORS)] + [("serb", "exact"), ("erb", "exact")],
)
def test_same_seed_same_episode(integrator, jacobian):
    kwargs = {"integrator": integrator, "jacobian": jacobian, "n_paths": 2, **SMALL}
    env1, env2 = SwarmEnv(**kwargs), SwarmEnv(**kwargs)
    actions = random_actions(env1, env1.n_steps, seed=3)
    a, b = rollout(env1, 42, actions), rollout(env2, 42, actions)
    for key in a:
        assert data_equivalence(a[key], b[key], exact=True), key
    c = rollout(env1, 43, actions)
    assert not data_equivalence(a["obs"], c["obs"])


def test_env_steps_the_core_integrator_with_its_np_random():
    """The env's positions are exactly make_integrator(...).step on draws from np_random."""
    env = SwarmEnv(n_paths=3, integrator="serb", **SMALL)
    actions = random_actions(env, 5, seed=5)
    out = rollout(env, 7, actions)
    rng = np.random.default_rng(7)  # what gymnasium's seeding.np_random(7) builds
    params = env.params
    x = np.broadcast_to(uniform_positions(rng, 6, 1), (3, 6, 1)).copy()
    model, scheme = SwarmModel(params), make_integrator("serb")
    np.testing.assert_array_equal(out["infos"][0]["positions"], x)
    for n, action in enumerate(actions):
        u = env.max_control * np.clip(action.astype(np.float64), -1, 1)[:, None]
        x = scheme.step(model, x, u, n * env.dt, env.dt, brownian_increments(rng, x.shape, env.dt))
        np.testing.assert_array_equal(out["infos"][n + 1]["positions"], x)
    obs = split_observation(out["obs"][-1], 6, 1)
    np.testing.assert_allclose(obs["positions"], x.mean(axis=0), rtol=1e-6)
    drift = model.interaction_drift(x).mean(axis=0)
    np.testing.assert_allclose(obs["interaction_drift"], drift, rtol=1e-5, atol=1e-5)
    assert obs["time_fraction"] == pytest.approx(5 / env.n_steps)


# ------------------------------------------------------------------ reset options
def test_reset_options_initial_positions_and_target():
    env = SwarmEnv(**SMALL)
    env.reset(seed=0)
    model = env.model
    x0 = np.linspace(-0.5, 0.5, 6)
    for given in (x0, x0[:, None]):
        obs, info = env.reset(seed=0, options={"initial_positions": given, "target": -1.7})
        parts = split_observation(obs, 6, 1)
        np.testing.assert_allclose(parts["positions"][:, 0], x0, rtol=1e-6)
        np.testing.assert_array_equal(info["positions"][0, :, 0], x0)
        assert parts["target"][0] == pytest.approx(-1.7)
        assert env.params.target == -1.7
        # the target is a cost parameter: the dynamics model (and kernel) is not rebuilt
        assert env.model is model
    obs, _ = env.reset(seed=0)  # options last for one episode only
    assert split_observation(obs, 6, 1)["target"][0] == pytest.approx(0.7)
    assert env.model is model


def test_initial_positions_do_not_change_the_noise():
    env = SwarmEnv(n_paths=2, **SMALL)
    actions = random_actions(env, 4, seed=2)
    a = rollout(env, 9, actions)
    start = a["infos"][0]["positions"][0]
    b = rollout(env, 9, actions, options={"initial_positions": start})
    for key in ("obs", "rewards"):
        assert data_equivalence(a[key], b[key], exact=True)


def test_two_dimensional_env():
    env = SwarmEnv(dim=2, target=(0.5, -0.5), **SMALL)
    assert env.action_space.shape == (12,)
    assert env.observation_space.shape == (2 * 12 + 2 + 1,)
    x0 = np.zeros((6, 2)) + np.arange(6)[:, None] * 0.1
    obs, _ = env.reset(seed=0, options={"initial_positions": x0, "target": [1.0, 2.0]})
    parts = split_observation(obs, 6, 2)
    np.testing.assert_allclose(parts["positions"], x0, rtol=1e-6)
    np.testing.assert_allclose(parts["target"], [1.0, 2.0])
    out = rollout(env, 0, random_actions(env, env.n_steps), {"initial_positions": x0})
    assert out["truncated"][-1] and out["infos"][-1]["positions"].shape == (1, 6, 2)


def test_split_observation_on_a_vector_env_batch():
    envs = gym.make_vec(ENV_ID, num_envs=3, vectorization_mode="sync", **SMALL)
    obs, _ = envs.reset(seed=0)
    parts = split_observation(obs, 6, 1)
    assert parts["positions"].shape == (3, 6, 1)
    assert parts["interaction_drift"].shape == (3, 6, 1)
    assert parts["target"].shape == (3, 1) and parts["time_fraction"].shape == (3,)
    np.testing.assert_allclose(parts["target"], 0.7)
    np.testing.assert_array_equal(parts["time_fraction"], 0.0)
    envs.close()


# ------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    ("kwargs", "error", "name"),
    [
        ({"integrator": "rk4"}, ValueError, "integrator"),
        ({"jacobian": "numeric"}, ValueError, "jacobian"),
        ({"epsilon": -0.05}, ValueError, "epsilon"),
        ({"n_steps": 0}, ValueError, "n_steps"),
        ({"n_steps": 2.5}, TypeError, "n_steps"),
        ({"n_paths": 0}, ValueError, "n_paths"),
        ({"max_control": -1.0}, ValueError, "max_control"),
        ({"divergence_threshold": 0.0}, ValueError, "divergence_threshold"),
        ({"target": (0.1, 0.2)}, ValueError, "target"),
        ({"target": 2e4}, ValueError, "target"),
        ({"render_mode": "ansi"}, ValueError, "render_mode"),
        ({"n_agentz": 5}, TypeError, "n_agentz"),
    ],
)
@pytest.mark.filterwarnings("ignore:.*render_mode='ansi'.*:UserWarning")  # gym.make's own warning
def test_bad_kwargs_name_the_argument(kwargs, error, name):
    with pytest.raises(error, match=name):
        SwarmEnv(**kwargs)
    with pytest.raises(error, match=name):
        gym.make(ENV_ID, **kwargs)


def test_bad_reset_options_and_actions():
    env = SwarmEnv(**SMALL)
    with pytest.raises(ValueError, match="initial_positions"):
        env.reset(options={"initial_positions": np.zeros(5)})
    with pytest.raises(ValueError, match="initial_positions"):
        env.reset(options={"initial_positions": np.full(6, np.nan)})
    with pytest.raises(ValueError, match="target"):
        env.reset(options={"target": [0.0, 1.0]})
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(np.full(6, np.nan, dtype=np.float32))
    with pytest.raises(ValueError, match="action"):
        env.step(np.zeros(5, dtype=np.float32))
    with pytest.raises(TypeError, match="action"):
        env.step(["a"] * 6)
    assert env.step_index == 0  # nothing was stepped by the bad calls


def test_out_of_range_actions_are_clipped():
    env = SwarmEnv(**SMALL)
    env.reset(seed=4)
    _, r_big, _, _, info_big = env.step(np.full(6, 7.0, dtype=np.float32))
    env.reset(seed=4)
    _, r_one, _, _, info_one = env.step(np.ones(6, dtype=np.float32))
    np.testing.assert_array_equal(info_big["control"], env.max_control)
    assert r_big == r_one
    np.testing.assert_array_equal(info_big["positions"], info_one["positions"])


def test_step_after_the_end_raises():
    env = SwarmEnv(n_agents=3, n_steps=2)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(3, dtype=np.float32))
    env.reset(seed=0)
    env.step(np.zeros(3, dtype=np.float32))
    env.step(np.zeros(3, dtype=np.float32))
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(3, dtype=np.float32))


def test_a_misshapen_action_names_both_accepted_shapes():
    env = SwarmEnv(dim=2, target=(0.5, -0.3), n_agents=6, n_steps=3)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action must have shape \(12,\) or \(6, 2\), got \(6,\)"):
        env.step(np.zeros(6, dtype=np.float32))


# ------------------------------------------------------------------- divergence
@pytest.mark.parametrize(
    "kwargs",
    [
        # Euler-Maruyama on a very stiff kernel with few steps jumps by ~1e5 in one step.
        {"integrator": "em", "epsilon": 1e-6, "n_agents": 20, "n_steps": 3},
        # a tiny threshold: the full control leaves [-2, 2] in the first steps.
        {"divergence_threshold": 2.0, "n_agents": 6, "n_steps": 10},
    ],
)
def test_divergence_terminates_with_finite_outputs(kwargs):
    env = SwarmEnv(**kwargs)
    n = kwargs["n_agents"]
    actions = np.full((kwargs["n_steps"], n), 0.0 if "epsilon" in kwargs else 1.0, np.float32)
    out = rollout(env, 0, actions)
    assert out["terminated"][-1] is True and out["truncated"][-1] is False
    assert out["infos"][-1]["diverged"] is True
    assert all(info["diverged"] is False for info in out["infos"][:-1])
    assert len(out["rewards"]) < kwargs["n_steps"]
    assert all(math.isfinite(r) for r in out["rewards"])
    assert all(np.all(np.isfinite(o)) and o in env.observation_space for o in out["obs"])
    last = out["infos"][-1]["positions"]
    assert np.all(np.isfinite(last))
    np.testing.assert_array_equal(last, out["infos"][-2]["positions"])  # last finite state
    # the identity still holds: the diverging step is charged at its (finite) start state
    positions = np.stack([info["positions"] for info in out["infos"]])
    controls = np.stack([info["control"] for info in out["infos"][1:]])
    cost = discrete_cost(positions, controls[:, None], env.params.target_vector, 0.01, env.dt)
    assert math.fsum(out["rewards"]) == pytest.approx(-float(cost.mean()), rel=1e-12)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(actions[0])


# -------------------------------------------------------------- the paper setting
@pytest.mark.parametrize(
    ("kernel", "target"), [("symmetric", 0.7), ("symmetric", -1.7), ("nonsymmetric", 2.3)]
)
def test_turnpike_control_is_not_clipped_in_the_paper_setting(kernel, target):
    """beta (xbar - E x) - E drift, switched off at tbar (eq:tptime), stays within max_control."""
    env = SwarmEnv(kernel=kernel, target=target)
    beta, delta = 12.0, 2e-4
    obs, info = env.reset(seed=0)
    x0 = info["positions"][0]
    tbar = math.log(delta / np.sum((x0 - target) ** 2)) / (-2 * beta)
    largest, done = 0.0, False
    while not done:
        parts = split_observation(obs, 100, 1)
        if env.time < tbar:
            u = beta * (parts["target"] - parts["positions"]) - parts["interaction_drift"]
        else:
            u = np.zeros((100, 1))
        largest = max(largest, float(np.max(np.abs(u))))
        obs, _, terminated, truncated, info = env.step((u / env.max_control).reshape(-1))
        done = terminated or truncated
    assert not terminated
    assert 30.0 < largest <= env.max_control
    mean_final = float(np.mean(info["positions"]))
    assert abs(mean_final - target) < 0.05  # the turnpike reaches the target


# -------------------------------------------------------------------- rendering
@pytest.mark.parametrize("dim", [1, 2])
def test_rgb_array_frames(dim):
    env = SwarmEnv(dim=dim, render_mode="rgb_array", **SMALL)
    env.reset(seed=0)
    for _ in range(3):
        env.step(env.action_space.sample())
    frame = env.render()
    assert isinstance(frame, np.ndarray) and frame.dtype == np.uint8
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.shape[0] > 100
    assert frame.std() > 0  # something was drawn
    env.close()
    env.close()


def test_the_first_frame_shows_the_initial_positions():
    # at t = 0 there is no trace yet (a line of one point draws nothing): the frame must still
    # show where the agents start, as dots in the agents' colour (an animation's first frame)
    blue = np.array([31, 119, 180])  # matplotlib's tab:blue
    counts = []
    for n_agents in (3, 12):
        env = SwarmEnv(dim=1, render_mode="rgb_array", n_agents=n_agents, n_steps=10)
        env.reset(seed=0)
        frame = env.render().astype(int)
        env.close()
        counts.append(int((np.abs(frame - blue).sum(axis=-1) < 60).sum()))
    assert counts[0] > 0 and counts[1] > counts[0]  # more agents, more dots


def test_human_mode_with_a_non_interactive_backend_is_silent():
    env = SwarmEnv(render_mode="human", **SMALL)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env.reset(seed=0)
        env.step(env.action_space.sample())
        assert env.render() is None
    env.close()


@pytest.mark.parametrize("integrator", ["serb", "em"])
def test_kernel_matrix_is_built_once_per_step(monkeypatch, integrator):
    """The observation's drift and the next integrator step share L(x) (see episode.py)."""
    import agent_envs.dynamics.swarm as swarm_module

    env = SwarmEnv(n_paths=2, integrator=integrator, **SMALL)
    env.reset(seed=0)
    calls = []
    # the numpy passes or, with numba, the compiled pass that replaces them
    for name in ("fill_cucker_smale", "compiled_cucker_smale_drift"):
        original = getattr(swarm_module, name)
        monkeypatch.setattr(
            swarm_module, name, lambda *a, _f=original, **k: calls.append(1) or _f(*a, **k)
        )
    for _ in range(3):
        env.step(env.action_space.sample())
    assert len(calls) == 3  # one per new state; without the cache it would be 6


def test_kernel_matrix_of_a_user_kernel_is_built_once_per_step():
    """The same on the Array-API path (a kernel that is not a CuckerSmaleKernel)."""
    from agent_envs.dynamics.kernels import CuckerSmaleKernel

    class Wrapped:
        symmetric = True
        radial = True

        def __init__(self) -> None:
            self.inner = CuckerSmaleKernel.symmetric_kernel(0.1, 0.05)
            self.calls = 0

        def value(self, xk, xl):
            self.calls += 1
            return self.inner.value(xk, xl)

        def grad_x(self, xk, xl):
            return self.inner.grad_x(xk, xl)

        def grad_y(self, xk, xl):
            return self.inner.grad_y(xk, xl)

    kernel = Wrapped()
    env = SwarmEnv(n_paths=2, **{**SMALL, "kernel": kernel})
    env.reset(seed=0)
    before = kernel.calls
    for _ in range(3):
        env.step(env.action_space.sample())
    assert kernel.calls - before == 3


def test_misspelt_reset_option_is_rejected_naming_it():
    env = gym.make("agent_envs/Swarm-v0", n_agents=5, n_steps=4)
    with pytest.raises(ValueError, match="initial_position"):
        env.reset(seed=0, options={"initial_position": np.zeros(5)})
    with pytest.raises(TypeError, match="options"):
        env.reset(seed=0, options=[1, 2])
