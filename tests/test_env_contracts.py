"""Contracts of the env modules that their mutation run found untested (issue 39).

Each test states a property of a public entry point: the PettingZoo env's action checks
(every accepted form gives the step of the (d,) float arrays; every refused one names the
agent), the human render mode drawing at reset and step, the two adapters' frames and
metadata agreeing, an episode's divergence ending it, the agent rewards' two modes, the
`StepOutcome` record being frozen, and the compiled step's load check (`same_as_numpy`)
feeding the corners it is documented to cover.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest

from agent_envs import native, swarm_v0
from agent_envs.envs import SwarmEnv, SwarmParallelEnv, compiled_agents, fast_step
from agent_envs.envs.episode import mean_running_cost
from agent_envs.envs.interface import controls_from_actions

SMALL = {"n_agents": 5, "n_steps": 8}


def _stepped(par_env: SwarmParallelEnv, actions: dict[str, Any]) -> tuple[Any, ...]:
    """(observations, rewards) of one step from a seeded reset, as arrays to compare."""
    par_env.reset(seed=3)
    obs, rewards, *_ = par_env.step(actions)
    return np.stack(list(obs.values())), np.array(list(rewards.values()))


def _assert_same_step(dim: int, actions: dict[str, Any]) -> None:
    """The step under `actions` equals the one under the same values as (d,) float64 arrays."""
    env = swarm_v0.parallel_env(dim=dim, **SMALL)
    want = {a: np.asarray(v, dtype=np.float64).reshape(dim) for a, v in actions.items()}
    got_obs, got_rewards = _stepped(env, actions)
    want_obs, want_rewards = _stepped(env, want)
    np.testing.assert_array_equal(got_obs, want_obs)
    np.testing.assert_array_equal(got_rewards, want_rewards)


# ------------------------------------------------------------- PettingZoo actions
def test_list_and_python_float_actions_step_as_arrays():
    env = swarm_v0.parallel_env(**SMALL)
    _assert_same_step(1, {a: [0.25 * k - 0.5] for k, a in enumerate(env.possible_agents)})
    _assert_same_step(1, {a: 0.25 * k - 0.5 for k, a in enumerate(env.possible_agents)})


def test_scalar_actions_of_a_one_dimensional_swarm_mix_with_rows():
    """For d = 1 an action may be a 0-d array or a (1,) one, also mixed in one dict."""
    env = swarm_v0.parallel_env(**SMALL)
    mixed = {
        a: np.array(0.3 * k - 0.6) if k % 2 else np.array([0.3 * k - 0.6])
        for k, a in enumerate(env.possible_agents)
    }
    _assert_same_step(1, mixed)
    _assert_same_step(1, {a: np.array(v).reshape(()) for a, v in mixed.items()})


def test_strided_rows_step_as_their_contiguous_copies():
    """Rows that are views with a stride (columns of a (d, N) array) are read as values."""
    env = swarm_v0.parallel_env(dim=2, **SMALL)
    columns = np.linspace(-0.8, 0.8, 10).reshape(2, 5)
    assert not columns[:, 0].flags.c_contiguous
    _assert_same_step(2, {a: columns[:, k] for k, a in enumerate(env.possible_agents)})


@pytest.mark.parametrize(
    ("dim", "value", "shape"),
    [(1, np.zeros((1, 1)), "(1, 1)"), (2, np.float64(0.0), "()"), (2, np.zeros(()), "()")],
)
def test_action_of_another_shape_is_refused_naming_the_agent(dim, value, shape):
    env = swarm_v0.parallel_env(dim=dim, **SMALL)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=rf"actions\['agent_0'\] must have shape .*{shape}"):
        env.step(dict.fromkeys(env.possible_agents, value))


@pytest.mark.parametrize(("missing", "ellipsis"), [(5, False), (6, True)])
def test_missing_agents_listed_five_at_most(missing, ellipsis):
    env = swarm_v0.parallel_env(n_agents=8, n_steps=4)
    env.reset(seed=0)
    kept = env.possible_agents[missing:]
    with pytest.raises(ValueError) as raised:
        env.step({a: np.zeros(1) for a in kept})
    message = str(raised.value)
    listed = [f"agent_{k}" for k in range(5)]
    assert all(f"'{a}'" in message for a in listed)
    assert "'agent_5'" not in message
    assert ("]..." in message) is ellipsis


# ------------------------------------------------------------------ rendering
def _count_renders(env: Any) -> list[int]:
    calls = [0]
    render = env.render

    def counted() -> Any:
        calls[0] += 1
        return render()

    env.render = counted
    return calls


@pytest.mark.parametrize("make", [SwarmEnv, swarm_v0.parallel_env])
@pytest.mark.parametrize(("mode", "draws"), [("human", 2), ("rgb_array", 0)])
def test_human_mode_draws_at_reset_and_step(monkeypatch, make, mode, draws):
    """Gymnasium's and PettingZoo's contract: "human" renders in reset and step by itself,
    "rgb_array" only when asked."""
    monkeypatch.setattr("matplotlib.pyplot.pause", lambda *_: None)
    env = make(render_mode=mode, **SMALL)
    calls = _count_renders(env)
    env.reset(seed=0)
    if isinstance(env, SwarmEnv):
        env.step(np.zeros(5, np.float32))
    else:
        env.step({a: np.zeros(1, np.float32) for a in env.possible_agents})
    assert calls[0] == draws
    env.close()


def test_the_two_adapters_render_the_same_frames():
    """One renderer for both: the same metadata, and from the same seed and controls the same
    pixels after reset and after a step."""
    for key in ("render_modes", "render_fps"):
        assert SwarmEnv.metadata[key] == SwarmParallelEnv.metadata[key]
    gym_env = SwarmEnv(render_mode="rgb_array", dim=2, **SMALL)
    par_env = swarm_v0.parallel_env(render_mode="rgb_array", dim=2, **SMALL)
    gym_env.reset(seed=4)
    par_env.reset(seed=4)
    np.testing.assert_array_equal(gym_env.render(), par_env.render())
    actions = np.linspace(-0.5, 0.5, 10).reshape(5, 2)
    gym_env.step(actions)
    par_env.step({a: actions[k] for k, a in enumerate(par_env.possible_agents)})
    np.testing.assert_array_equal(gym_env.render(), par_env.render())
    gym_env.close()
    par_env.close()


def test_threads_load_in_the_first_reset(monkeypatch):
    """The threaded passes' one-time load (numba's threads start there) falls in reset, not in
    the constructor (a fork after it loses its children) nor in a step."""
    try:
        env = SwarmEnv(num_threads=2, **SMALL)
    except ValueError:  # (no numba, or it allows one thread here)
        pytest.skip("no two threads of the compiled passes here")
    loads: list[int] = []
    monkeypatch.setattr(native, "load_compiled_threads", loads.append)
    env.reset(seed=0)
    assert loads == [2]


# -------------------------------------------------------------------- episode
def test_a_diverged_step_ends_the_episode():
    """`SwarmEpisode.step` (the numpy step): a diverged step keeps x^n, marks the episode done,
    and a further step raises."""
    env = SwarmEnv(divergence_threshold=2.0, **SMALL)
    env.reset(seed=0)
    episode, rng = env.episode, np.random.default_rng(0)
    push = np.full((5, 1), 150.0)
    for _ in range(SMALL["n_steps"]):
        before = episode.positions
        outcome = episode.step(rng, push)
        if outcome.diverged:
            break
    assert outcome.diverged and not outcome.truncated
    assert episode.diverged and episode.done
    np.testing.assert_array_equal(episode.positions, before)
    with pytest.raises(RuntimeError, match="over"):
        episode.step(rng, push)


@pytest.mark.parametrize("make", [SwarmEnv, swarm_v0.parallel_env])
def test_a_new_env_has_taken_no_steps(make):
    """Before the first reset the episode counts no steps (n = 0, t_0 = 0)."""
    env = make(**SMALL)
    assert env.episode.step_index == 0 and env.episode.time_fraction == 0.0
    assert not env.episode.done


@pytest.mark.parametrize("mode", ["own", "team"])
def test_agent_rewards_follow_the_agent_reward_mode(mode):
    env = swarm_v0.parallel_env(agent_reward=mode, **SMALL)
    env.reset(seed=1)
    episode = env.episode
    outcome = episode.step(np.random.default_rng(1), np.linspace(-20.0, 20.0, 5)[:, None])
    rewards = episode.agent_rewards(outcome)
    if mode == "team":
        np.testing.assert_array_equal(rewards, np.full(5, episode.reward(outcome)))
    else:
        want = -(episode.dt / 5) * episode.agent_costs(outcome)
        np.testing.assert_array_equal(rewards, want)
        assert rewards.sum() == pytest.approx(episode.reward(outcome), rel=1e-12)
        assert np.ptp(rewards) > 0


def test_step_outcome_is_a_frozen_record():
    env = SwarmEnv(**SMALL)
    env.reset(seed=0)
    outcome = env.episode.step(np.random.default_rng(0), np.zeros((5, 1)))
    with pytest.raises(dataclasses.FrozenInstanceError):
        outcome.running_cost = 0.0  # type: ignore[misc]


# ------------------------------------------------------- the compiled step's check
class _ReferenceModule:
    """A stand-in for the compiled step module: `prologue` is the numpy step's (what the check
    compares against) and records its inputs; `epilogue` records its inputs and writes
    nothing (the check then fails there, after one call)."""

    def __init__(self) -> None:
        self.prologues: list[tuple[np.ndarray, ...]] = []
        self.epilogues: list[tuple[np.ndarray, float]] = []

    def prologue(self, actions, max_control, x, drift, targets, gamma, controls, costs, rhs):
        self.prologues.append((actions.copy(), x, drift))
        if not np.all(np.isfinite(actions)):
            return False
        basis = "agents" if actions.shape[1] == x.shape[2] else "common"
        u = controls_from_actions(actions.astype(np.float64), basis, max_control, x.shape[2])
        controls[...] = u
        costs[...] = mean_running_cost(x, u, targets, gamma)
        rhs[...] = drift + u[:, None]
        return True

    def epilogue(self, x_next, drift, threshold, *rest):
        self.epilogues.append((x_next, threshold))


def test_the_load_check_feeds_the_corners_it_promises():
    """`same_as_numpy`'s data: read-only states and drifts (the machine code the env runs),
    signed zeros in both, actions inside [-1, 1] and clipped on both sides with a -0.0 among
    them, both dtypes, a non-finite action refused, and one env (the last) diverged."""
    module = _ReferenceModule()
    assert not fast_step.same_as_numpy(module, shapes=((2, 3, 4, 2),))
    calls = module.prologues
    assert [c[0].dtype for c in calls[:4]] == [np.float32] * 2 + [np.float64] * 2
    for actions, x, drift in calls[:4]:
        assert not x.flags.writeable and not drift.flags.writeable
        assert np.signbit(x.flat[0]) and x.flat[0] == 0 and x.flat[1] == 0
        assert np.signbit(drift.flat[-2]) and drift.flat[-2] == 0 and drift.flat[-1] == 0
        assert actions.flat[0] == 0 and np.signbit(actions.flat[0])
    agents = calls[0][0]
    assert agents.min() < -1 and agents.max() > 1
    assert np.any(np.abs(agents) < 1) and np.any((agents > 0) & (agents < 1))
    assert not np.all(np.isfinite(calls[4][0]))
    x_next, threshold = module.epilogues[0]
    beyond = np.any(np.abs(x_next) > threshold, axis=(1, 2, 3))
    assert beyond.tolist() == [False, True]


class _RecordingAgentModule:
    """A stand-in for the compiled per-agent module: records its inputs, writes nothing (the
    check then fails at the first comparison)."""

    def __init__(self) -> None:
        self.costs: list[tuple[np.ndarray, np.ndarray]] = []
        self.rows: list[tuple[np.ndarray, ...]] = []

    def agent_costs(self, x, controls, targets, gamma, out):
        self.costs.append((x, controls.copy()))
        out[...] = np.nan

    def agent_rows(self, means, drifts, targets, fractions, low, high, relative, out):
        self.rows.append((means.copy(), drifts.copy(), low, high))
        out[...] = np.nan


def test_the_agent_check_feeds_the_corners_it_promises():
    """`agents_same_as_numpy`'s data: a read-only state of both signs over six orders of
    magnitude, controls with signed zeros, path means and drifts beyond the observation's
    bounds (the clip cuts) and inside them."""
    module = _RecordingAgentModule()
    assert not compiled_agents.agents_same_as_numpy(module)
    x, controls = module.costs[0]
    assert not x.flags.writeable
    assert np.any(x < -10) and np.any(x > 10) and np.any(np.abs(x) < 1e-2)
    assert controls.flat[0] == 0 and np.signbit(controls.flat[0])
    assert controls.flat[1] == 0 and not np.signbit(controls.flat[1])
    means, drifts = module.rows[0][:2]
    for values, bound in ((means, 1e6), (drifts, 1e5)):
        assert np.any(np.abs(values) > bound) and np.any(np.abs(values) < bound)


# ---------------------------------------------------------------- episode config
def test_config_replace_changes_what_it_names():
    """`EpisodeConfig.replace`: a swarm parameter, a simulation option and an env option, each
    by its env keyword, the rest kept; the properties read the parts."""
    config = SwarmEnv(**SMALL).config
    assert config.replace(n_agents=7).params.n_agents == 7
    assert config.replace(n_agents=7).simulation == config.simulation
    assert config.replace(n_steps=5).simulation.n_steps == 5
    assert config.replace(n_steps=5).params == config.params
    assert config.replace(observation="relative").observation == "relative"
    assert config.replace(n_steps=5).n_steps == 5
    assert config.dt == config.params.horizon / config.simulation.n_steps
    assert config.integrator == config.simulation.integrator
    assert config.jacobian == config.simulation.jacobian
    assert config.phi_method == config.simulation.phi_method
    assert config.n_paths == config.simulation.n_paths
    assert isinstance(config.phi_method, str) and isinstance(config.n_paths, int)


def test_an_option_value_of_the_other_env_is_refused_naming_this_env():
    with pytest.raises(ValueError, match=r"not an option of agent_envs/Swarm-v0; it takes 'own'"):
        SwarmEnv(agent_reward="team", **SMALL)
    with pytest.raises(ValueError, match=r"not an option of agent_envs\.swarm_v0"):
        swarm_v0.parallel_env(action_basis="modes", **SMALL)


# ------------------------------------------------------------------ vector env
def test_vector_plan_follows_the_autoreset_mode():
    """A SAME_STEP autoreset needs the numpy tail after the compiled step (the reset envs'
    observations); NEXT_STEP does not. The repr names every env and the plan."""
    import gymnasium as gym
    from gymnasium.vector import AutoresetMode

    from agent_envs.envs import ENV_ID

    envelopes = {}
    for mode in (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP):
        venv = gym.make_vec(
            ENV_ID, num_envs=2, vectorization_mode="vector_entry_point", n_agents=20,
            integrator="em", autoreset_mode=mode,
        )  # fmt: skip
        envelopes[mode] = venv.unwrapped.plan.envelope
        assert f"num_envs=2, plan: {venv.unwrapped.plan.describe()})" in repr(venv)
    if envelopes[AutoresetMode.NEXT_STEP] == "numpy":
        pytest.skip("no compiled step here")
    assert envelopes == {
        AutoresetMode.NEXT_STEP: "compiled-step",
        AutoresetMode.SAME_STEP: "compiled-step+numpy-tail",
    }
