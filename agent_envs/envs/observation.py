"""Observation layouts of the swarm environments, their spaces and their inverse (`split_*`).

Gymnasium (`agent_envs/Swarm-v0`), one float32 vector of length ``2 N d + d + 1``, (N, d)
blocks flattened agent-major (index ``k d + i`` is coordinate i of agent k)::

    [ E x (N d) | E interaction drift (N d) | target xbar (d) | t / T (1) ]

PettingZoo (`agent_envs.swarm_v0`), one float32 vector of length ``3 d + 1`` per agent k::

    [ E x_k (d) | E (1/N) sum_l p(x_k, x_l)(x_l - x_k) (d) | target xbar (d) | t / T (1) ]

E is the mean over the Brownian paths simulated together (the value itself when n_paths = 1);
the interaction drift is averaged path by path, as the expectation in the cheap control of
`eq:cheap_ctr` is. With these, the turnpike control
``u_k = beta (xbar - E x_k) - E (1/N) sum_l p(x_k, x_l)(x_l - x_k)`` is a function of the
observation (of each agent's own observation in the PettingZoo env).

Bounds (finite, as the checkers want them): positions and target lie in
``[-divergence_threshold, divergence_threshold]`` (a state beyond it ends the episode and is
never observed); the drift of the Cucker-Smale kernel ``w_l / (alpha^2 + |r|^2)`` obeys
``|(1/N) sum_l w_l r / (alpha^2 + |r|^2)| <= mean(w) / (2 alpha)`` (since
``|r| / (alpha^2 + |r|^2) <= 1 / (2 alpha)``); for a user kernel the drift bound is the largest
float32. The time fraction lies in [0, 1]. Observations are clipped to these bounds, which only
float32 rounding can reach.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces

from agent_envs.dynamics.kernels import CuckerSmaleKernel

FLOAT32_MAX = float(np.finfo(np.float32).max)


def observation_size(n_agents: int, dim: int) -> int:
    """Length of the Gymnasium observation: 2 N d + d + 1."""
    return 2 * n_agents * dim + dim + 1


def agent_observation_size(dim: int) -> int:
    """Length of one PettingZoo agent's observation: 3 d + 1."""
    return 3 * dim + 1


def interaction_drift_bound(kernel: Any) -> float:
    """An upper bound on every coordinate of the interaction drift for this kernel.

    ``mean(w) / (2 alpha)`` for `CuckerSmaleKernel` (see the module docstring), else the largest
    float32 (no bound is known for a user kernel).
    """
    if isinstance(kernel, CuckerSmaleKernel):
        bound = float(np.mean(kernel.weights)) / (2.0 * kernel.alpha)
        return min(bound, FLOAT32_MAX)
    return FLOAT32_MAX


def _bounds(n_blocks: int, dim: int, position_bound: float, drift_bound: float) -> np.ndarray:
    """Upper bounds of `n_blocks` position and drift blocks of size dim, target, time."""
    return np.concatenate(
        [
            np.full(n_blocks * dim, position_bound),
            np.full(n_blocks * dim, drift_bound),
            np.full(dim, position_bound),
            [1.0],
        ]
    ).astype(np.float32)


def _box(high: np.ndarray, dim: int) -> spaces.Box:
    low = -high
    low[-1] = 0.0  # the time fraction t/T is in [0, 1]
    return spaces.Box(low=low, high=high, dtype=np.float32)


def observation_space(
    n_agents: int, dim: int, position_bound: float, drift_bound: float
) -> spaces.Box:
    """The Gymnasium observation space Box((2 N d + d + 1,), float32) (also the PZ state)."""
    return _box(_bounds(n_agents, dim, position_bound, drift_bound), dim)


def agent_observation_space(dim: int, position_bound: float, drift_bound: float) -> spaces.Box:
    """One PettingZoo agent's observation space Box((3 d + 1,), float32)."""
    return _box(_bounds(1, dim, position_bound, drift_bound), dim)


def global_observation(
    mean_positions: np.ndarray,
    mean_drift: np.ndarray,
    target: np.ndarray,
    time_fraction: float | np.ndarray,
    space: spaces.Box,
) -> np.ndarray:
    """The Gymnasium observation from path means, target and t/T; a new float32 array.

    Batched over leading (env) axes: mean_positions and mean_drift (..., N, d), target
    (..., d), time_fraction a float or (...); returns (..., 2 N d + d + 1). torch tensors
    give a float32 tensor on their device.
    """
    lead = mean_positions.shape[:-2]
    if not isinstance(mean_positions, np.ndarray):
        return _global_observation_tensor(mean_positions, mean_drift, target, time_fraction, space)
    obs = np.empty((*lead, *space.shape), dtype=np.float32)
    nd = mean_positions.shape[-2] * mean_positions.shape[-1]
    obs[..., :nd] = mean_positions.reshape(*lead, nd)
    obs[..., nd : 2 * nd] = mean_drift.reshape(*lead, nd)
    obs[..., 2 * nd : -1] = target
    obs[..., -1] = time_fraction
    return np.clip(obs, space.low, space.high, out=obs)


def _global_observation_tensor(
    mean_positions: Any, mean_drift: Any, target: Any, time_fraction: Any, space: spaces.Box
) -> Any:
    """`global_observation` for torch tensors (same layout, float32 on their device)."""
    import torch

    lead = tuple(mean_positions.shape[:-2])
    nd = mean_positions.shape[-2] * mean_positions.shape[-1]
    device = mean_positions.device
    time_fraction = torch.as_tensor(time_fraction, dtype=torch.float64, device=device)
    parts = [
        mean_positions.reshape(*lead, nd),
        mean_drift.reshape(*lead, nd),
        torch.broadcast_to(torch.as_tensor(target, device=device), (*lead, target.shape[-1])),
        torch.broadcast_to(time_fraction, lead)[..., None],
    ]
    obs = torch.cat([part.to(torch.float32) for part in parts], dim=-1)
    low = torch.as_tensor(space.low, device=device)
    high = torch.as_tensor(space.high, device=device)
    return torch.minimum(torch.maximum(obs, low), high)


def agent_observations(
    mean_positions: np.ndarray,
    mean_drift: np.ndarray,
    target: np.ndarray,
    time_fraction: float,
    space: spaces.Box,
) -> np.ndarray:
    """All agents' PettingZoo observations: one new (N, 3 d + 1) float32 array, row k = agent k."""
    n, d = mean_positions.shape
    obs = np.empty((n, 3 * d + 1), dtype=np.float32)
    obs[:, :d] = mean_positions
    obs[:, d : 2 * d] = mean_drift
    obs[:, 2 * d : 3 * d] = target
    obs[:, -1] = time_fraction
    return np.clip(obs, space.low, space.high, out=obs)


def split_observation(obs: Any, n_agents: int, dim: int) -> dict[str, np.ndarray]:
    """Inverse of the Gymnasium layout, batched over leading axes.

    Args:
        obs: (..., 2 N d + d + 1), e.g. one observation or a VecEnv batch (n_envs, obs_dim).
        n_agents, dim: N and d of the env.

    Returns:
        dict with ``positions`` (..., N, d), ``interaction_drift`` (..., N, d), ``target``
        (..., d) and ``time_fraction`` (...), as float64 arrays.
    """
    arr = np.asarray(obs, dtype=np.float64)
    size = observation_size(n_agents, dim)
    if arr.ndim < 1 or arr.shape[-1] != size:
        raise ValueError(
            f"obs must have shape (..., {size}) for n_agents={n_agents}, dim={dim}; got {arr.shape}"
        )
    lead = arr.shape[:-1]
    nd = n_agents * dim
    return {
        "positions": arr[..., :nd].reshape(*lead, n_agents, dim),
        "interaction_drift": arr[..., nd : 2 * nd].reshape(*lead, n_agents, dim),
        "target": arr[..., 2 * nd : 2 * nd + dim],
        "time_fraction": arr[..., -1],
    }


def split_agent_observation(obs: Any, dim: int) -> dict[str, np.ndarray]:
    """Inverse of the PettingZoo per-agent layout, batched over leading axes.

    Returns a dict with ``position`` (..., d), ``interaction_drift`` (..., d), ``target``
    (..., d) and ``time_fraction`` (...), as float64 arrays.
    """
    arr = np.asarray(obs, dtype=np.float64)
    size = agent_observation_size(dim)
    if arr.ndim < 1 or arr.shape[-1] != size:
        raise ValueError(f"obs must have shape (..., {size}) for dim={dim}; got {arr.shape}")
    return {
        "position": arr[..., :dim],
        "interaction_drift": arr[..., dim : 2 * dim],
        "target": arr[..., 2 * dim : 3 * dim],
        "time_fraction": arr[..., -1],
    }


def agent_observations_from_global(obs: Any, n_agents: int, dim: int) -> np.ndarray:
    """The N per-agent (PettingZoo) observations held in Gymnasium observations, batched.

    Args:
        obs: (..., 2 N d + d + 1) Gymnasium observations.
        n_agents, dim: N and d of the env.

    Returns:
        (..., N, 3 d + 1) float32: row k is ``[E x_k | E drift on k | target | t/T]``, the row
        `agent_observations` builds from the same path means (without its clipping, which the
        Gymnasium observation has already had).
    """
    parts = split_observation(obs, n_agents, dim)
    lead = parts["positions"].shape[:-2]
    shape = (*lead, n_agents, dim)
    rows = np.concatenate(
        [
            parts["positions"],
            parts["interaction_drift"],
            np.broadcast_to(parts["target"][..., None, :], shape),
            np.broadcast_to(parts["time_fraction"][..., None, None], (*lead, n_agents, 1)),
        ],
        axis=-1,
    )
    return rows.astype(np.float32)
