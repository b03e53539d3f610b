"""The read-only attributes the swarm envs expose, defined once.

`EnvAttributes` holds what every swarm env reads off its `EpisodeConfig` and its `StepPlan`
(``env.unwrapped.n_steps``, ``.dt``, ``.plan``, ...): the Gymnasium env, the PettingZoo env and
the native vector env inherit it. `EpisodeAttributes` adds what the two single envs read off
their `SwarmEpisode` (the current state, the episode's params, its model).
"""

from __future__ import annotations

from collections import Counter

import numpy as np
from gymnasium import spaces

from agent_envs.dynamics.linearization_cache import LinearizationCache
from agent_envs.envs.episode import SwarmEpisode
from agent_envs.envs.episode_config import EpisodeConfig
from agent_envs.envs.observation import global_observation
from agent_envs.envs.step_plan import StepPlan
from agent_envs.params import SwarmParams


class EnvAttributes:
    """Read-only attributes of every swarm env, from its configuration and its step plan.

    The env provides `self.config` (its `EpisodeConfig`) and `self.plan` (its `StepPlan`,
    resolved when the env was made).
    """

    config: EpisodeConfig
    plan: StepPlan

    @property
    def max_control(self) -> float:
        """u = max_control * action."""
        return self.config.simulation.max_control

    @property
    def n_steps(self) -> int:
        """m, the number of steps of an episode."""
        return self.config.simulation.n_steps

    @property
    def n_paths(self) -> int:
        """Brownian paths simulated together (per env)."""
        return self.config.simulation.n_paths

    @property
    def dt(self) -> float:
        """tau = T / m."""
        return self.config.dt

    @property
    def integrator_name(self) -> str:
        """em | ee | heun | erb | serb."""
        return self.config.simulation.integrator

    @property
    def jacobian(self) -> str:
        """ "frozen" or "exact" (the linearization of erb and serb)."""
        return self.config.simulation.jacobian

    @property
    def phi_method(self) -> str:
        """The phi strategy the integrator is built with (`StepPlan.phi_method`: "auto"
        resolved for the env's paths)."""
        return self.plan.phi_method

    def _plan_repr(self, name: str) -> str:
        """``<Class<name> plan>``: the env's name and its step plan."""
        return f"<{type(self).__name__}<{name}> {self.plan.describe()}>"


class EpisodeAttributes(EnvAttributes):
    """Read-only attributes both single-env adapters expose (`env.unwrapped.params`, ...).

    The adapter provides `self.episode` (a `SwarmEpisode`) and `self.config` (its
    `EpisodeConfig`).
    """

    episode: SwarmEpisode

    @property
    def params(self) -> SwarmParams:
        """SwarmParams of the current episode (target included)."""
        return self.episode.params

    @property
    def model(self) -> LinearizationCache:
        """The SwarmModel the integrator and the controllers use (a `LinearizationCache`)."""
        return self.episode.model

    @property
    def plan(self) -> StepPlan:  # type: ignore[override]
        """Which code a step runs (`agent_envs.envs.step_plan.StepPlan`), resolved when the
        env was made."""
        return self.episode.plan

    @property
    def plan_fallbacks(self) -> Counter[str]:
        """The mid-step fallbacks of this env's steps so far, by kind
        (`agent_envs.envs.step_plan.FALLBACKS`): a `collections.Counter`."""
        return self.episode.fallbacks

    @property
    def positions(self) -> np.ndarray | None:
        """(n_paths, N, d) current state (read-only; None before the first reset)."""
        return self.episode.positions

    @property
    def time(self) -> float:
        """t_n = n tau."""
        return self.episode.time

    @property
    def step_index(self) -> int:
        """n, the number of steps taken since reset."""
        return self.episode.step_index

    def _global_observation(self, space: spaces.Box, layout: str = "absolute") -> np.ndarray:
        """The Gymnasium observation vector (= the PettingZoo global state, "absolute") of the
        episode in `layout`."""
        ep = self.episode
        return global_observation(
            ep.mean_positions,
            ep.mean_interaction_drift,
            ep.target,
            ep.time_fraction,
            space,
            layout,
        )
