"""Explicit schemes: Euler-Maruyama, explicit Euler and Heun (explicit trapezoidal rule).

For additive noise sigma dW:

- EM (`eq:eulermaru`):   x+ = x + dt F(t, x) + sigma dW.
- EE: the same formula; with sigma = 0 (the paper's deterministic tests) it is explicit Euler.
- Heun (Section 5.1, stochastic Heun for additive noise):
      X = x + dt F(t, x) + sigma dW,
      x+ = x + dt/2 (F(t, x) + F(t + dt, X)) + sigma dW.
  The control is held fixed over the step (zero-order hold), as in every scheme here.
"""

from __future__ import annotations

import numpy as np

from agent_envs.integrators.base import DriftModel, Integrator


class EulerMaruyama(Integrator):
    """x+ = x + dt F(t, x, u) + sigma dW (`eq:eulermaru`); strong order 1 for additive noise."""

    name = "em"
    strong_order = 1.0
    deterministic_order = 1.0

    def step(self, model: DriftModel, x, u, t, dt, dW, du_dt=None) -> np.ndarray:
        return x + dt * model.drift(t, x, u) + model.sigma * dW


class ExplicitEuler(EulerMaruyama):
    """Explicit Euler x+ = x + dt F(x, u); with sigma > 0 it coincides with EM."""

    name = "ee"


class Heun(Integrator):
    """Heun's method / explicit trapezoidal rule (RK2), with additive noise."""

    name = "heun"
    strong_order = 1.0
    deterministic_order = 2.0

    def step(self, model: DriftModel, x, u, t, dt, dW, du_dt=None) -> np.ndarray:
        noise = model.sigma * dW
        f0 = model.drift(t, x, u)
        predictor = x + dt * f0 + noise
        u1 = u if du_dt is None or u is None else u + dt * du_dt
        return x + 0.5 * dt * (f0 + model.drift(t + dt, predictor, u1)) + noise
