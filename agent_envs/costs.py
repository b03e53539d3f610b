"""Running cost and turnpike distance of the discrete control problem.

- running cost (`eq:running_cost`), per path:  c(x, u) = (1/N) sum_k (|x_k - xbar|^2
  + gamma |u_k|^2); the expectation is the mean over paths.
- discrete cost functional (`eq:discrete_cost_functional`): tau sum_{n<m} c(x^n, u^n)
  (left rectangle rule).
- turnpike distance: ||E x^n - xbar||^2 + ||u^n||^2 (sums over agents and coordinates), the
  quantity whose interior smallness is the turnpike shape.
"""

from __future__ import annotations

import numpy as np


def running_cost(x: np.ndarray, u: np.ndarray | None, target: np.ndarray, gamma: float):
    """c(x, u) per path: x, u of shape (..., N, d), target (d,); returns shape (...)."""
    return np.mean(agent_running_cost(x, u, target, gamma), axis=-1)


def agent_running_cost(x, u, target, gamma) -> np.ndarray:
    """Per-agent term |x_k - xbar|^2 + gamma |u_k|^2: shape (..., N)."""
    cost = np.sum((x - target) ** 2, axis=-1)
    if u is not None:
        cost = cost + gamma * np.sum(u * u, axis=-1)
    return cost


def discrete_cost(positions: np.ndarray, controls: np.ndarray, target, gamma, dt) -> np.ndarray:
    """tau sum_{n=0}^{m-1} c(x^n, u^n): positions (m+1, ..., N, d), controls (m, ..., N, d)."""
    m = controls.shape[0]
    return dt * np.sum(running_cost(positions[:m], controls, target, gamma), axis=0)


def turnpike_distance(mean_positions: np.ndarray, control: np.ndarray, target) -> np.ndarray:
    """||E x^n - xbar||^2 + ||u^n||^2 over agents and coordinates: inputs (..., N, d)."""
    return np.sum((mean_positions - target) ** 2, axis=(-2, -1)) + np.sum(control**2, axis=(-2, -1))
