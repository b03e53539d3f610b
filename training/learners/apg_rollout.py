"""Differentiable closed-loop episodes of the swarm env, for the analytic-policy-gradient learner.

One episode here is one episode of the Gymnasium env `agent_envs/Swarm-v0` with the same
kwargs, computed by the core's own integrator on torch (`agent_envs.simulator.simulate` with
``control=callable``), so the discrete cost functional (`eq:discrete_cost_functional`, mean
over the env's K Brownian paths) is differentiable in the law's weights:

    x^0 ~ uniform [-1, 1]^d per agent (the env's start), the same for the K paths
    u^n = law(E x^n, E L(x^n) x^n, xbar, n / m)       (what the env observes; E over the paths)
    x^{n+1} = integrator step of every path with u^n and dW^n
    J = tau sum_n (1/K) sum_j c(x^{n,j}, u^n)

`EpisodeNoise.for_env_seed(seed, ...)` draws x^0 and dW exactly as the env does after
``reset(seed=seed)`` (Gymnasium's generator `np.random.default_rng(seed)`: the uniform start,
then one (K, N, d) block of increments per step), so a cost computed here on an env seed is the
env's episode cost for that seed (up to the float32 rounding of the env's observations and
actions; `tests/test_apg.py` checks it).

The closed loop needs the interaction drift L(x^n) x^n at every step, and the integrator's
step needs L(x^n) again (its frozen linearization). The model is a plain `SwarmModel`, which
keeps nothing between calls: the envs' `agent_envs.dynamics.linearization_cache.
LinearizationCache` could share one L(x^n) between the two uses (``cache_tensors=True``) and
give the same cost, but its backward pass would add the two uses' gradients before going
through L(x^n) once, which moves the law's gradient by round-off (about 1e-14 on the tests'
settings) and so every trained law. Each step therefore builds L(x^n) twice, as the rollouts
the published apg runs were trained with did (sharing it would save a quarter to two thirds
of an episode's cost and gradient time, measured on two settings).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from agent_envs.baselines.optimal_control import differentiated_phi_method
from agent_envs.costs import discrete_cost
from agent_envs.draws import brownian_increments, uniform_positions
from agent_envs.dynamics.swarm import SwarmModel
from agent_envs.envs.episode_config import EpisodeConfig
from agent_envs.simulator import simulate
from agent_envs.training.learners.apg_policy import SwarmFeedbackLaw


@dataclass(frozen=True)
class EpisodeNoise:
    """x^0 (N, d) and the Brownian increments dW (m, K, N, d) of one episode (numpy)."""

    start: np.ndarray
    increments: np.ndarray

    @classmethod
    def for_env_seed(cls, seed: int, config: EpisodeConfig) -> EpisodeNoise:
        """The start and increments of the env's episode after ``reset(seed=seed)``."""
        rng = np.random.default_rng(seed)
        return cls.draw(rng, config)

    @classmethod
    def draw(cls, rng: np.random.Generator, config: EpisodeConfig) -> EpisodeNoise:
        """A fresh episode from `rng`, drawn in the env's order (start, then step by step)."""
        n, d, k = config.params.n_agents, config.params.dim, config.simulation.n_paths
        start = uniform_positions(rng, n, d)
        dw = np.stack(
            [
                brownian_increments(rng, (k, n, d), config.dt)
                for _ in range(config.simulation.n_steps)
            ]
        )
        return cls(start, dw)


class ClosedLoop:
    """The env's episode as a differentiable function of a law (module docstring).

    Args:
        config: the env's validated kwargs (`EpisodeConfig.from_kwargs(**env_kwargs)`).
        phi_method: the phi strategy of the differentiated steps; default the solver's choice
            (`differentiated_phi_method`: "eigh" for a symmetric linearization, whose gradient
            is tested; the env's "auto" may pick Krylov, whose backward is not).
    """

    def __init__(self, config: EpisodeConfig, phi_method: str | None = None) -> None:
        if not isinstance(config, EpisodeConfig):
            raise TypeError(f"config must be an EpisodeConfig, got {type(config).__name__}")
        self.config = config
        self.params = config.params
        self.phi_method = differentiated_phi_method(
            config.params, config.simulation.jacobian, phi_method or config.simulation.phi_method
        )
        # a plain model: no linearization kept between steps (module docstring)
        self.model = SwarmModel(config.params, "dense")
        self.target = torch.as_tensor(config.params.target_vector, dtype=torch.float64)

    def cost(self, law: SwarmFeedbackLaw, noise: EpisodeNoise) -> tuple[torch.Tensor, bool]:
        """(J, diverged): the sample-mean discrete cost of the episode (differentiable)."""
        config, model, target = self.config, self.model, self.target
        m = config.simulation.n_steps

        def control(t: float, x: torch.Tensor) -> torch.Tensor:
            s = torch.tensor(round(t / config.dt) / m, dtype=torch.float64)
            drift = model.interaction_drift(x).mean(dim=0)
            return law(x.mean(dim=0), drift, target, s)

        traj = simulate(
            self.params,
            config.simulation.integrator,
            jacobian=config.simulation.jacobian,
            phi_method=self.phi_method,
            n_steps=m,
            n_paths=config.simulation.n_paths,
            initial_positions=torch.as_tensor(noise.start, dtype=torch.float64),
            increments=noise.increments,
            control=control,
            model=model,
            divergence_threshold=config.divergence_threshold,
        )
        if traj.diverged:
            return torch.tensor(float("nan"), dtype=torch.float64), True
        costs = discrete_cost(traj.positions, traj.controls, target, self.params.gamma, config.dt)
        return costs.mean(), False


__all__ = ["ClosedLoop", "EpisodeNoise"]
