"""PettingZoo adapter: one agent per swarm member, over the same `SwarmEpisode` core.

Exposed as the versioned module `agent_envs.swarm_v0` (`parallel_env`, `env`, `raw_env`).
"""

from __future__ import annotations

import operator
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv

from agent_envs import native
from agent_envs.envs.attributes import EpisodeAttributes
from agent_envs.envs.compiled_agents import AgentOutputs, compiled_agent_costs
from agent_envs.envs.compiled_episode import CompiledOutcome, compiled_episode_step
from agent_envs.envs.episode import SwarmEpisode
from agent_envs.envs.episode_config import EpisodeConfig, reset_options
from agent_envs.envs.interface import DEFAULT_NEIGHBOURS
from agent_envs.envs.observation import (
    agent_observation_space,
    agent_observations,
    interaction_drift_bound,
    observation_space,
)
from agent_envs.envs.rendering import RENDER_MODES, SwarmRenderer, check_render_mode
from agent_envs.validation import check_seed, real_array

_DTYPE = operator.attrgetter("dtype")
_NDIM = operator.attrgetter("ndim")
_REAL_KINDS = frozenset("iuf")


def _real_numpy_values(values: list[Any]) -> bool:
    """Whether every value is a numpy array or scalar of a real dtype (signed or unsigned int,
    float): the types and dtypes of the N actions collected by C-level maps into sets, then
    checked once per distinct type and dtype."""
    if not all(issubclass(t, (np.ndarray, np.generic)) for t in set(map(type, values))):
        return False
    return all(dtype.kind in _REAL_KINDS for dtype in set(map(_DTYPE, values)))


def _joined_rows(values: list[Any], n: int, d: int) -> np.ndarray | None:
    """The N actions as one new writable (N, d) array where each is a C-contiguous numpy array
    of shape (d,) and all share one real dtype (the common case): their bytes joined in one
    C-level call, the array ``np.asarray(values)`` gives, in a third of its time; None
    otherwise (`_stacked_actions` then stacks and checks as before)."""
    if set(map(type, values)) != {np.ndarray}:
        return None
    dtypes = set(map(_DTYPE, values))
    if len(dtypes) != 1:
        return None
    (dtype,) = dtypes
    if dtype.kind not in _REAL_KINDS or not dtype.isnative or set(map(_NDIM, values)) != {1}:
        return None
    if set(map(len, values)) != {d}:
        return None
    try:
        joined = b"".join(values)
    except (BufferError, TypeError, ValueError):  # (a row that is not C-contiguous)
        return None
    return np.frombuffer(bytearray(joined), dtype=dtype).reshape(n, d)


class SwarmParallelEnv(EpisodeAttributes, ParallelEnv[str, np.ndarray, np.ndarray]):
    r"""The swarm of `agent_envs/Swarm-v0` with each member as its own agent.

    ## Description

    The same controlled SDE (`eq:dynamics`), integrator, seeding and episode as
    `agent_envs.envs.swarm_env.SwarmEnv` (both adapt `agent_envs.envs.episode.SwarmEpisode`),
    but agent ``agent_k`` (k = 0 .. N-1) chooses its own control u_k.

    ## Action Space

    Per agent `Box(-1, 1, (d,), float32)`; u_k = max_control * clip(action_k, -1, 1). Every
    live agent must act each step; a missing or unknown agent, a NaN/infinite entry or a
    wrong shape raises `ValueError`, an action that is not real numbers (strings, bools,
    complex numbers) raises `TypeError` naming the agent. Out-of-range actions are clipped.

    ## Observation Space

    Per agent `Box((3 d + 1,), float32)`, means over the Brownian paths:

    | slice        | content                                                  |
    |--------------|----------------------------------------------------------|
    | [0, d)       | E x_k, the agent's own position                          |
    | [d, 2d)      | E (1/N) sum_l p(x_k, x_l)(x_l - x_k), the drift it feels |
    | [2d, 3d)     | the target xbar                                          |
    | 3d           | t / T                                                    |

    This is enough for a decentralized turnpike policy
    u_k = beta (xbar - E x_k) - E drift_k. `state()` returns the global state, equal to the
    Gymnasium observation vector (`state_space` is its Box).

    With ``observation="local"`` each agent sees no global statistic (not even the drift, a
    mean over the swarm): `Box(((K + 1)(d + 1),))`, K = ``neighbours`` (default 6),

    | slice                  | content                                                  |
    |------------------------|----------------------------------------------------------|
    | [0, d)                 | E x_k - xbar, its own offset to the target               |
    | [d, d + K d)           | E x_l - E x_k for its K nearest agents l, nearest first  |
    | [(K+1) d, (K+1) d + K) | mask: 1 for a neighbour, 0 for an empty slot (N - 1 < K) |
    | (K + 1)(d + 1) - 1     | t / T                                                    |

    (nearest by Euclidean distance between path means, ties to the lower agent index; the
    K-nearest-neighbour communication graph this implies and its cost per step:
    `agent_envs.envs.local_observation`.)

    ## Rewards

    r_k^n = -tau/N (|x_k^n - xbar|^2 + gamma |u_k^n|^2), mean over the paths, at the state at
    the start of the step. sum_k r_k^n is the Gymnasium reward -tau c(x^n, u^n) for the same
    states and controls (up to round-off). With ``agent_reward="team"`` every agent receives the
    swarm's reward -tau c(x^n, u^n) instead (no agent moves the centre, the cost's main term,
    by more than O(1/N) alone; docs page "Env options").

    Units: with c(x, u) = (1/N) sum_k (|x_k - xbar|^2 + gamma |u_k|^2) the swarm's running cost
    and tau = T / m, the swarm's return is -sum_n tau c(x^n, u^n). With ``agent_reward="own"``
    the agents' rewards add up to it, so a mean over agents (BenchMARL's
    ``episode_reward_mean``) is -1/N of it: swarm cost = -N x that mean. With "team" every agent
    has the swarm's reward: swarm cost = -1 x the mean. The info ``running_cost`` is the
    agent's term |x_k - xbar|^2 + gamma |u_k|^2 itself, with no tau / N factor: its reward
    under "own" is -tau / N x it.

    ## Starting State

    As `SwarmEnv`: uniform on [-1, 1]^d from the env's generator, the same for every path;
    `reset(seed=s, options={"initial_positions": x0, "target": xbar})` overrides them for one
    episode. Unknown option keys are ignored here (PettingZoo's own API tests pass one), where
    the Gymnasium env raises `ValueError`.

    ## Episode End

    After m = `n_steps` steps every agent is truncated; on divergence (a path non-finite or
    beyond `divergence_threshold`) every agent is terminated and its info has
    ``diverged=True``. Either way `agents` becomes empty; call `reset()` again.

    ## Arguments

    The keyword arguments of `SwarmEnv`, with the same defaults and accepted ranges (its
    table), `render_mode` included, except the env options: ``observation`` is "absolute",
    "relative" (E x_k - xbar in the first slice), "swarm" (the "relative" row with the
    swarm's centre offset c - xbar and spread sqrt(mean_l (x_l - c)^2) inserted before t / T:
    `Box((5 d + 1,))`) or "local" (Observation Space; ``neighbours`` K, an int in [1, 1024],
    default 6, is its kwarg and refused with any other layout); ``action_basis`` is "agents"
    only (each agent acts for itself); ``agent_reward`` is "own" or "team" (Rewards).
    `state()` keeps the default layout. Bad values raise `ValueError`/`TypeError` naming the
    argument; an unknown keyword raises
    `TypeError("SwarmParallelEnv.__init__() got an unexpected keyword argument 'x'")`.
    `agent_envs.swarm_v0.env()`/`raw_env()` give the AEC env through PettingZoo's
    `parallel_to_aec`.

    ## Info (per agent)

    `time` (after the step), `running_cost` (the agent's term |x_k - xbar|^2 + gamma |u_k|^2,
    mean over the paths, unscaled: no tau / N factor; Units), `diverged` (bool). `reset`
    returns the same keys, with `time` and `running_cost` 0.0 and `diverged` False. Global
    quantities (positions of all paths, the control) are on the env: `positions`,
    `last_control`. Which code a step runs is `plan` (`agent_envs.envs.step_plan.StepPlan`,
    resolved when the env is made; `repr(env)` shows it), its mid-step fallbacks so far
    `plan_fallbacks` (a `Counter`).

    ## Version History

    - v0 (`agent_envs.swarm_v0`): the only version; its changes within v0 are the Gymnasium
      env's (`SwarmEnv`, Version History), which shares the episode core, and the env options
      ``observation`` (its value "local" with the kwarg ``neighbours``) and ``agent_reward``
      (defaults unchanged); `render(mode=...)`.
    """

    metadata: ClassVar[dict[str, Any]] = {
        "name": "swarm_v0",
        "render_modes": ["human", "rgb_array"],
        "render_fps": 10,
        "is_parallelizable": True,
    }

    def __init__(self, render_mode: str | None = None, **kwargs: Any) -> None:
        self.config = EpisodeConfig.from_kwargs(
            f"{type(self).__name__}.__init__", env_kind="pettingzoo", **kwargs
        )
        self.episode = SwarmEpisode(self.config, "pettingzoo")
        self.render_mode = check_render_mode(render_mode)
        # K of observation="local" (unused, and the layouts' default, otherwise)
        self._neighbours = self.config.neighbours or DEFAULT_NEIGHBOURS
        params = self.config.params
        n, d = params.n_agents, params.dim
        self.possible_agents: list[str] = [f"agent_{k}" for k in range(n)]
        self.agents: list[str] = []
        self._agent_index = {agent: k for k, agent in enumerate(self.possible_agents)}
        bound = self.config.divergence_threshold
        drift_bound = interaction_drift_bound(self.episode.model.kernel)
        self.observation_spaces = {
            agent: agent_observation_space(
                d, bound, drift_bound, self.config.observation, self._neighbours
            )
            for agent in self.possible_agents
        }
        self.action_spaces = {
            agent: spaces.Box(-1.0, 1.0, shape=(d,), dtype=np.float32)
            for agent in self.possible_agents
        }
        self.state_space = observation_space(n, d, bound, drift_bound)
        self._obs_space = self.observation_spaces[self.possible_agents[0]]
        self._np_random: np.random.Generator | None = None
        self._np_random_seed: int | None = None
        self.last_control: np.ndarray | None = None
        self._renderer = (
            None
            if self.render_mode is None
            else SwarmRenderer(self.render_mode, params.horizon, self.metadata["render_fps"])
        )
        # the compiled step's constants (`compiled_episode_step`)
        self._compiled_step = self.plan.compiled_step
        self._state_bounds = (self.state_space.low, self.state_space.high)
        self._obs_bounds = (self._obs_space.low, self._obs_space.high)
        # "swarm" and "local": their rows are numpy's, from the means (no compiled rows)
        numpy_rows = self.config.observation in ("swarm", "local")
        relative = self.config.observation == "relative"
        self._agent_outputs = AgentOutputs(None if numpy_rows else self._obs_bounds, relative)
        # the step's kept dicts (`_agent_dict`, `_agent_flags`): their agents, and every agent
        # -> None / False / True
        self._kept_agents = self.possible_agents[:]
        self._kept_dicts = {v: dict.fromkeys(self._kept_agents, v) for v in (None, False, True)}

    def __repr__(self) -> str:
        # (str(env) stays PettingZoo's, the metadata name)
        return self._plan_repr(self.metadata["name"])

    # ------------------------------------------------------------ spaces, rng
    def observation_space(self, agent: str) -> spaces.Box:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Box:
        return self.action_spaces[agent]

    @property
    def np_random(self) -> np.random.Generator:
        """The env's generator (seeded by `reset(seed=...)`, as in Gymnasium)."""
        if self._np_random is None:
            self._np_random, self._np_random_seed = seeding.np_random()
        return self._np_random

    # ------------------------------------------------------------------ API
    def _observations(self, mean_positions: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Every agent's observation, rows (views) of one (N, size) array, from the current
        state (its path means E x where given: a compiled step's)."""
        ep = self.episode
        if mean_positions is None:
            mean_positions = ep.mean_positions
        rows = agent_observations(
            mean_positions,
            ep._mean_drift,
            ep._target,
            ep.time_fraction,
            self._obs_space,
            self.config.observation,
            self._neighbours,
        )
        return dict(zip(self.possible_agents, rows, strict=True))

    def state(self) -> np.ndarray:
        """The global state: the Gymnasium observation vector of the current state."""
        return self._global_observation(self.state_space)

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        if check_seed(seed) is not None:
            self._np_random, self._np_random_seed = seeding.np_random(int(seed))
        # unknown keys ignored: PettingZoo's API tests pass {"options": 1}
        self.episode.reset(self.np_random, **reset_options(options, strict=False))
        self.agents = self.possible_agents[:]
        self.last_control = None
        if self._renderer is not None:
            self._renderer.reset(0.0, self.episode.mean_positions, self.episode.target)
            if self.render_mode == "human":
                self.render()
        # the same keys as the step infos (TorchRL's PettingZooWrapper builds its specs here)
        infos = {
            agent: {"time": 0.0, "running_cost": 0.0, "diverged": False} for agent in self.agents
        }
        return self._observations(), infos

    def _stacked_actions(self, actions: dict[str, Any]) -> Any:
        """The live agents' actions stacked (N, d) (or (N,) for d = 1 scalars) in agent order,
        after the checks of the dict: every live agent and no other, each a numpy array of a
        real dtype (stacking would promote a bool or an int action among float ones silently,
        so every value's own dtype is checked). Where a value is not, each agent's action is
        checked alone, so that the error names the agent."""
        if not self.agents:
            raise RuntimeError("the episode is over (no live agents); call reset() first")
        if not isinstance(actions, dict):
            raise TypeError(f"actions must be a dict agent -> action, got {type(actions).__name__}")
        if type(actions) is dict and list(actions) == self.possible_agents:
            values = list(actions.values())  # (the common case: keyed in the agents' order)
        elif actions.keys() != self._agent_index.keys():  # (every agent is live while any is)
            missing = [a for a in self.agents if a not in actions]
            extra = [a for a in actions if a not in self._agent_index]
            raise ValueError(
                f"actions must hold one action per live agent; missing {missing[:5]}"
                f"{'...' if len(missing) > 5 else ''}, unknown {extra[:5]}"
            )
        else:
            values = list(map(actions.__getitem__, self.possible_agents))
        n, d = self.config.params.n_agents, self.config.params.dim
        stacked = _joined_rows(values, n, d)
        if stacked is not None:
            return stacked
        if _real_numpy_values(values):
            try:
                stacked = np.asarray(values)
            except ValueError:  # ragged: the slow path names the agent
                stacked = None
            if stacked is not None and stacked.shape in ((n, d), (n,) if d == 1 else (n, d)):
                return stacked
        agent_shapes = ((d,), ()) if d == 1 else ((d,),)
        rows = []
        for agent in self.possible_agents:
            arr = real_array(f"actions[{agent!r}]", actions[agent])  # names the agent
            if arr.shape not in agent_shapes:
                raise ValueError(f"actions[{agent!r}] must have shape ({d},), got {arr.shape}")
            rows.append(arr.reshape(d))
        return np.stack(rows)

    def step(
        self, actions: dict[str, Any]
    ) -> tuple[
        dict[str, np.ndarray],
        dict[str, float],
        dict[str, bool],
        dict[str, bool],
        dict[str, dict[str, Any]],
    ]:
        episode = self.episode
        stacked = self._stacked_actions(actions)
        found = None
        if self._compiled_step:  # the plan's compiled envelope (`compiled_episode_step`)
            found = compiled_episode_step(
                episode, self.np_random, stacked, self._state_bounds, False, self._agent_outputs
            )
            if found is None:
                episode.fallbacks["compiled-step-declined"] += 1
        if found is None:
            control = episode.control_from_action(stacked, name="actions")
            outcome = episode.step(self.np_random, control)
            costs, observations = episode.agent_costs(outcome), None
        else:
            outcome = found.outcome
            costs, observations = self._compiled_agent_outputs(found)
        self.last_control = outcome.control
        if self.config.agent_reward == "team":
            rewards_arr = np.full(self.config.params.n_agents, episode.reward(outcome))
        else:  # (`SwarmEpisode.agent_rewards`, from the costs taken once)
            rewards_arr = -(episode.dt / episode.n_agents) * costs
        agents = self.agents
        rewards = self._agent_dict(agents, rewards_arr.tolist())
        terminations = self._agent_flags(agents, outcome.diverged)
        truncations = self._agent_flags(agents, outcome.truncated)
        time, diverged = episode.time, outcome.diverged
        infos = self._agent_dict(
            agents,
            [{"time": time, "running_cost": c, "diverged": diverged} for c in costs.tolist()],
        )
        if observations is None:
            observations = self._observations()
        if self._renderer is not None and not outcome.diverged:
            self._renderer.record(time, episode.mean_positions)
            if self.render_mode == "human":
                self.render()
        if outcome.diverged or outcome.truncated:
            self.agents = []
        return observations, rewards, terminations, truncations, infos

    def _agent_flags(self, agents: list[str], value: Any) -> dict[str, Any]:
        """``dict.fromkeys(agents, value)``: a copy of the kept dict where `value` is a bool
        and `agents` are the agents it was made for (a step's case: copying takes a tenth of
        the time of building it)."""
        if (value is False or value is True) and agents == self._kept_agents:
            return self._kept_dicts[value].copy()
        return dict.fromkeys(agents, value)

    def _agent_dict(self, agents: list[str], values: Any) -> dict[str, Any]:
        """``dict(zip(agents, values, strict=True))`` for `values` of len(agents) (N): where
        `agents` are the kept agents, their kept dict copied and its values replaced (the same
        keys in the same order, without the N insertions growing it)."""
        if agents == self._kept_agents:
            found = self._kept_dicts[None].copy()
            found.update(zip(agents, values, strict=True))
            return found
        return dict(zip(agents, values, strict=True))

    def _compiled_agent_outputs(
        self, found: CompiledOutcome
    ) -> tuple[np.ndarray, dict[str, np.ndarray] | None]:
        """After a compiled step: the per-agent costs (N,) and, where the step moved the state,
        the observations (the step's compiled calls gave both, `AgentOutputs`, for the
        "absolute" and "relative" layouts; numpy's `agent_observations` for "swarm" and
        "local"; None after a diverged or general step: `_observations` of the state)."""
        costs = found.agent_costs
        if costs is None:  # (not expected: the step was asked for them)
            ep, outcome = self.episode, found.outcome
            costs = compiled_agent_costs(
                native.loaded("step"), outcome.start_positions[None], outcome.control[None],
                ep.targets, ep.params.gamma,
            )[0]  # fmt: skip
        if found.mean_positions is None:
            return costs, None
        if found.agent_rows is None:
            return costs, self._observations(found.mean_positions)
        return costs, self._agent_dict(self.possible_agents, found.agent_rows)

    def render(self, mode: str | None = None) -> np.ndarray | None:
        """A frame in `render_mode` (None without one); `mode` ("human" | "rgb_array", as
        BenchMARL's ``env.render(mode="rgb_array")`` passes it) renders in that mode instead:
        the env's own renderer where it is that mode, else a renderer made for this call with
        the env's recorded history (just the current state where it records none; the
        "call reset() first" frame before a reset). A mode that is not one raises `ValueError`.
        """
        if mode is None or (self._renderer is not None and mode == self.render_mode):
            return None if self._renderer is None else self._renderer.render()
        if mode not in RENDER_MODES:
            raise ValueError(f"mode must be None or one of {RENDER_MODES}, got {mode!r}")
        params = self.config.params
        renderer = SwarmRenderer(mode, params.horizon, self.metadata["render_fps"])
        if self._renderer is not None:
            renderer.__setstate__(self._renderer.__getstate__())
            renderer.render_mode = mode
        elif self.episode.positions is not None:
            renderer.reset(self.episode.time, self.episode.mean_positions, self.episode.target)
        try:
            return renderer.render()
        finally:
            renderer.close()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
