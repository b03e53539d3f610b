"""The episode core shared by the Gymnasium and the PettingZoo swarm environments.

Both envs are thin adapters over `SwarmEpisode`: it takes the validated keyword arguments
(`agent_envs.envs.episode_config.EpisodeConfig`), holds the state of the `n_paths` Brownian
paths, steps them with the core's integrator (built as the env's `StepPlan` says,
`agent_envs.envs.step_plan.planned_step`) on increments drawn from the generator the env
passes in (its ``self.np_random``), takes the running cost of `eq:running_cost` with
`agent_envs.costs`, and flags divergence with `agent_envs.simulator.diverged_paths`. Nothing
here re-derives the dynamics: the drift, its linearization and the interaction drift of the
observation all come from `agent_envs.dynamics.SwarmModel`.

One step n -> n + 1 (tau = T / m, t_n = n tau)::

    c^n     = mean over paths of c(x^n, u^n)                  (eq:running_cost)
    dW^n    ~ N(0, tau I), shape (n_paths, N, d), from the env's generator
    x^{n+1} = integrator.step(model, x^n, u^n, t_n, tau, dW^n)

and the reward is ``-tau c^n`` (left rectangle rule of `eq:discrete_cost_functional`), so that
the rewards of an episode add up to minus the discrete cost functional on the env's paths.

The observation needs the interaction drift L(x^{n+1}) x^{n+1} at the new state, and the next
integrator step needs L(x^{n+1}) again (every scheme evaluates F(x, u) = L(x) x + u at the start
of the step). The episode's model, `agent_envs.dynamics.linearization_cache.LinearizationCache`,
keeps the last L(x), keyed by the identity of the (read-only) state array, so the kernel
matrix is built once per step instead of twice (the matrix-free operator of large swarms,
env kwarg `linear_operator`, likewise).
"""

from __future__ import annotations

import contextlib
from collections import Counter
from dataclasses import dataclass
from typing import Any

import numpy as np

from agent_envs import arrays
from agent_envs.costs import agent_running_cost, running_cost
from agent_envs.draws import brownian_increments
from agent_envs.dynamics.linearization_cache import LinearizationCache
from agent_envs.dynamics.swarm import SwarmModel
from agent_envs.envs.episode_config import (
    EpisodeConfig,
    episode_params,
    same_dynamics,
    start_positions,
)
from agent_envs.envs.interface import action_rows, controls_from_actions
from agent_envs.envs.step_plan import StepPlan, planned_step
from agent_envs.integrators import Integrator
from agent_envs.simulator import diverged_paths
from agent_envs.validation import real_array


def _quiet_overflow(x: Any) -> Any:
    """numpy's errstate ignoring overflow/invalid (a diverging step is flagged, not warned);
    a no-op context for torch, which does not warn."""
    if isinstance(x, np.ndarray):
        return np.errstate(over="ignore", invalid="ignore")
    return contextlib.nullcontext()


def mean_interaction_drift(model: SwarmModel, x: Any) -> Any:
    """E over the paths of the interaction drift L(x) x: x (..., P, N, d) -> (..., N, d).

    Marks a numpy x read-only first, so that a `LinearizationCache` keeps L(x) for the
    next integrator step from this state. numpy arrays or torch tensors.
    """
    if isinstance(x, np.ndarray):
        x.flags.writeable = False
    with _quiet_overflow(x):
        return arrays.mean_axis(model.interaction_drift(x), -3)


def mean_running_cost(x: Any, control: Any, target: Any, gamma: float) -> Any:
    """c(x^n, u^n) of `eq:running_cost`, mean over the paths.

    x (..., P, N, d), control (..., N, d) (the same for every path), target (..., d);
    returns shape (...). Batched over leading (env) axes; numpy arrays or torch tensors.
    """
    per_path = running_cost(x, control[..., None, :, :], target[..., None, None, :], gamma)
    return arrays.mean_axis(per_path, -1)


def advance_paths(
    integrator: Integrator,
    model: SwarmModel,
    x: np.ndarray,
    control: np.ndarray,
    t: float | np.ndarray,
    dt: float,
    dw: np.ndarray,
    divergence_threshold: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One integrator step of every path, with the divergence check of the envs.

    Args:
        x: x^n, (..., P, N, d); leading axes are envs.
        control: u^n, (..., N, d), held over the step and the same for every path.
        t: t_n, a float or an array broadcastable to x (one time per env).
        dw: Brownian increments, the shape of x.

    numpy arrays or torch tensors (all in one library).

    Returns:
        x^{n+1} (..., P, N, d); E interaction drift at x^{n+1}, (..., N, d); and the (...)
        flags "diverged": some path of the env left the divergence threshold, or it or the
        interaction drift became non-finite. Entries of diverged envs are meaningless.
    """
    with _quiet_overflow(x):
        x_next = integrator.step(model, x, control[..., None, :, :], t, dt, dw)
    return checked_advance(model, x_next, divergence_threshold)


def checked_advance(
    model: SwarmModel, x_next: Any, divergence_threshold: float
) -> tuple[Any, Any, Any]:
    """`advance_paths` after the integrator's step: x^{n+1} (..., P, N, d), E interaction
    drift at x^{n+1} (..., N, d), and the (...) flags "diverged" (some path beyond the
    threshold or non-finite, or the drift non-finite)."""
    xp = arrays.namespace(x_next)
    diverged = xp.any(diverged_paths(x_next, divergence_threshold), axis=-1)
    drift = mean_interaction_drift(model, x_next)
    diverged = diverged | ~xp.all(xp.isfinite(drift), axis=(-2, -1))
    return x_next, drift, diverged


@dataclass(frozen=True)
class StepOutcome:
    """What one `SwarmEpisode.step` did.

    Attributes:
        start_positions: x^n, (n_paths, N, d), the state the running cost is taken at.
        control: u^n, (N, d), the control applied over the step (after clipping).
        running_cost: c(x^n, u^n) of `eq:running_cost`, mean over the paths.
        diverged: True when x^{n+1} left the divergence threshold, or it or its interaction
            drift became non-finite, on some path; the episode then keeps x^n and t_n.
        truncated: True when the step reached the horizon T (n + 1 = m) without diverging.
    """

    start_positions: np.ndarray
    control: np.ndarray
    running_cost: float
    diverged: bool
    truncated: bool


class SwarmEpisode:
    """State and stepping of one episode of the controlled swarm, for both env adapters.

    Attributes:
        config: the validated `EpisodeConfig`.
        params: the `SwarmParams` of the current episode (target included).
        model: the `SwarmModel` of `params` (the integrators and controllers use it): a
            `LinearizationCache`.
        integrator: the `Integrator` named by the config's simulation, as the plan builds it.
        positions: (n_paths, N, d) current state (read-only array).
        step_index: n, the number of steps taken since reset.
        diverged: True once a step diverged (the episode is then over).
        plan: the `StepPlan` of a step, resolved here once with the model and the integrator
            (`step_plan.planned_step`; `env` names the adapter: "gymnasium" or "pettingzoo").
        fallbacks: the mid-step fallbacks counted (`step_plan.FALLBACKS`), a `Counter`.
    """

    def __init__(self, config: EpisodeConfig, env: str = "gymnasium", threads: int = 1) -> None:
        self.config = config
        self.params = config.params
        self.fallbacks: Counter[str] = Counter()
        self.model: LinearizationCache
        self.plan: StepPlan
        self.integrator: Integrator
        self.model, self.plan, self.integrator = planned_step(
            config, self.fallbacks, env=env, threads=threads
        )
        arrays.prepare_hot_path()
        self.dt = config.dt
        self.positions: np.ndarray | None = None
        self.step_index = 0
        self.diverged = False
        self._mean_drift: np.ndarray | None = None
        self._target = self.params.target_vector
        n, d = self.params.n_agents, self.params.dim
        rows = action_rows(config.action_basis, n)
        #: the action's accepted shapes, its rows and d (the compiled step's check)
        self.action_shapes = (((rows * d,), (rows, d)), rows, d)
        #: xbar as a (1, d) float64 array (the compiled step's batch of one env)
        self.targets = np.ascontiguousarray(self._target, dtype=np.float64)[None]

    # ----------------------------------------------------------------- state
    @property
    def n_agents(self) -> int:
        return self.params.n_agents

    @property
    def dim(self) -> int:
        return self.params.dim

    @property
    def target(self) -> np.ndarray:
        """xbar as a (d,) array (a copy)."""
        return self._target.copy()

    @property
    def time(self) -> float:
        """t_n = n T / m."""
        return self.params.horizon * self.step_index / self.config.simulation.n_steps

    @property
    def time_fraction(self) -> float:
        """t_n / T = n / m."""
        return self.step_index / self.config.simulation.n_steps

    @property
    def done(self) -> bool:
        """True when the episode has ended (horizon reached or diverged)."""
        return self.diverged or self.step_index >= self.config.simulation.n_steps

    @property
    def mean_positions(self) -> np.ndarray:
        """E x over the paths: (N, d), a new array (`arrays.mean_axis`, as the native vector
        env's observation: the same bits)."""
        return arrays.mean_axis(self._require_state(), 0)

    @property
    def mean_interaction_drift(self) -> np.ndarray:
        """E (1/N) sum_l p(x_k, x_l)(x_l - x_k) over the paths: (N, d), a new array."""
        self._require_state()
        return self._mean_drift.copy()

    def _require_state(self) -> np.ndarray:
        if self.positions is None:
            raise RuntimeError("the episode has not been reset; call reset() first")
        return self.positions

    # ---------------------------------------------------------------- stepping
    def reset(
        self, rng: np.random.Generator, initial_positions: Any = None, target: Any = None
    ) -> None:
        """Start an episode at t = 0.

        The uniform start on [-1, 1]^d is always drawn from `rng` (then replaced by
        `initial_positions` if given), so that the Brownian increments of the episode do not
        depend on whether a start was given. `target` overrides xbar for this episode.
        """
        n, d = self.config.params.n_agents, self.config.params.dim
        x0 = start_positions(self.config, rng, initial_positions)
        params = episode_params(self.config, target)
        if params != self.params:
            # target and gamma are cost parameters: a new target keeps the dynamics model
            # (and its kernel); only a change of the dynamics would rebuild it.
            if not same_dynamics(params, self.params):
                self.model = LinearizationCache(
                    params,
                    self.config.linear_operator,
                    fallbacks=self.fallbacks,
                    threads=self.model.threads,
                )
            self.params = params
            self._target = params.target_vector
            self.targets = np.ascontiguousarray(self._target, dtype=np.float64)[None]
        x = np.broadcast_to(x0, (self.config.simulation.n_paths, n, d)).copy()
        drift = mean_interaction_drift(self.model, x)
        if not np.all(np.isfinite(drift)):
            raise ValueError(
                "kernel: the interaction drift is not finite at the initial positions (a user "
                "kernel must return finite values there)"
            )
        self.positions, self._mean_drift = x, drift
        self.step_index = 0
        self.diverged = False

    def step(self, rng: np.random.Generator, control: np.ndarray) -> StepOutcome:
        """Advance all paths by one step under the control u^n (N, d) (already validated)."""
        x = self._require_state()
        if self.done:
            raise RuntimeError(
                "the episode is over (horizon reached or diverged); call reset() first"
            )
        cost = float(mean_running_cost(x, control, self._target, self.params.gamma))
        dw = brownian_increments(rng, x.shape, self.dt)
        # BLAS limited to one thread while stepping (see agent_envs.arrays.hot_path_threads).
        with arrays.hot_path_threads():
            x_next, drift, diverged_flag = advance_paths(
                self.integrator,
                self.model,
                x,
                control,
                self.time,
                self.dt,
                dw,
                self.config.divergence_threshold,
            )
        return self.commit_step(x, control, cost, x_next, drift, diverged_flag)

    def commit_step(
        self,
        x: np.ndarray,
        control: np.ndarray,
        cost: float,
        x_next: np.ndarray,
        drift: np.ndarray,
        diverged_flag: Any,
    ) -> StepOutcome:
        """The episode after a step from x under `control` (running cost `cost`) to x_next
        with mean drift `drift`: the new state, or, where the step diverged, the old state kept
        and the episode ended; its `StepOutcome`. (The numpy step and the compiled envelope,
        `compiled_episode`, both end here.)"""
        diverged = bool(diverged_flag)
        if diverged:
            self.diverged = True
        else:
            self.positions, self._mean_drift = x_next, drift
            self.step_index += 1
        return StepOutcome(
            start_positions=x,
            control=control,
            running_cost=cost,
            diverged=diverged,
            truncated=not diverged and self.step_index >= self.config.simulation.n_steps,
        )

    # ------------------------------------------------------------------ rewards
    def reward(self, outcome: StepOutcome) -> float:
        """-tau c(x^n, u^n), mean over the paths."""
        return -self.dt * outcome.running_cost

    def agent_costs(self, outcome: StepOutcome) -> np.ndarray:
        """|x_k^n - xbar|^2 + gamma |u_k^n|^2, mean over the paths: (N,)."""
        costs = agent_running_cost(
            outcome.start_positions, outcome.control, self._target, self.params.gamma
        )
        return costs.mean(axis=0)

    def agent_rewards(self, outcome: StepOutcome) -> np.ndarray:
        """-tau/N (|x_k^n - xbar|^2 + gamma |u_k^n|^2), mean over the paths: (N,).

        They add up to `reward(outcome)` (up to round-off). With ``agent_reward="team"`` every
        entry is `reward(outcome)`, the swarm's reward.
        """
        if self.config.agent_reward == "team":
            return np.full(self.n_agents, self.reward(outcome))
        return -(self.dt / self.n_agents) * self.agent_costs(outcome)

    def control_from_action(self, action: Any, name: str = "action") -> np.ndarray:
        """u = max_control * clip(action, -1, 1) as an (N, d) float64 array (in the config's
        ``action_basis``: `agent_envs.envs.interface.controls_from_actions`).

        `action` must have rows d entries, shaped (rows d,) or (rows, d) (rows = N, or 1 for
        ``action_basis="common"``; (N,) for d = 1), of a real
        numeric dtype (`agent_envs.validation.real_array`): strings, bools and complex numbers
        raise `TypeError` (a complex part is never dropped silently); an object array is
        accepted when every entry is an int or a float. A NaN or infinite entry, or an int too
        large for a float, raises `ValueError`; a finite entry outside [-1, 1] is clipped.
        """
        n, d = self.config.params.n_agents, self.config.params.dim
        rows = action_rows(self.config.action_basis, n)
        arr = real_array(name, action)
        if arr.shape not in ((rows * d,), (rows, d)):
            raise ValueError(
                f"{name} must have shape ({rows * d},) or ({rows}, {d}), got {arr.shape}"
            )
        return controls_from_actions(
            arr.reshape(rows, d), self.config.action_basis, self.config.simulation.max_control, n
        )
