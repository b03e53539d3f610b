"""The turnpike (cheap) reference controller of the paper, Section 4, as an SB3 policy.

Formulas (labels of the source paper):

- cheap control, `eq:cheap_ctr`, with the expectation taken over the simulated Brownian paths:

      u_k^n = E[ beta (xbar - x_k^n) - (1/N) sum_l p(x_k^n, x_l^n)(x_l^n - x_k^n) ]
            = beta (xbar - E x_k^n) - E[interaction drift on k].

  In continuous time it turns the mean dynamics into `eq:dyn_mean`,
  d/dt E x_k = beta (xbar - E x_k), whose exponential-integrator discretization
  `eq:expint_mean` is exact: E x^{n+1} - xbar = exp(-beta tau) (E x^n - xbar).
- turnpike time, `eq:tptime`: the Lyapunov functional L^n = ||E x^n - xbar||^2 (squared Euclidean
  norm of the whole N d vector, summed over agents and coordinates) decays like
  exp(-2 beta t_n) L^0, so L <= delta from

      tbar = ln(delta / ||E x^0 - xbar||^2) / (-2 beta).

- after tbar the static control of `eq:stationary_solution` is used: u = 0 (xtilde = xbar).

The controller reads everything it needs from the env it is built for: N, d, T, m and
`max_control` from `env.unwrapped` (the env's `SwarmParams`), and the path-mean positions,
the path-mean interaction drift (computed by the env's own `SwarmModel`), the target and t/T from
each observation (layouts in docs/CONTRACT.md). It never re-derives the kernel.

Discretization note (measured; README.md, "Paper's controlled experiments"): an env holds
each action constant over a time step (zero-order hold). With Euler-Maruyama the held cheap
control gives exactly the explicit Euler scheme of `eq:dyn_mean`. With SERB/ERB the
exponential integrator treats the interaction implicitly (phi1(tau L)) while the held control
cancels it only at the step's start,
so in stiff directions the cheap phase barely contracts the spread of the swarm. The paper's own
procedure integrates the closed loop `eq:dyn_mean` in [0, tbar] instead; `CheapClosedLoopModel`
provides that closed loop to the core's integrators (used by
`agent_envs.training.reproduce_turnpike`).
With several paths, the env's control (one for all paths, from path means) also cannot cancel
each path's own stiff interaction; we measured single paths scattering under SERB.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from typing import Any

import numpy as np

from agent_envs.params import SwarmParams

#: Paper values (Section 5.2).
DEFAULT_BETA = 12.0
DEFAULT_DELTA = 2e-4


def turnpike_time(
    mean_x0: np.ndarray,
    target: float | np.ndarray,
    beta: float = DEFAULT_BETA,
    delta: float = DEFAULT_DELTA,
    horizon: float | None = None,
) -> float | np.ndarray:
    """The turnpike time tbar of `eq:tptime`.

    ``tbar = ln(delta / ||E x^0 - xbar||^2) / (-2 beta)``, with ``||.||^2`` summed over all agents
    and coordinates. It is clamped below at 0 (a start already within delta of the target needs no
    cheap phase; this includes E x^0 = xbar exactly) and, when `horizon` is given, above at T.

    Args:
        mean_x0: path-mean initial positions, shape (N,) (d = 1) or (..., N, d) for a batch.
        target: xbar, a scalar or shape (d,) (or broadcastable to mean_x0).
        beta: beta > 0, the decay rate of the cheap control.
        delta: delta > 0, the threshold on the Lyapunov functional.
        horizon: T, the upper clamp (optional).

    Returns:
        a float for a single state, an array of shape (...) for a batch.
    """
    if not beta > 0:
        raise ValueError(f"beta must be > 0, got {beta}")
    if not delta > 0:
        raise ValueError(f"delta must be > 0, got {delta}")
    x = np.asarray(mean_x0, dtype=float)
    if x.ndim == 1:
        x = x[:, None]
    if x.ndim < 2:
        raise ValueError(f"mean_x0 must have shape (N,) or (..., N, d), got {np.shape(mean_x0)}")
    sq = np.sum((x - np.asarray(target, dtype=float)) ** 2, axis=(-2, -1))
    with np.errstate(divide="ignore"):
        tbar = np.log(delta / sq) / (-2.0 * beta)
    tbar = np.maximum(tbar, 0.0)
    if horizon is not None:
        tbar = np.minimum(tbar, float(horizon))
    return float(tbar) if np.ndim(tbar) == 0 else tbar


def cheap_control(
    mean_positions: np.ndarray,
    mean_interaction_drift: np.ndarray,
    target: np.ndarray,
    beta: float = DEFAULT_BETA,
    cancel_interaction: bool = True,
) -> np.ndarray:
    """The cheap control of `eq:cheap_ctr` from path means; shapes (..., N, d), target (..., d).

    ``u_k = beta (xbar - E x_k) - E[(1/N) sum_l p(x_k, x_l)(x_l - x_k)]``. With
    ``cancel_interaction=False`` the second term is dropped (the proportional baseline).
    The expectation is linear, so the path mean of the per-path control equals this expression
    evaluated on the path means of positions and interaction drift.
    """
    x = np.asarray(mean_positions, dtype=float)
    tgt = np.asarray(target, dtype=float)[..., None, :]
    u = beta * (tgt - x)
    if cancel_interaction:
        u = u - np.asarray(mean_interaction_drift, dtype=float)
    return u


def cheap_control_from_model(
    model: Any, positions: np.ndarray, target: np.ndarray, beta: float = DEFAULT_BETA
) -> np.ndarray:
    """`eq:cheap_ctr` for a batch of paths (n_paths, N, d) using a `SwarmModel`'s drift.

    Returns the path-mean control, shape (N, d): the same for every path.
    """
    x = np.asarray(positions, dtype=float)
    drift = model.interaction_drift(x)
    return cheap_control(x.mean(axis=0), drift.mean(axis=0), np.asarray(target, float), beta)


class CheapClosedLoopModel:
    """The swarm under continuous cheap feedback, a drift model for the core's integrators.

    The cheap control `eq:cheap_ctr` applied along each path, u(x) = beta (xbar - x) - L(x) x,
    turns the drift F(x, u) = L(x) x + u into beta (xbar - x): the closed loop is the linear SDE
    dx = beta (xbar - x) dt + sigma dW, whose mean obeys `eq:dyn_mean`. Its linearization is
    ``-beta I`` (per coordinate, symmetric), so ERB/SERB applied to it give `eq:expint_mean`,
    E x^{n+1} = E x^n + tau phi1(-beta tau) beta (xbar - E x^n), exact for the mean; EM gives the
    explicit Euler scheme of `eq:dyn_mean`. This is the paper's cheap integration on [0, tbar]
    (Section 5.2). The drift is evaluated through the wrapped `SwarmModel` (no copy of the
    kernel formulas).

    With `until` = tbar the feedback acts while t < tbar and the model is the open-loop swarm
    afterwards (drift F(t, x, u), the wrapped model's linearization): the paper's whole
    procedure is then one `simulate(..., model=...)` run.

    Why per path: cancelling only the path-mean interaction, with the per-path remainder
    L(x) x - E[L(x) x] left in a drift whose linearization is -beta I, integrates that stiff
    remainder explicitly; we measured it to blow up individual paths in the stiff setting
    (eps = 0.05, m = 50) while their mean still looked right.
    """

    def __init__(
        self,
        model: Any,
        target: np.ndarray,
        beta: float = DEFAULT_BETA,
        until: float = math.inf,
    ) -> None:
        self.model = model
        self.sigma = model.sigma
        self.n_agents = model.n_agents
        self.dim = model.dim
        self.target = np.asarray(target, dtype=float).reshape(model.dim)
        self.beta = float(beta)
        self.until = float(until)

    def feedback_on(self, t: float) -> bool:
        """True while t < `until` (the turnpike time tbar; up to 1e-9 of round-off).

        The switch is a function of t: a scheme that evaluates the drift at t + tau inside a
        step (Heun's predictor) sees the open loop there once t + tau >= tbar.
        """
        return t < self.until - 1e-9

    def control(self, x: np.ndarray) -> np.ndarray:
        """u(x) = beta (xbar - x) - L(x) x per path, same shape as x (..., N, d)."""
        x = np.asarray(x, dtype=float)
        return self.beta * (self.target - x) - self.model.interaction_drift(x)

    def drift(self, t: float, x: np.ndarray, u: np.ndarray | None = None) -> np.ndarray:
        """F(t, x, u + u_fb(x)) with the feedback u_fb while `feedback_on(t)`, else F(t, x, u)."""
        x = np.asarray(x, dtype=float)
        if not self.feedback_on(t):
            return self.model.drift(t, x, u)
        f = self.model.drift(t, x, self.control(x))
        return f if u is None else f + u

    def drift_and_linearization(self, t: float, x: np.ndarray, u: np.ndarray | None, kind: str):
        """(F, -beta I) while the feedback is on; the wrapped model's pair afterwards."""
        from agent_envs.dynamics.swarm import Linearization

        if not self.feedback_on(t):
            return self.model.drift_and_linearization(t, x, u, kind)
        x = np.asarray(x, dtype=float)
        eye = np.broadcast_to(np.eye(self.n_agents), (*x.shape[:-2], self.n_agents, self.n_agents))
        lin = Linearization(-self.beta * eye, per_coordinate=True, symmetric=True)
        return self.drift(t, x, u), lin


# --------------------------------------------------------------------------------------------
# Reading the env and its observations
# --------------------------------------------------------------------------------------------


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


class FeedbackController:
    """Shared machinery of the baselines: SB3 `PolicyPredictor` over the swarm envs.

    Accepted observations (layouts of docs/CONTRACT.md):

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
        return 2 * self.n_agents * self.dim + self.dim + 1

    @property
    def agent_obs_dim(self) -> int:
        return 3 * self.dim + 1

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
        n = self._step_index(rows[:, 3 * self.dim])
        if np.any(n == 0) or self._agent_episode_tbar is None:
            global_state = self._global_state()
            if self.fixed_turnpike_time is not None:
                tb = float(self.fixed_turnpike_time)
            elif global_state is not None and np.all(n == 0):
                tb = float(self._tbar_from_gym_rows(global_state[None])[0])
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
        return s if s.shape == (self.gym_obs_dim,) else None

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

    def _tbar_from_gym_rows(self, rows: np.ndarray) -> np.ndarray:
        from agent_envs.envs.observation import split_observation

        parts = split_observation(rows, self.n_agents, self.dim)
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

    def _finish(self, u: np.ndarray, n: np.ndarray, tbar: np.ndarray) -> np.ndarray:
        """Zero the control after tbar, scale to [-1, 1], clip (with one warning), float32."""
        if self.switch_off:
            on = n * self.dt < tbar - 1e-9
            u = np.where(on.reshape(on.shape + (1,) * (u.ndim - 1)), u, 0.0)
        a = u / self.max_control
        clipped = np.abs(a) > 1.0
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
        return np.clip(a, -1.0, 1.0).astype(np.float32)

    def _predict_gym(self, batch: np.ndarray, state) -> tuple[np.ndarray, np.ndarray]:
        from agent_envs.envs.observation import split_observation

        parts = split_observation(batch, self.n_agents, self.dim)
        n = self._step_index(parts["time_fraction"])
        tbar = self._initial_tbar(state, batch.shape[0])
        start = n == 0
        if np.any(start):
            tbar[start] = self._tbar_from_gym_rows(batch[start])
        self._check_tbar(tbar)
        self._tbar_cache = tbar.copy()
        u = self.control(parts["positions"], parts["interaction_drift"], parts["target"])
        act = self._finish(u, n, tbar)
        return act.reshape(batch.shape[0], self.n_agents * self.dim), tbar

    def _predict_agents(
        self, batch: np.ndarray, state, tbar: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        from agent_envs.envs.observation import split_agent_observation

        d = self.dim
        parts = split_agent_observation(batch, d)
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
            groups = batch.reshape(size // n_ag, n_ag, -1)
            tb = turnpike_time(
                groups[..., 0:d],
                groups[:, 0, None, 2 * d : 3 * d],
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


class TurnpikeController(FeedbackController):
    """The paper's turnpike control: cheap control `eq:cheap_ctr` until tbar, then u = 0.

    ``u_k = beta (xbar - E x_k) - E[(1/N) sum_l p(x_k, x_l)(x_l - x_k)]`` for t_n < tbar
    (`eq:tptime`, computed per episode from the first observation), u = 0 afterwards
    (`eq:stationary_solution`). Returned actions are u / max_control clipped to [-1, 1].

    Args:
        env: the env it acts on (Gymnasium env, SB3 VecEnv, or PettingZoo parallel env); N, d,
            T, m and max_control are read from it.
        beta: decay rate of the cheap control (paper: 12).
        delta: threshold of the Lyapunov functional (paper: 2e-4).
        turnpike_time: a fixed tbar instead of `eq:tptime` per episode (e.g. the paper's 0.54).
        switch_off: False keeps the cheap control on for the whole horizon.
        params, max_control, n_steps: override what is read from env (or give them without env).
    """

    def control(self, positions, drift, target):
        return cheap_control(positions, drift, target, self.beta, cancel_interaction=True)
