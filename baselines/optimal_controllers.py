"""The optimal open-loop controller and its receding-horizon (MPC) version, as SB3 policies.

Both plan with `solve_optimal_control` on the env's own discretization (integrator, Jacobian
choice, phi method, tau, m, max_control, read from the env's `EpisodeConfig`) and act with
``a = u / max_control`` in [-1, 1] (float32), like the turnpike controllers.

What they see: the Gymnasium observation (docs/CONTRACT.md) holds E x, the mean over the env's
Brownian paths, of every agent, the target and t/T. At t = 0 all the env's paths start at the
same x^0, so E x^0 = x^0 (up to float32 rounding) and the plan starts from the true state. At
later steps (MPC) the controller re-plans from E x^n: exact for the default env (one path),
an approximation (it restarts every path from their mean) when the env simulates several.

What they plan against (a documented choice): the expectation of `eq:discrete_cost_functional`
is replaced by the sample mean over `n_paths` Brownian paths that the controller draws itself
(seed `seed`, independent of the env's noise, which the controller cannot know): the
sample-average approximation of the stochastic problem, with the paper's K = 20 by default.
`noise_free=True` plans on the deterministic model (sigma = 0, one path) instead; for small
sigma the two plans are close, and the noise-free one is K times cheaper.

- `OptimalController`: open loop. Solves once per episode, at the first observation (t/T = 0),
  for the whole horizon, then replays the plan u^n at step n.
- `MPCController`: receding horizon. At every step n it re-solves from the observed E x^n over
  the remaining m - n steps (same tau), warm-started from its previous plan shifted by one step,
  with at most `max_iterations` L-BFGS-B iterations per re-solve (the first solve of an episode
  uses `first_iterations`), and applies the first control. This is the feedback reference a
  learner should be measured against.

Batches: a single observation (2Nd + d + 1,) or a VecEnv batch (n_envs, 2Nd + d + 1); one plan
is kept per batch row on the controller. Per-agent (PettingZoo) rows are not accepted: a plan
needs all agents' positions (use the Gymnasium env, or `act` on the parallel env's dict of all
N agents).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np

from agent_envs.baselines.feedback import env_attribute, env_interface
from agent_envs.baselines.optimal_control import (
    DEFAULT_GTOL,
    DEFAULT_MAX_ITERATIONS,
    solve_optimal_control,
)
from agent_envs.envs.interface import action_rows, actions_from_controls
from agent_envs.envs.observation import observation_size, split_observation
from agent_envs.params import SwarmParams, check_int
from agent_envs.simulator import SAMPLE_AVERAGE_PATHS

#: iteration cap of each MPC re-solve after the first (keeps an evaluation affordable)
DEFAULT_MPC_ITERATIONS = 15


class PlanningController:
    """Shared machinery: env reading, observation parsing, one plan per batch row.

    Args:
        env: the env it acts on (Gymnasium env, SB3 VecEnv or PettingZoo parallel env); the
            discretization and bounds are read from its `config` (`EpisodeConfig`).
        n_paths: K, the Brownian paths of the sample-average problem (module docstring).
        seed: the seed of those paths.
        noise_free: plan on the sigma = 0 model with one path instead.
        gtol, max_iterations: passed to `solve_optimal_control` for the first solve.
        params, max_control, n_steps, integrator, jacobian, phi_method: override the env's.
    """

    def __init__(
        self,
        env: Any = None,
        *,
        n_paths: int = SAMPLE_AVERAGE_PATHS,
        seed: int = 0,
        noise_free: bool = False,
        gtol: float = DEFAULT_GTOL,
        max_iterations: int = DEFAULT_MAX_ITERATIONS,
        params: SwarmParams | None = None,
        max_control: float | None = None,
        n_steps: int | None = None,
        integrator: str | None = None,
        jacobian: str | None = None,
        phi_method: str | None = None,
    ) -> None:
        config = None
        if env is not None:
            try:
                config = env_attribute(env, "config")
            except AttributeError:
                config = None

        def pick(given: Any, name: str) -> Any:
            if given is not None:
                return given
            if name == "params":
                return env_attribute(env, "params")
            if config is None:
                raise ValueError(f"{type(self).__name__} needs {name}= without a swarm env")
            return getattr(config.simulation, name)

        self.env = env
        self.params: SwarmParams = pick(params, "params")
        self.max_control = float(pick(max_control, "max_control"))
        self.n_steps = check_int("n_steps", pick(n_steps, "n_steps"), 1)
        self.integrator = str(pick(integrator, "integrator"))
        self.jacobian = str(pick(jacobian, "jacobian"))
        self.phi_method = str(pick(phi_method, "phi_method"))
        self.n_paths = 1 if noise_free else check_int("n_paths", n_paths, 1)
        self.seed = check_int("seed", seed, 0)
        self.noise_free = bool(noise_free)
        self.gtol = gtol
        self.max_iterations = check_int("max_iterations", max_iterations, 1)
        self.dt = self.params.horizon / self.n_steps
        self.observation_layout, self.action_basis = env_interface(env)
        if self.observation_layout == "summary":
            raise ValueError(
                f"{type(self).__name__} plans from the agents' positions; the env's "
                "observation='summary' holds only the swarm's centre and spread"
            )
        self.obs_dim = observation_size(
            self.params.n_agents, self.params.dim, self.observation_layout
        )
        #: per batch row: (step index the plan starts at, plan (m - n0, N, d))
        self._plans: dict[int, tuple[int, np.ndarray]] = {}
        #: the last solve's result (diagnostics)
        self.last_result: Any = None
        self.solves = 0

    # ----------------------------------------------------------------- planning
    def plan(
        self,
        positions: np.ndarray,
        target: np.ndarray,
        start_step: int,
        warm_start: np.ndarray | None,
        max_iterations: int,
        warn: bool,
    ) -> np.ndarray:
        """The optimal open-loop control (m - n0, N, d) from `positions` at step n0."""
        remaining = self.n_steps - start_step
        params = dataclasses.replace(
            self.params,
            horizon=remaining * self.dt,
            target=tuple(float(v) for v in np.asarray(target).reshape(-1)),
            **({"sigma": 0.0} if self.noise_free else {}),
        )
        res = solve_optimal_control(
            params,
            self.integrator,
            jacobian=self.jacobian,
            phi_method=self.phi_method,
            n_steps=remaining,
            n_paths=self.n_paths,
            seed=self.seed,
            initial_positions=positions,
            max_control=self.max_control,
            initial_controls=warm_start,
            gtol=self.gtol,
            max_iterations=max_iterations,
            warn=warn,
        )
        self.last_result = res
        self.solves += 1
        return res.controls

    def control_at(self, row: int, step: int, positions: np.ndarray, target: np.ndarray):
        """u^n (N, d) for one batch row; subclasses decide when to (re-)plan."""
        raise NotImplementedError

    # ------------------------------------------------------------------ SB3 API
    def predict(
        self,
        observation: Any,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """SB3 `PolicyPredictor.predict`: actions u / max_control for one obs or a batch."""
        obs = np.asarray(observation, dtype=np.float64)
        if obs.shape[-1:] != (self.obs_dim,) or obs.ndim not in (1, 2):
            raise ValueError(
                f"{type(self).__name__} takes Gymnasium observations of shape ({self.obs_dim},) "
                f"or (n_envs, {self.obs_dim}) for N = {self.params.n_agents}, "
                f"d = {self.params.dim}; got {obs.shape} (per-agent rows cannot be planned on: "
                "use the Gymnasium env or act() with all agents)"
            )
        single = obs.ndim == 1
        batch = obs[None] if single else obs
        parts = split_observation(
            batch, self.params.n_agents, self.params.dim, self.observation_layout
        )
        steps = np.rint(parts["time_fraction"] * self.n_steps).astype(int)
        rows = action_rows(self.action_basis, self.params.n_agents)
        actions = np.empty((batch.shape[0], rows * self.params.dim), np.float32)
        for row in range(batch.shape[0]):
            step = int(min(steps[row], self.n_steps - 1))
            u = self.control_at(row, step, parts["positions"][row], parts["target"][row])
            a = actions_from_controls(u, self.action_basis, self.max_control)
            actions[row] = a.reshape(-1).astype(np.float32)
        return (actions[0] if single else actions), state

    def act(self, observations: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """PettingZoo parallel env: actions for a dict of all N agents' rows (in agent order)."""
        agents = list(observations)
        n, d = self.params.n_agents, self.params.dim
        if len(agents) != n:
            raise ValueError(f"act needs all {n} agents' observations, got {len(agents)}")
        rows = np.stack([np.asarray(observations[a], dtype=np.float64) for a in agents])
        gym_obs = np.concatenate(
            [
                rows[:, :d].reshape(-1),
                rows[:, d : 2 * d].reshape(-1),
                rows[0, 2 * d : 3 * d],
                rows[0, -1:],
            ]
        )
        actions, _ = self.predict(gym_obs)
        return {a: actions[i * d : (i + 1) * d] for i, a in enumerate(agents)}

    def reset(self) -> None:
        """Forget every plan (the next observation starts planning afresh)."""
        self._plans.clear()

    def __repr__(self) -> str:
        noise = "noise-free" if self.noise_free else f"{self.n_paths} paths, seed {self.seed}"
        return f"{type(self).__name__}({self.integrator}, {noise})"


class OptimalController(PlanningController):
    """Open-loop optimum: one solve per episode at t/T = 0, then replay (module docstring)."""

    def control_at(self, row: int, step: int, positions: np.ndarray, target: np.ndarray):
        entry = self._plans.get(row)
        if step == 0 or entry is None or not 0 <= step - entry[0] < len(entry[1]):
            plan = self.plan(positions, target, step, None, self.max_iterations, warn=True)
            entry = (step, plan)
            self._plans[row] = entry
        start, plan = entry
        return plan[step - start]


class MPCController(PlanningController):
    """Receding horizon: re-solve from every observation over the remaining horizon.

    Args:
        env: as `PlanningController`.
        max_iterations: L-BFGS-B iterations per re-solve after the first (default 15).
        first_iterations: iterations of the first solve of an episode (default 500).
        **kwargs: n_paths, seed, noise_free, gtol and the overrides of `PlanningController`.
    """

    def __init__(
        self,
        env: Any = None,
        *,
        max_iterations: int = DEFAULT_MPC_ITERATIONS,
        first_iterations: int = DEFAULT_MAX_ITERATIONS,
        **kwargs: Any,
    ) -> None:
        super().__init__(env, max_iterations=first_iterations, **kwargs)
        self.step_iterations = check_int("max_iterations", max_iterations, 1)

    def control_at(self, row: int, step: int, positions: np.ndarray, target: np.ndarray):
        entry = self._plans.get(row)
        if step == 0 or entry is None or not 1 <= step - entry[0] < len(entry[1]):
            plan = self.plan(positions, target, step, None, self.max_iterations, warn=True)
        else:
            start, previous = entry
            warm = previous[step - start :]
            plan = self.plan(positions, target, step, warm, self.step_iterations, warn=False)
        self._plans[row] = (step, plan)
        return plan[0]
