"""The PettingZoo env's local observation (``observation="local"``): each agent's own offset to
the target, its k nearest neighbours' relative positions, and t / T; no global statistic.

Row of agent k (``(K + 1)(d + 1)`` float32 entries, K = the kwarg ``neighbours``)::

    [ E x_k - xbar (d) | E x_l - E x_k for its K nearest l (K d) | mask (K) | t / T (1) ]

E is the mean over the Brownian paths (the value itself when n_paths = 1), as in the other
layouts. Neighbour slot j holds the j-th nearest other agent l (j = 0 nearest), its mask entry
1. "Nearest" is by the squared Euclidean distance ``|E x_l - E x_k|^2`` in R^d, computed in
float64 as ``sum_i (E x_{l,i} - E x_{k,i})^2`` with the coordinates added in order i = 0 .. d-1
(`squared_distances`); agents at the same distance (equal float64 values) are ranked by the
lower agent index, so the ranking is stable and does not depend on the search used. An agent
is never its own neighbour; with N - 1 < K the slots j >= N - 1 are zeros with mask 0 (the row
keeps its length, so every agent's space is the same for every N).

**Communication graph.** Agent k observes agent l iff l is among k's K nearest: a directed
K-nearest-neighbour graph on the path means, min(K, N - 1) out-edges per agent (not
symmetric: l may be among k's nearest while k is not among l's), rebuilt every step. Each agent
needs only its neighbours' mean positions, no swarm-wide sum: per step N min(K, N - 1) messages
of d numbers. The target and t / T are common knowledge.

**Cost per step.** Up to `BRUTE_FORCE_MAX_AGENTS` agents, the exact search in row blocks of at
most `BLOCK_ENTRIES` squared distances (2^22, 32 MiB): O(N^2 d) time, O(min(N^2,
BLOCK_ENTRIES)) memory. Above it, matrix-free: a k-d tree (`scipy.spatial.cKDTree`,
O(N log N) to build, about O(K log N) per agent to query) proposes candidates, a ball query of
the K-th tree distance (widened by a relative 1e-9 for the tree's rounding) collects every tie,
and the same exact distances and ranking as the blocks pick the K; so both give the same
indices. Where agents share a position exactly (a collapsed swarm read in float32), the
search runs over the distinct positions instead and ranks each position's candidate agents
once for all its agents (`_nearest_grouped`, the same indices: 0.08 s at N = 10^4 for a
float32 swarm of spread 1e-6, where the blocks took 26 s when everyone sat at one point).
Where the candidates exceed `CANDIDATE_BUDGET_PER_AGENT` per agent on average, either search
falls back to the blocks (exact, memory-bounded, O(N^2 d) time).
The observation rows themselves cost O(N K d).

Bounds (as the "relative" layout's): the offsets to the target and between agents lie in
``[-2 threshold, 2 threshold]`` (every observed position is within the divergence threshold),
the mask and t / T in [0, 1]. Observations are clipped to them (only float32 rounding reaches
them).
"""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np
from gymnasium import spaces

#: Up to this N the exact search runs on blocks of squared distances; above it, on a k-d tree
#: (the two cost the same near N = 256 here: 0.6 ms at d = 1, K = 6; at N = 2048 the blocks
#: take 90 ms, the tree 5 ms).
BRUTE_FORCE_MAX_AGENTS = 256
#: The most squared distances one block holds (2^22 float64: 32 MiB).
BLOCK_ENTRIES = 1 << 22
#: The k-d tree path's candidates per agent, on average, before it falls back to the blocks.
CANDIDATE_BUDGET_PER_AGENT = 64
#: Relative widening of the tree's K-th distance for its ball query (its rounding is ~1e-16).
_TREE_WIDENING = 1e-9

_FLOAT32_MAX = float(np.finfo(np.float32).max)


def local_observation_size(dim: int, neighbours: int) -> int:
    """Length of one agent's local row: (K + 1)(d + 1)."""
    return (neighbours + 1) * (dim + 1)


def local_observation_space(dim: int, position_bound: float, neighbours: int) -> spaces.Box:
    """One agent's local observation space: Box((K + 1)(d + 1),) float32 with the offsets in
    [-2 position_bound, 2 position_bound] and the mask and t / T in [0, 1]."""
    offset = min(2.0 * position_bound, _FLOAT32_MAX)
    high = np.full(local_observation_size(dim, neighbours), offset)
    low = -high
    masks = slice((neighbours + 1) * dim, None)  # the mask entries and t / T
    high[masks], low[masks] = 1.0, 0.0
    return spaces.Box(low=low.astype(np.float32), high=high.astype(np.float32), dtype=np.float32)


def squared_distances(differences: np.ndarray) -> np.ndarray:
    """sum_i differences[..., i]^2, the coordinates added in order i = 0 .. d-1: (..., d) -> (...).

    Written out (not ``np.sum``, whose pairwise order may depend on the array's shape) so that
    the same pair gives the same float64 bits in every search."""
    total = differences[..., 0] * differences[..., 0]
    for i in range(1, differences.shape[-1]):
        total += differences[..., i] * differences[..., i]
    return total


def _ranked(
    owners: np.ndarray, others: np.ndarray, distances: np.ndarray, n: int, count: int
) -> np.ndarray:
    """The first `count` candidates of each owner 0 .. n-1 by (distance, index): (n, count).

    owners, others, distances (M,): candidate pairs; every owner has at least `count`, and they
    hold every agent nearer than its `count`-th (and every one at that distance)."""
    order = np.lexsort((others, distances, owners))
    counts = np.bincount(owners, minlength=n)
    starts = np.cumsum(counts) - counts
    return others[order[starts[:, None] + np.arange(count)]]


def _nearest_blocks(x: np.ndarray, count: int) -> np.ndarray:
    """`nearest_neighbours` by the exact squared distances, in row blocks of at most
    `BLOCK_ENTRIES` entries (no N x N array above that)."""
    n = x.shape[0]
    rows_per_block = max(1, BLOCK_ENTRIES // n)
    blocks = []
    for start in range(0, n, rows_per_block):
        rows = np.arange(start, min(n, start + rows_per_block))
        dist = squared_distances(x[None, :, :] - x[rows, None, :])  # (b, N)
        dist[np.arange(rows.size), rows] = np.inf  # never its own neighbour
        if count < n - 1:  # candidates: every agent at most the count-th smallest distance away
            kth = np.partition(dist, count - 1, axis=1)[:, count - 1]
            owners, others = np.nonzero(dist <= kth[:, None])
        else:
            owners, others = np.nonzero(np.isfinite(dist))
        blocks.append(_ranked(owners, others, dist[owners, others], rows.size, count))
    return np.concatenate(blocks, axis=0)


def _ball_candidates(points: np.ndarray, wanted: int) -> list[list[int]]:
    """For each of the points (M, d), the indices of every point at most its `wanted`-th
    smallest k-d tree distance away, itself included, in no particular order: a ball query of
    that distance, widened by `_TREE_WIDENING` for the tree's rounding, so every tie at it is
    in (both searches' candidates)."""
    from scipy.spatial import cKDTree

    tree = cKDTree(points)
    tree_distances, _ = tree.query(points, k=wanted)
    radius = tree_distances.reshape(len(points), -1)[:, -1]  # k = 1 gives a flat array
    radius = np.nextafter(radius * (1.0 + _TREE_WIDENING), np.inf)
    return tree.query_ball_point(points, radius)


def _nearest_tree(x: np.ndarray, count: int) -> np.ndarray | None:
    """`nearest_neighbours` from a k-d tree's candidates, ranked by the exact distances; None
    where the candidates exceed the budget (exact ties of many agents)."""
    n = x.shape[0]
    lists = _ball_candidates(x, count + 1)  # (self among them, or a tie at distance 0)
    lengths = np.fromiter(map(len, lists), dtype=np.intp, count=n)
    total = int(lengths.sum())
    if total > CANDIDATE_BUDGET_PER_AGENT * n:
        return None
    others = np.fromiter(itertools.chain.from_iterable(lists), dtype=np.intp, count=total)
    owners = np.repeat(np.arange(n), lengths)
    keep = others != owners
    owners, others = owners[keep], others[keep]
    distances = squared_distances(x[others] - x[owners])
    return _ranked(owners, others, distances, n, count)


def _nearest_grouped(x: np.ndarray, count: int) -> np.ndarray | None:
    """`nearest_neighbours` for swarms with exactly equal positions (a collapsed swarm read in
    float32): the search runs over the U distinct positions, then each position's candidate
    agents (the lowest `count` + 1 indices of each candidate position, which is all the ranking
    can take from it) are ranked by (exact distance, index) once for all its agents. The same
    indices as the blocks; None where the candidates exceed the budget."""
    n = x.shape[0]
    unique, inverse = np.unique(x, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    members = np.argsort(inverse, kind="stable")  # grouped by position, each in index order
    sizes = np.bincount(inverse, minlength=len(unique))
    starts = np.cumsum(sizes) - sizes
    candidates = _ball_candidates(unique, min(count + 1, len(unique)))
    if sum(map(len, candidates)) > CANDIDATE_BUDGET_PER_AGENT * n:
        return None
    out = np.empty((n, count), dtype=np.intp)
    for position, near in enumerate(candidates):
        agents = np.concatenate(
            [members[starts[v] : starts[v] + min(sizes[v], count + 1)] for v in near]
        )
        distances = squared_distances(x[agents] - unique[position])
        first = agents[np.lexsort((agents, distances))][: count + 1]
        mine = members[starts[position] : starts[position] + sizes[position]]
        out[mine] = first[:count]  # agents not among the first count + 1: none of them is k
        for k in np.intersect1d(mine, first):
            out[k] = first[first != k][:count]
    return out


def nearest_neighbours(x: np.ndarray, neighbours: int) -> np.ndarray:
    """The min(K, N - 1) nearest other agents of each agent, nearest first: (N, min(K, N - 1))
    int indices, for positions x (N, d) float64 (ranking and search: the module docstring)."""
    n = x.shape[0]
    count = min(neighbours, n - 1)
    if count == 0:
        return np.empty((n, 0), dtype=np.intp)
    if n > BRUTE_FORCE_MAX_AGENTS:
        # equal positions (a collapsed swarm read in float32): search the distinct ones
        duplicates = len(np.unique(x, axis=0)) < n
        found = (_nearest_grouped if duplicates else _nearest_tree)(x, count)
        if found is not None:
            return found
    return _nearest_blocks(x, count)


def local_observations(
    mean_positions: np.ndarray,
    target: np.ndarray,
    time_fraction: float,
    space: spaces.Box,
    neighbours: int,
) -> np.ndarray:
    """Every agent's local row (module docstring): one new (N, (K + 1)(d + 1)) float32 array,
    row k = agent k, from the path means (N, d), the target (d,) and t / T, clipped to `space`."""
    x = np.asarray(mean_positions, dtype=np.float64)
    n, d = x.shape
    nearest = nearest_neighbours(x, neighbours)
    count = nearest.shape[1]
    obs = np.zeros((n, local_observation_size(d, neighbours)), dtype=np.float32)
    obs[:, :d] = x - np.asarray(target)
    offsets = x[nearest] - x[:, None, :]  # (N, count, d)
    obs[:, d : d + count * d] = offsets.reshape(n, count * d)
    masks = (neighbours + 1) * d
    obs[:, masks : masks + count] = 1.0
    obs[:, -1] = time_fraction
    return np.clip(obs, space.low, space.high, out=obs)


def split_local_observation(obs: Any, dim: int, neighbours: int) -> dict[str, np.ndarray]:
    """Inverse of the local row, batched over leading axes: ``offset`` (..., d) = E x_k - xbar,
    ``neighbour_offsets`` (..., K, d), ``neighbour_mask`` (..., K) and ``time_fraction``
    (...), as float64 arrays; ValueError for a wrong last axis."""
    arr = np.asarray(obs, dtype=np.float64)
    size = local_observation_size(dim, neighbours)
    if arr.ndim < 1 or arr.shape[-1] != size:
        raise ValueError(
            f"obs must have shape (..., {size}) for dim={dim}, neighbours={neighbours}; "
            f"got {arr.shape}"
        )
    lead = arr.shape[:-1]
    masks = (neighbours + 1) * dim
    return {
        "offset": arr[..., :dim],
        "neighbour_offsets": arr[..., dim:masks].reshape(*lead, neighbours, dim),
        "neighbour_mask": arr[..., masks:-1],
        "time_fraction": arr[..., -1],
    }
