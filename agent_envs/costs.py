"""Running cost and turnpike distance of the discrete control problem.

- running cost (`eq:running_cost`), per path:  c(x, u) = (1/N) sum_k (|x_k - xbar|^2
  + gamma |u_k|^2); the expectation is the mean over paths.
- discrete cost functional (`eq:discrete_cost_functional`): tau sum_{n<m} c(x^n, u^n)
  (left rectangle rule).
- turnpike distance: ||E x^n - xbar||^2 + ||u^n||^2 (sums over agents and coordinates), the
  quantity whose interior smallness is the turnpike shape.

Inputs are numpy arrays or torch tensors (`agent_envs.arrays`); the result is in the library
of `x` (differentiable on torch). The target may be a numpy array or a tensor.
"""

from __future__ import annotations

from typing import Any

from agent_envs import arrays


def _target_like(target: Any, x: Any) -> Any:
    return arrays.asarray(target, like=x) if arrays.is_torch(x) else target


def running_cost(x: Any, u: Any, target: Any, gamma: float) -> Any:
    """c(x, u) per path: x, u of shape (..., N, d), target (d,); returns shape (...)."""
    xp = arrays.namespace(x, u)
    return xp.mean(agent_running_cost(x, u, target, gamma), axis=-1)


def agent_running_cost(x: Any, u: Any, target: Any, gamma: float) -> Any:
    """Per-agent term |x_k - xbar|^2 + gamma |u_k|^2: shape (..., N)."""
    cost = arrays.sum_axis((x - _target_like(target, x)) ** 2, -1)
    if u is not None:
        cost = cost + gamma * arrays.sum_axis(u * u, -1)
    return cost


def discrete_cost(positions: Any, controls: Any, target: Any, gamma: float, dt: float) -> Any:
    """tau sum_{n=0}^{m-1} c(x^n, u^n): positions (m+1, ..., N, d), controls (m, ..., N, d)."""
    xp = arrays.namespace(positions, controls)
    m = controls.shape[0]
    return dt * xp.sum(running_cost(positions[:m], controls, target, gamma), axis=0)


def turnpike_distance(mean_positions: Any, control: Any, target: Any) -> Any:
    """||E x^n - xbar||^2 + ||u^n||^2 over agents and coordinates: inputs (..., N, d)."""
    xp = arrays.namespace(mean_positions, control)
    err = mean_positions - _target_like(target, mean_positions)
    return xp.sum(err**2, axis=(-2, -1)) + xp.sum(control**2, axis=(-2, -1))
