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

These are the default layouts (``observation="absolute"``). The env kwarg ``observation``
selects another (`agent_envs.envs.interface`: "relative", "modes", "summary" for the Gymnasium
env; "relative", "swarm", "local" for a PettingZoo agent); every function here takes it as
`layout`. The ``"local"`` row (own offset, K nearest neighbours, mask, t / T) is built by
`agent_envs.envs.local_observation`; the per-agent functions here take its K as `neighbours`.

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
from agent_envs.envs.interface import (
    AGENT_OBSERVATIONS,
    DEFAULT_NEIGHBOURS,
    OBSERVATIONS,
    from_modes,
    modes_bound,
    swarm_summary,
    to_modes,
)
from agent_envs.envs.local_observation import (
    local_observation_size,
    local_observation_space,
    local_observations,
    split_local_observation,
)

FLOAT32_MAX = float(np.finfo(np.float32).max)


def check_layout(layout: str, agent: bool = False) -> str:
    """`layout` if it is a Gymnasium (`agent`: a PettingZoo agent's) observation layout;
    ValueError naming ``observation`` and the layouts otherwise."""
    accepted = AGENT_OBSERVATIONS if agent else OBSERVATIONS
    if layout not in accepted:
        raise ValueError(f"observation must be one of {', '.join(accepted)}; got {layout!r}")
    return layout


def observation_size(n_agents: int, dim: int, layout: str = "absolute") -> int:
    """Length of the Gymnasium observation: 2 N d + d + 1 (``"summary"``: 3 d + 1)."""
    check_layout(layout)
    if layout == "summary":
        return 3 * dim + 1
    return 2 * n_agents * dim + dim + 1


def agent_observation_size(
    dim: int, layout: str = "absolute", neighbours: int = DEFAULT_NEIGHBOURS
) -> int:
    """Length of one PettingZoo agent's observation: 3 d + 1 (``"swarm"``: 5 d + 1;
    ``"local"``: (K + 1)(d + 1), K = `neighbours`)."""
    check_layout(layout, agent=True)
    if layout == "local":
        return local_observation_size(dim, neighbours)
    return 5 * dim + 1 if layout == "swarm" else 3 * dim + 1


def interaction_drift_bound(kernel: Any) -> float:
    """An upper bound on every coordinate of the interaction drift for this kernel.

    ``mean(w) / (2 alpha)`` for `CuckerSmaleKernel` (see the module docstring), else the largest
    float32 (no bound is known for a user kernel).
    """
    if isinstance(kernel, CuckerSmaleKernel):
        bound = float(np.mean(kernel.weights)) / (2.0 * kernel.alpha)
        return min(bound, FLOAT32_MAX)
    return FLOAT32_MAX


def _block(bound: float, size: int) -> np.ndarray:
    return np.full(size, min(bound, FLOAT32_MAX))


def _bounds(
    n_blocks: int, dim: int, position_bound: float, drift_bound: float, layout: str = "absolute"
) -> np.ndarray:
    """Upper bounds of the layout's entries (`agent_envs.envs.interface`): positions or their
    offsets from the target (|x - xbar| < 2 threshold), drift, target, [centre offset, spread],
    time. In modes a coordinate is at most sqrt(N) times the largest entry
    (`interface.modes_bound`)."""
    offset = 2.0 * position_bound
    if layout == "summary":
        parts = [_block(offset, 2 * dim), _block(position_bound, dim)]
    else:
        scale = modes_bound(n_blocks) if layout == "modes" else 1.0
        position = position_bound if layout == "absolute" else offset
        parts = [
            _block(scale * position, n_blocks * dim),
            _block(scale * drift_bound, n_blocks * dim),
            _block(position_bound, dim),
        ]
        if layout == "swarm":
            parts.append(_block(offset, 2 * dim))
    return np.concatenate([*parts, [1.0]]).astype(np.float32)


def _box(high: np.ndarray, dim: int) -> spaces.Box:
    low = -high
    low[-1] = 0.0  # the time fraction t/T is in [0, 1]
    return spaces.Box(low=low, high=high, dtype=np.float32)


def observation_space(
    n_agents: int, dim: int, position_bound: float, drift_bound: float, layout: str = "absolute"
) -> spaces.Box:
    """The Gymnasium observation space Box((2 N d + d + 1,), float32) (also the PZ state);
    Box((3 d + 1,)) for the ``"summary"`` layout."""
    return _box(_bounds(n_agents, dim, position_bound, drift_bound, layout), dim)


def agent_observation_space(
    dim: int,
    position_bound: float,
    drift_bound: float,
    layout: str = "absolute",
    neighbours: int = DEFAULT_NEIGHBOURS,
) -> spaces.Box:
    """One PettingZoo agent's observation space Box((3 d + 1,), float32) (``"swarm"``: 5 d + 1;
    ``"local"``: `local_observation.local_observation_space`, (K + 1)(d + 1) with K =
    `neighbours`)."""
    if layout == "local":
        return local_observation_space(dim, position_bound, neighbours)
    return _box(_bounds(1, dim, position_bound, drift_bound, layout), dim)


def _layout_blocks(layout: str, mean_positions: Any, mean_drift: Any, target: Any) -> list[Any]:
    """The (..., k, d) blocks before the target and time of a Gymnasium layout."""
    if layout == "absolute":
        return [mean_positions, mean_drift]
    offsets = mean_positions - target[..., None, :]
    if layout == "relative":
        return [offsets, mean_drift]
    if layout == "modes":
        return [to_modes(offsets), to_modes(mean_drift)]
    centre, spread = swarm_summary(mean_positions, target)
    return [centre[..., None, :], spread[..., None, :]]


def global_observation(
    mean_positions: np.ndarray,
    mean_drift: np.ndarray,
    target: np.ndarray,
    time_fraction: float | np.ndarray,
    space: spaces.Box,
    layout: str = "absolute",
) -> np.ndarray:
    """The Gymnasium observation from path means, target and t/T; a new float32 array.

    Batched over leading (env) axes: mean_positions and mean_drift (..., N, d), target
    (..., d), time_fraction a float or (...); returns (..., 2 N d + d + 1) (``"summary"``:
    (..., 3 d + 1)) in the `layout` of `agent_envs.envs.interface`. torch tensors give a
    float32 tensor on their device.
    """
    lead = mean_positions.shape[:-2]
    if not isinstance(mean_positions, np.ndarray):
        blocks = _layout_blocks(layout, mean_positions, mean_drift, target)
        return _global_observation_tensor(blocks, target, time_fraction, space)
    blocks = _layout_blocks(layout, mean_positions, mean_drift, np.asarray(target))
    obs = np.empty((*lead, *space.shape), dtype=np.float32)
    start = 0
    for block in blocks:
        size = block.shape[-2] * block.shape[-1]
        obs[..., start : start + size] = block.reshape(*lead, size)
        start += size
    obs[..., start:-1] = target
    obs[..., -1] = time_fraction
    return np.clip(obs, space.low, space.high, out=obs)


def _global_observation_tensor(
    blocks: list[Any], target: Any, time_fraction: Any, space: spaces.Box
) -> Any:
    """`global_observation` for torch tensors (same layout, float32 on their device)."""
    import torch

    lead = tuple(blocks[0].shape[:-2])
    device = blocks[0].device
    time_fraction = torch.as_tensor(time_fraction, dtype=torch.float64, device=device)
    parts = [block.reshape(*lead, block.shape[-2] * block.shape[-1]) for block in blocks]
    parts += [
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
    layout: str = "absolute",
    neighbours: int = DEFAULT_NEIGHBOURS,
) -> np.ndarray:
    """All agents' PettingZoo observations: one new (N, size) float32 array, row k = agent k.

    `layout` "absolute" | "relative" | "swarm" | "local" (`agent_envs.envs.interface`; "local"
    reads neither `mean_drift` nor anything global, and takes K = `neighbours`).
    """
    if layout == "local":
        return local_observations(mean_positions, target, time_fraction, space, neighbours)
    n, d = mean_positions.shape
    obs = np.empty((n, agent_observation_size(d, layout)), dtype=np.float32)
    target = np.asarray(target)
    obs[:, :d] = mean_positions if layout == "absolute" else mean_positions - target
    obs[:, d : 2 * d] = mean_drift
    obs[:, 2 * d : 3 * d] = target
    if layout == "swarm":
        centre, spread = swarm_summary(mean_positions, target)
        obs[:, 3 * d : 4 * d] = centre
        obs[:, 4 * d : 5 * d] = spread
    obs[:, -1] = time_fraction
    return np.clip(obs, space.low, space.high, out=obs)


def split_observation(
    obs: Any, n_agents: int, dim: int, layout: str = "absolute"
) -> dict[str, np.ndarray]:
    """Inverse of the Gymnasium layout, batched over leading axes.

    Args:
        obs: (..., 2 N d + d + 1), e.g. one observation or a VecEnv batch (n_envs, obs_dim).
        n_agents, dim: N and d of the env.
        layout: the env's ``observation`` option; "relative" and "modes" are mapped back to
            positions (x = offset + xbar) and drift (`interface.from_modes`), to float32
            round-off. "summary" holds no agent's position: ValueError.

    Returns:
        dict with ``positions`` (..., N, d), ``interaction_drift`` (..., N, d), ``target``
        (..., d) and ``time_fraction`` (...), as float64 arrays.
    """
    check_layout(layout)
    if layout == "summary":
        raise ValueError(
            "observation='summary' holds the swarm's centre and spread, not the agents' "
            "positions; a controller that needs them acts on 'absolute', 'relative' or 'modes'"
        )
    arr = np.asarray(obs, dtype=np.float64)
    size = observation_size(n_agents, dim)
    if arr.ndim < 1 or arr.shape[-1] != size:
        raise ValueError(
            f"obs must have shape (..., {size}) for n_agents={n_agents}, dim={dim}; got {arr.shape}"
        )
    lead = arr.shape[:-1]
    nd = n_agents * dim
    positions = arr[..., :nd].reshape(*lead, n_agents, dim)
    drift = arr[..., nd : 2 * nd].reshape(*lead, n_agents, dim)
    target = arr[..., 2 * nd : 2 * nd + dim]
    if layout == "modes":
        positions, drift = from_modes(positions), from_modes(drift)
    if layout != "absolute":
        positions = positions + target[..., None, :]
    return {
        "positions": positions,
        "interaction_drift": drift,
        "target": target,
        "time_fraction": arr[..., -1],
    }


def split_agent_observation(
    obs: Any, dim: int, layout: str = "absolute", neighbours: int = DEFAULT_NEIGHBOURS
) -> dict[str, np.ndarray]:
    """Inverse of the PettingZoo per-agent layout, batched over leading axes.

    Returns a dict with ``position`` (..., d) (absolute: offsets are mapped back),
    ``interaction_drift`` (..., d), ``target`` (..., d) and ``time_fraction`` (...), as float64
    arrays; the ``"swarm"`` layout adds ``centre_offset`` and ``spread`` (..., d). The
    ``"local"`` row holds no position, drift or target: its dict is
    `local_observation.split_local_observation`'s (``offset``, ``neighbour_offsets``,
    ``neighbour_mask``, ``time_fraction``).
    """
    if check_layout(layout, agent=True) == "local":
        return split_local_observation(obs, dim, neighbours)
    arr = np.asarray(obs, dtype=np.float64)
    size = agent_observation_size(dim, layout)
    if arr.ndim < 1 or arr.shape[-1] != size:
        raise ValueError(f"obs must have shape (..., {size}) for dim={dim}; got {arr.shape}")
    target = arr[..., 2 * dim : 3 * dim]
    position = arr[..., :dim] if layout == "absolute" else arr[..., :dim] + target
    parts = {
        "position": position,
        "interaction_drift": arr[..., dim : 2 * dim],
        "target": target,
        "time_fraction": arr[..., -1],
    }
    if layout == "swarm":
        parts["centre_offset"] = arr[..., 3 * dim : 4 * dim]
        parts["spread"] = arr[..., 4 * dim : 5 * dim]
    return parts


def agent_observations_from_global(
    obs: Any,
    n_agents: int,
    dim: int,
    layout: str = "absolute",
    neighbours: int = DEFAULT_NEIGHBOURS,
) -> np.ndarray:
    """The N per-agent (PettingZoo) observations held in Gymnasium observations, batched.

    Args:
        obs: (..., 2 N d + d + 1) Gymnasium observations in the default ("absolute") layout.
        n_agents, dim: N and d of the env.
        layout: the per-agent layout to build ("absolute" | "relative" | "swarm" | "local").
        neighbours: K of the "local" layout (ignored by the others).

    Returns:
        (..., N, size) float32: row k is the row `agent_observations` builds from the same path
        means in `layout` (without its clipping, which the Gymnasium observation has already
        had; the swarm's centre and spread, and the local layout's nearest neighbours and their
        offsets, are taken from the float32 positions, so a tie or a rounding may rank two
        neighbours otherwise than the PettingZoo env's float64 search).
    """
    if check_layout(layout, agent=True) == "local":
        return _local_rows_from_global(obs, n_agents, dim, neighbours)
    parts = split_observation(obs, n_agents, dim)
    lead = parts["positions"].shape[:-2]
    shape = (*lead, n_agents, dim)
    positions, target = parts["positions"], parts["target"]
    blocks = [
        positions if layout == "absolute" else positions - target[..., None, :],
        parts["interaction_drift"],
        np.broadcast_to(target[..., None, :], shape),
    ]
    if layout == "swarm":
        centre, spread = swarm_summary(positions, target)
        blocks += [
            np.broadcast_to(centre[..., None, :], shape),
            np.broadcast_to(spread[..., None, :], shape),
        ]
    blocks.append(np.broadcast_to(parts["time_fraction"][..., None, None], (*lead, n_agents, 1)))
    return np.concatenate(blocks, axis=-1).astype(np.float32)


def _local_rows_from_global(obs: Any, n_agents: int, dim: int, neighbours: int) -> np.ndarray:
    """`agent_observations_from_global` for the "local" layout: (..., N, (K + 1)(d + 1))."""
    parts = split_observation(obs, n_agents, dim)
    positions = np.asarray(parts["positions"], dtype=np.float64)
    lead = positions.shape[:-2]
    unbounded = local_observation_space(dim, np.inf, neighbours)
    flat = positions.reshape(-1, n_agents, dim)
    targets = np.asarray(parts["target"], dtype=np.float64).reshape(-1, dim)
    times = np.asarray(parts["time_fraction"], dtype=np.float64).reshape(-1)
    rows = [
        local_observations(flat[b], targets[b], float(times[b]), unbounded, neighbours)
        for b in range(flat.shape[0])
    ]
    size = local_observation_size(dim, neighbours)
    out = np.stack(rows) if rows else np.zeros((0, n_agents, size), np.float32)
    return out.reshape(*lead, n_agents, size)
