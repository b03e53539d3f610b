"""The baselines' shared machinery: an SB3 `PolicyPredictor` over the swarm envs' observations.

The controller reads everything it needs from the env it is built for: N, d, T, m and
`max_control` from `env.unwrapped` (the env's `SwarmParams`), and the path-mean positions,
the path-mean interaction drift (computed by the env's own `SwarmModel`), the target and t/T from
each observation (layouts and their parsing: `agent_envs.envs.observation`). It never
re-derives the kernel.

`FeedbackController` accepts the observation forms of both envs (a Gymnasium vector, a VecEnv
batch, a PettingZoo per-agent row, a batch of rows, a dict of rows) and turns the control law of
a subclass (`agent_envs.baselines.controllers`) into actions in [-1, 1].
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from typing import Any

import numpy as np

from agent_envs.baselines.turnpike import DEFAULT_BETA, DEFAULT_DELTA, turnpike_time
from agent_envs.envs.interface import actions_from_controls
from agent_envs.envs.observation import (
    agent_observation_size,
    observation_size,
    split_agent_observation,
    split_observation,
)
from agent_envs.params import SwarmParams


def env_attribute(env: Any, name: str) -> Any:
    """`name` from a Gym env (via unwrapped), a PettingZoo env, or an SB3 VecEnv (first env)."""
    if env is None:
        raise AttributeError(name)
    if hasattr(env, "get_attr") and hasattr(env, "num_envs"):  # SB3 VecEnv (and wrappers)
        return env.get_attr(name, indices=[0])[0]
    inner = getattr(env, "unwrapped", env)
    if hasattr(inner, name):
        return getattr(inner, name)
    if hasattr(env, "get_wrapper_attr"):
        return env.get_wrapper_attr(name)
    raise AttributeError(name)


def env_interface(env: Any) -> tuple[str, str]:
    """(observation layout, action basis) of the env's `EpisodeConfig` (`agent_envs.envs.
    interface`); the defaults ("absolute", "agents") without an env or a config."""
    try:
        config = env_attribute(env, "config")
    except AttributeError:
        return "absolute", "agents"
    return getattr(config, "observation", "absolute"), getattr(config, "action_basis", "agents")


class FeedbackController:
    """Shared machinery of the baselines: SB3 `PolicyPredictor` over the swarm envs.

    Accepted observations (layouts of `agent_envs.envs.observation`):

    - Gymnasium `agent_envs/Swarm-v0`: one vector (2Nd + d + 1,) or a VecEnv batch
      (n_envs, 2Nd + d + 1); actions (N d,) or (n_envs, N d).
    - PettingZoo `swarm_v0` per-agent rows (3d + 1,): one row, or a batch (B, 3d + 1) (e.g. a
      SuperSuit vec env, rows grouped N agents per env); actions (d,) or (B, d). A dict
      {agent: observation} (the parallel env's) gives a dict of actions (see `act`).

    Subclasses implement `control(positions, drift, target)` -> u of shape (..., N, d) (or
    (..., 1, d) for single agents). Actions are ``clip(u / max_control, -1, 1)`` as float32.

    Turnpike switching: when `switch_off` is True the control is zero at steps with
    ``t_n >= tbar`` (`eq:stationary_solution`); tbar (`eq:tptime`) is computed per episode from
    the observation with t/T = 0. It is kept per batch row in the returned `state` (a tuple
    ``(tbar,)``, shape (B,)), and also cached on the controller, so VecEnvs whose envs reset at
    different times work with or without passing `state` back (as `evaluate_policy` does).
    """

    #: whether the switch at tbar applies; subclasses set it in __init__
    switch_off: bool = True

    def __init__(
        self,
        env: Any = None,
        *,
        beta: float = DEFAULT_BETA,
        delta: float = DEFAULT_DELTA,
        turnpike_time: float | None = None,
        switch_off: bool = True,
        params: SwarmParams | None = None,
        max_control: float | None = None,
        n_steps: int | None = None,
    ) -> None:
        if not beta > 0:
            raise ValueError(f"beta must be > 0, got {beta}")
        if not delta > 0:
            raise ValueError(f"delta must be > 0, got {delta}")
        if turnpike_time is not None and not turnpike_time >= 0:
            raise ValueError(f"turnpike_time must be >= 0 or None, got {turnpike_time}")
        self.env = env
        self.params: SwarmParams = params if params is not None else env_attribute(env, "params")
        self.max_control = float(
            max_control if max_control is not None else env_attribute(env, "max_control")
        )
        self.n_steps = int(n_steps if n_steps is not None else env_attribute(env, "n_steps"))
        self.observation_layout, self.action_basis = env_interface(env)
        if self.observation_layout == "summary":
            raise ValueError(
                f"{type(self).__name__} needs the agents' positions; the env's "
                "observation='summary' holds only the swarm's centre and spread"
            )
        if self.observation_layout == "local":
            raise ValueError(
                f"{type(self).__name__} needs the agents' positions and the interaction drift; "
                "the env's observation='local' holds each agent's neighbourhood only"
            )
        if not self.max_control > 0:
            raise ValueError(f"max_control must be > 0, got {self.max_control}")
        self.n_agents = self.params.n_agents
        self.dim = self.params.dim
        self.horizon = self.params.horizon
        self.dt = self.horizon / self.n_steps
        self.beta = float(beta)
        self.delta = float(delta)
        self.fixed_turnpike_time = turnpike_time
        self.switch_off = bool(switch_off)
        self._tbar_cache: np.ndarray | None = None
        self._agent_episode_tbar: float | None = None
        self._warned_clip = False
        #: fraction of clipped action entries over the controller's life (clipping diagnostics)
        self.n_actions = 0
        self.n_clipped = 0

    # -- sizes -------------------------------------------------------------------------------
    @property
    def gym_obs_dim(self) -> int:
        return observation_size(self.n_agents, self.dim, self.observation_layout)

    @property
    def agent_obs_dim(self) -> int:
        return agent_observation_size(self.dim, self.observation_layout)

    # -- the control law (subclasses) ---------------------------------------------------------
    def control(self, positions: np.ndarray, drift: np.ndarray, target: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    # -- SB3 PolicyPredictor ------------------------------------------------------------------
    def predict(
        self,
        observation: np.ndarray | Mapping[str, np.ndarray],
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[Any, tuple[np.ndarray, ...] | None]:
        """Actions in [-1, 1] for one observation or a batch; see the class docstring.

        `deterministic` is accepted for the protocol (the controllers are deterministic);
        `episode_start` is not needed: a new episode is recognized by t/T = 0.
        """
        if isinstance(observation, Mapping):
            return self.act(observation), None
        obs = np.asarray(observation, dtype=float)
        if obs.ndim not in (1, 2):
            raise ValueError(
                f"observation must have shape (obs_dim,) or (batch, obs_dim), got {obs.shape}"
            )
        single = obs.ndim == 1
        batch = obs[None] if single else obs
        width = batch.shape[-1]
        if width == self.gym_obs_dim:
            actions, tbar = self._predict_gym(batch, state)
        elif width == self.agent_obs_dim:
            actions, tbar = self._predict_agents(batch, state)
        else:
            raise ValueError(
                f"observation width {width} matches neither the Gym layout (2Nd+d+1 = "
                f"{self.gym_obs_dim}) nor the per-agent layout (3d+1 = {self.agent_obs_dim}) "
                f"for N = {self.n_agents}, d = {self.dim}"
            )
        return (actions[0] if single else actions), (tbar,)

    def act(self, observations: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """PettingZoo parallel env: one action (d,) per agent from that agent's own observation.

        tbar is taken from the env's global `state()` (the Gym observation vector) at t/T = 0 when
        the controller was built on a PettingZoo env; otherwise from the N agents' rows.
        """
        agents = list(observations)
        if not agents:
            return {}
        rows = np.stack([np.asarray(observations[a], dtype=float) for a in agents])
        if rows.shape[-1] != self.agent_obs_dim:
            raise ValueError(
                f"per-agent observations must have shape ({self.agent_obs_dim},), got "
                f"{rows.shape[1:]}"
            )
        n = self._step_index(
            split_agent_observation(rows, self.dim, self.observation_layout)["time_fraction"]
        )
        if np.any(n == 0) or self._agent_episode_tbar is None:
            global_state = self._global_state()
            if self.fixed_turnpike_time is not None:
                tb = float(self.fixed_turnpike_time)
            elif global_state is not None and np.all(n == 0):
                tb = float(self._tbar_from_gym_rows(global_state[None], "absolute")[0])
            elif np.all(n == 0) and len(agents) == self.n_agents:
                tb = float(self._tbar_from_agent_rows(rows, np.ones(len(agents), bool))[0])
            else:
                tb = float("nan")
            self._agent_episode_tbar = tb
        tbar = np.full(len(agents), self._agent_episode_tbar)
        actions, _ = self._predict_agents(rows, None, tbar=tbar)
        return {a: actions[i] for i, a in enumerate(agents)}

    # -- internals ----------------------------------------------------------------------------
    def _global_state(self) -> np.ndarray | None:
        state_fn = getattr(self.env, "state", None)
        if state_fn is None or not callable(state_fn):
            return None
        try:
            s = np.asarray(state_fn(), dtype=float)
        except Exception:
            return None
        return s if s.shape == (observation_size(self.n_agents, self.dim),) else None

    def _step_index(self, time_fraction: np.ndarray) -> np.ndarray:
        return np.rint(np.asarray(time_fraction, dtype=float) * self.n_steps).astype(int)

    def _initial_tbar(self, state: tuple[np.ndarray, ...] | None, size: int) -> np.ndarray:
        if self.fixed_turnpike_time is not None:
            return np.full(size, float(self.fixed_turnpike_time))
        if state is not None and len(state) == 1 and np.shape(state[0]) == (size,):
            return np.array(state[0], dtype=float)
        if self._tbar_cache is not None and self._tbar_cache.shape == (size,):
            return self._tbar_cache.copy()
        return np.full(size, np.nan)

    def _tbar_from_gym_rows(self, rows: np.ndarray, layout: str) -> np.ndarray:
        parts = split_observation(rows, self.n_agents, self.dim, layout)
        if self.fixed_turnpike_time is not None:
            return np.full(rows.shape[0], float(self.fixed_turnpike_time))
        return np.atleast_1d(
            turnpike_time(
                parts["positions"],
                parts["target"][..., None, :],
                self.beta,
                self.delta,
                self.horizon,
            )
        )

    def _check_tbar(self, tbar: np.ndarray) -> None:
        if self.switch_off and np.any(np.isnan(tbar)):
            raise RuntimeError(
                f"{type(self).__name__} has not seen the first observation (t/T = 0) of the "
                "current episode, so it cannot compute the turnpike time tbar (eq:tptime). Call "
                "predict from the reset observation on, or pass turnpike_time=... explicitly."
            )

    def _finish(
        self, u: np.ndarray, n: np.ndarray, tbar: np.ndarray, basis: str = "agents"
    ) -> np.ndarray:
        """Zero the control after tbar, scale to [-1, 1] in the action `basis`, clip (with one
        warning), float32."""
        if self.switch_off:
            on = n * self.dt < tbar - 1e-9
            u = np.where(on.reshape(on.shape + (1,) * (u.ndim - 1)), u, 0.0)
        a = u / self.max_control
        clipped = np.abs(a) > 1.0  # counted on the controls, in every action basis
        self.n_actions += a.size
        n_clip = int(np.count_nonzero(clipped))
        self.n_clipped += n_clip
        if n_clip and not self._warned_clip:
            self._warned_clip = True
            warnings.warn(
                f"{type(self).__name__}: |u| exceeds max_control = {self.max_control:g} "
                f"(max |u| = {np.max(np.abs(u)):.3g}); the action is clipped to [-1, 1].",
                RuntimeWarning,
                stacklevel=4,
            )
        if basis != "agents":
            a = actions_from_controls(u, basis, self.max_control)
        return np.clip(a, -1.0, 1.0).astype(np.float32)

    def _predict_gym(self, batch: np.ndarray, state) -> tuple[np.ndarray, np.ndarray]:
        parts = split_observation(batch, self.n_agents, self.dim, self.observation_layout)
        n = self._step_index(parts["time_fraction"])
        tbar = self._initial_tbar(state, batch.shape[0])
        start = n == 0
        if np.any(start):
            tbar[start] = self._tbar_from_gym_rows(batch[start], self.observation_layout)
        self._check_tbar(tbar)
        self._tbar_cache = tbar.copy()
        u = self.control(parts["positions"], parts["interaction_drift"], parts["target"])
        act = self._finish(u, n, tbar, self.action_basis)
        return act.reshape(batch.shape[0], -1), tbar

    def _predict_agents(
        self, batch: np.ndarray, state, tbar: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        d = self.dim
        parts = split_agent_observation(batch, d, self.observation_layout)
        x = parts["position"][:, None, :]  # (B, 1, d)
        drift = parts["interaction_drift"][:, None, :]
        target = parts["target"]
        n = self._step_index(parts["time_fraction"])
        size = batch.shape[0]
        if tbar is not None:
            tbar = np.array(tbar, dtype=float)
        else:
            tbar = self._initial_tbar(state, size)
            start = n == 0
            if np.any(start) and self.switch_off:
                tbar[start] = self._tbar_from_agent_rows(batch, start)
        self._check_tbar(tbar)
        self._tbar_cache = tbar.copy()
        u = self.control(x, drift, target)  # (B, 1, d)
        act = self._finish(u, n, tbar)
        return act.reshape(size, d), tbar

    def _tbar_from_agent_rows(self, batch: np.ndarray, start: np.ndarray) -> np.ndarray:
        """tbar for the starting rows: grouped N per env, else from the env's global state."""
        if self.fixed_turnpike_time is not None:
            return np.full(int(np.count_nonzero(start)), float(self.fixed_turnpike_time))
        size, n_ag, d = batch.shape[0], self.n_agents, self.dim
        if size % n_ag == 0:
            groups = split_agent_observation(
                batch.reshape(size // n_ag, n_ag, -1), d, self.observation_layout
            )
            tb = turnpike_time(
                groups["position"],
                groups["target"][:, 0, None, :],
                self.beta,
                self.delta,
                self.horizon,
            )
            return np.repeat(np.atleast_1d(tb), n_ag)[start]
        global_state = self._global_state()
        if global_state is None:
            raise RuntimeError(
                "per-agent observations: tbar (eq:tptime) needs all N agents' positions; pass the "
                "N agents' rows together or build the controller on the PettingZoo env (state())"
            )
        tb = self._tbar_from_gym_rows(global_state[None])
        return np.full(int(np.count_nonzero(start)), float(tb[0]))

    def reset(self) -> None:
        """Forget the cached tbar (per batch row and per PettingZoo episode)."""
        self._tbar_cache = None
        self._agent_episode_tbar = None

    @property
    def turnpike_times(self) -> np.ndarray | None:
        """tbar per batch row of the last call (None before the first call or without switch)."""
        if self._tbar_cache is None or not self.switch_off:
            return None
        return self._tbar_cache.copy()

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(beta={self.beta:g}, delta={self.delta:g}, "
            f"max_control={self.max_control:g}, switch_off={self.switch_off})"
        )
