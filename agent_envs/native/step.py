"""The native vector env's step around its fused compiled pass, compiled with numba (optional).

This module imports numba; the package imports it only through `agent_envs.native.loader`
(path "step"), so the package works without numba (the env's numpy step runs).

A step of the native vector env at B = 64 envs of one path (N = 100) spent about a third of its
time outside its compiled passes, in some thirty numpy calls over (B, P, N, d) arrays: the
controls from the actions, the running costs, the divergence checks, the means over the paths
and the observation. Here they are two compiled loops over the batch, `prologue` (before the
draws and the integrator's fused pass) and `epilogue` (after it), which compute the same
values as those numpy calls bit for bit, so the native env still equals `SyncVectorEnv` over
the single env (which keeps its numpy calls):

- element-wise operations are the same IEEE operations in the same order (x - xbar, its
  square, gamma * |u|^2 + ..., clip, max_control * a, float32 casts);
- a sum over a contiguous axis is numpy's pairwise summation (`_pairwise_sum`: below 8 terms
  one running sum from -0.0, up to 128 eight running sums combined as
  ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7)) and then the rest, beyond 128 the two
  halves at a multiple of 8), added to the reduction's identity 0.0, as numpy's `add.reduce`
  does (numpy/_core/src/umath/loops_utils.h.src); a mean divides that sum by the count;
- a mean over the paths (axis -3, not contiguous) is numpy's order for an outer axis: 0.0 +
  x_0 + x_1 + ... in sequence, divided by P; over one path x + 0.0 (`arrays.mean_axis`).

The PettingZoo env's per-agent costs and observation rows (`agent_costs`, `agent_rows`) come
in the same calls where it asks (`prologue_agents`, `epilogue_agents`: the same functions
called inside, checked against the separate calls by `compiled_agents.
combined_same_as_separate`).

`agent_envs.envs.fast_step.same_as_numpy` checks all of this against numpy's own calls when
the loader loads the module (another numpy could sum in another order) and leaves the compiled
step off, with a warning, where a value differs; tests/test_fast_step.py checks it on many
shapes and the native env against SyncVectorEnv.

`cache=True`: the machine code is written next to this file (or to numba's user-wide cache
directory when that is read-only) the first time and loaded from there in every later process.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def _pairwise_leaf(a: np.ndarray, start: int, n: int) -> float:
    """numpy's pairwise sum of a[start : start + n] for n <= 128 (one block)."""
    if n < 8:
        res = -0.0
        for i in range(n):
            res += a[start + i]
        return res
    r0 = a[start]
    r1 = a[start + 1]
    r2 = a[start + 2]
    r3 = a[start + 3]
    r4 = a[start + 4]
    r5 = a[start + 5]
    r6 = a[start + 6]
    r7 = a[start + 7]
    i = 8
    top = n - n % 8
    while i < top:
        r0 += a[start + i]
        r1 += a[start + i + 1]
        r2 += a[start + i + 2]
        r3 += a[start + i + 3]
        r4 += a[start + i + 4]
        r5 += a[start + i + 5]
        r6 += a[start + i + 6]
        r7 += a[start + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[start + i]
        i += 1
    return res


#: levels of the pairwise sum's stack: the halves shrink by 2 each level, so n < 2^64
STACK_DEPTH = 64


@njit(cache=True, error_model="numpy")
def pairwise_stack() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Scratch of `_pairwise_sum` for sums of more than 128 terms (allocated once per call of
    `prologue`, not once per sum)."""
    return (
        np.empty(STACK_DEPTH, dtype=np.int64),
        np.empty(STACK_DEPTH, dtype=np.int64),
        np.empty(STACK_DEPTH, dtype=np.int64),
        np.empty(STACK_DEPTH + 1),
    )


@njit(cache=True, error_model="numpy")
def _pairwise_sum(a: np.ndarray, start: int, n: int, stack: tuple) -> float:
    """numpy's pairwise sum of a[start : start + n] (a 1-d float64 array), without the
    reduction's identity (the caller adds 0.0): blocks of at most 128 (`_pairwise_leaf`), above
    that the sum of the two halves split at a multiple of 8. numpy recurses; this walks the
    same tree with an explicit stack (`pairwise_stack`; numba's cache could not reload a
    recursive function here: the second process crashed), left half first, so every addition
    is numpy's."""
    if n <= 128:
        return _pairwise_leaf(a, start, n)
    starts, sizes, stage, values = stack
    stage[0] = 0
    top = 0
    count = 0
    starts[0] = start
    sizes[0] = n
    while top >= 0:
        m = sizes[top]
        if m <= 128:
            values[count] = _pairwise_leaf(a, starts[top], m)
            count += 1
            top -= 1
            continue
        half = m // 2
        half -= half % 8
        if stage[top] == 0:  # the left half first
            stage[top] = 1
            starts[top + 1] = starts[top]
            sizes[top + 1] = half
            stage[top + 1] = 0
            top += 1
        elif stage[top] == 1:  # then the right half
            stage[top] = 2
            starts[top + 1] = starts[top] + half
            sizes[top + 1] = m - half
            stage[top + 1] = 0
            top += 1
        else:  # both done: left + right
            values[count - 2] = values[count - 2] + values[count - 1]
            count -= 1
            top -= 1
    return values[0]


@njit(cache=True, error_model="numpy")
def sum_like_numpy(a: np.ndarray) -> float:
    """np.sum(a) of a 1-d float64 array, bit for bit (identity 0.0 + the pairwise sum)."""
    return 0.0 + _pairwise_sum(a, 0, a.shape[0], pairwise_stack())


@njit(cache=True, error_model="numpy", inline="always")
def _agent_cost(xb, at_x, u, at_u, target, d, gamma, terms, stack) -> float:
    """|x_k - xbar|^2 + gamma |u_k|^2 of one agent (x_k at xb[at_x:], u_k at u[at_u:]), each
    squared norm with numpy's sum over the d coordinates: fewer than 8 terms one running sum
    (numpy's unrolled loop, written out), else the pairwise sum (`_pairwise_sum`)."""
    if d < 8:
        position = -0.0
        control = -0.0
        for c in range(d):
            diff = xb[at_x + c] - target[c]
            position += diff * diff
            control += u[at_u + c] * u[at_u + c]
        return (0.0 + position) + gamma * (0.0 + control)
    for c in range(d):
        diff = xb[at_x + c] - target[c]
        terms[c] = diff * diff
    position = 0.0 + _pairwise_sum(terms, 0, d, stack)
    for c in range(d):
        terms[c] = u[at_u + c] * u[at_u + c]
    return position + gamma * (0.0 + _pairwise_sum(terms, 0, d, stack))


@njit(cache=True, error_model="numpy")
def prologue(
    actions: np.ndarray,
    max_control: float,
    x: np.ndarray,
    drift: np.ndarray,
    targets: np.ndarray,
    gamma: float,
    controls: np.ndarray,
    costs: np.ndarray,
    rhs: np.ndarray,
) -> bool:
    """For every env b: u = max_control * clip(a, -1, 1) into `controls` (B, N, d), from the
    actions (B, N, d) ("agents" basis) or (B, 1, d) ("common" basis: the one row for every
    agent) (float32 or float64, each entry taken as float64); the running cost
    c(x^n, u^n) of `eq:running_cost`, mean over the paths, into `costs` (B,); and the
    integrator's right-hand side F = L(x) x + u of every path into `rhs` (B, P, N, d), from the
    drift L(x) x (B, P, N, d). Returns False, with nothing written, when some action is not
    finite (the env's numpy step then raises its ValueError).

    The cost is `agent_envs.envs.episode.mean_running_cost`'s: per agent sum_c (x - xbar)_c^2
    + gamma sum_c u_c^2 (sums over the coordinates), the mean over the agents, then over the
    paths, with numpy's sums (module docstring). Every array C-contiguous; each env's rows
    are taken flat."""
    b_count, p_count, n, d = x.shape
    size = n * d
    given = actions.shape[1] * d  # N d, or d for the "common" basis
    acts = actions.reshape(b_count, given)
    for b in range(b_count):
        row = acts[b]
        finite = True
        for i in range(given):
            finite &= np.isfinite(row[i])
        if not finite:
            return False
    us = controls.reshape(b_count, size)
    xs = x.reshape(b_count, p_count * size)
    fs = drift.reshape(b_count, p_count * size)
    out = rhs.reshape(b_count, p_count * size)
    per_agent = np.empty(n)
    per_path = np.empty(p_count)
    terms = np.empty(d)
    stack = pairwise_stack()
    for b in range(b_count):
        row = acts[b]
        u = us[b]
        for i in range(given):
            a = np.float64(row[i])  # (finite: np.clip(a, -1, 1)'s value)
            if not a > -1.0:
                a = -1.0
            if not a < 1.0:
                a = 1.0
            u[i] = max_control * a
        for i in range(given, size):  # "common": the row repeated for every agent
            u[i] = u[i % d]
        xb = xs[b]
        target = targets[b]
        for j in range(p_count):
            base = j * size
            for k in range(n):
                per_agent[k] = _agent_cost(
                    xb, base + k * d, u, k * d, target, d, gamma, terms, stack
                )
            per_path[j] = (0.0 + _pairwise_sum(per_agent, 0, n, stack)) / n
        if p_count == 1:
            costs[b] = per_path[0] + 0.0
        else:
            costs[b] = (0.0 + _pairwise_sum(per_path, 0, p_count, stack)) / p_count
        fb = fs[b]
        ob = out[b]
        for j in range(p_count):
            base = j * size
            for i in range(size):
                ob[base + i] = fb[base + i] + u[i]
    return True


@njit(cache=True, error_model="numpy")
def _path_mean(a: np.ndarray, p_count: int, size: int, out: np.ndarray) -> None:
    """The mean over the paths of a (P * size,) (one env's (P, N, d), flat) into out (size,),
    in numpy's order."""
    if p_count == 1:
        for i in range(size):
            out[i] = a[i] + 0.0
        return
    for i in range(size):
        out[i] = 0.0
    for j in range(p_count):
        start = j * size
        for i in range(size):
            out[i] += a[start + i]
    for i in range(size):
        out[i] = out[i] / p_count


@njit(cache=True, error_model="numpy")
def epilogue(
    x_next: np.ndarray,
    drift_next: np.ndarray,
    threshold: float,
    targets: np.ndarray,
    time_fractions: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    absolute: bool,
    mean_positions: np.ndarray,
    mean_drift: np.ndarray,
    observations: np.ndarray,
    diverged: np.ndarray,
) -> None:
    """After the integrator's step, for every env b: `diverged[b]` as
    `agent_envs.envs.episode.advance_paths` flags it (some path's |x| above `threshold` or not
    finite, or the mean drift not finite); the means over the paths of x_next and of the drift
    L(x_next) x_next (B, P, N, d) into `mean_positions` and `mean_drift` (B, N, d); and, with
    `absolute` (the "absolute" observation layout), the observation (B, 2 N d + d + 1) float32
    of `agent_envs.envs.observation.global_observation`: the two means, the target and t/T
    (`time_fractions`, (B,)), each cast to float32 and clipped to [low, high] by numpy's
    rule for floats (max(v, low) then min(., high), NaN kept, a tie taking the bound). Every
    array
    C-contiguous; each env's rows are taken flat."""
    b_count, p_count, n, d = x_next.shape
    size = n * d
    xs = x_next.reshape(b_count, p_count * size)
    fs = drift_next.reshape(b_count, p_count * size)
    means_x = mean_positions.reshape(b_count, size)
    means_f = mean_drift.reshape(b_count, size)
    bounded = np.isfinite(threshold)
    for b in range(b_count):
        row = xs[b]
        inside = True
        if bounded:
            for i in range(p_count * size):
                inside &= abs(row[i]) <= threshold
        else:
            for i in range(p_count * size):
                inside &= np.isfinite(row[i])
        mx = means_x[b]
        mf = means_f[b]
        _path_mean(row, p_count, size, mx)
        _path_mean(fs[b], p_count, size, mf)
        for i in range(size):
            inside &= np.isfinite(mf[i])
        diverged[b] = not inside
        if absolute:
            obs = observations[b]
            for i in range(size):
                obs[i] = np.float32(mx[i])
                obs[size + i] = np.float32(mf[i])
            for c in range(d):
                obs[2 * size + c] = np.float32(targets[b, c])
            obs[2 * size + d] = np.float32(time_fractions[b])
            for i in range(obs.shape[0]):  # np.clip's rule, signed zeros and NaN included
                v = obs[i]
                if not (v > low[i] or v != v):
                    v = low[i]
                if not (v < high[i] or v != v):
                    v = high[i]
                obs[i] = v


@njit(cache=True, error_model="numpy")
def agent_costs(
    x: np.ndarray, controls: np.ndarray, targets: np.ndarray, gamma: float, out: np.ndarray
) -> None:
    """For every env b, agent k: |x_k - xbar|^2 + gamma |u_k|^2 mean over the paths into
    `out` (B, N), from x (B, P, N, d), the controls (B, N, d) and targets (B, d): the
    PettingZoo env's per-agent costs (`SwarmEpisode.agent_costs`: `costs.agent_running_cost`
    then the mean over the paths), with numpy's sums (module docstring; the mean over the
    paths as a division of the sum by P, one path included). Every array C-contiguous."""
    b_count, p_count, n, d = x.shape
    size = n * d
    xs = x.reshape(b_count, p_count * size)
    us = controls.reshape(b_count, size)
    terms = np.empty(d)
    stack = pairwise_stack()
    for b in range(b_count):
        xb = xs[b]
        u = us[b]
        target = targets[b]
        row = out[b]
        for k in range(n):
            row[k] = 0.0
        for j in range(p_count):
            base = j * size
            for k in range(n):
                row[k] += _agent_cost(xb, base + k * d, u, k * d, target, d, gamma, terms, stack)
        for k in range(n):
            row[k] = row[k] / p_count


@njit(cache=True, error_model="numpy")
def agent_rows(
    mean_positions: np.ndarray,
    mean_drift: np.ndarray,
    targets: np.ndarray,
    time_fractions: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    relative: bool,
    observations: np.ndarray,
) -> None:
    """For every env b, agent k: the PettingZoo observation row [E x_k (or E x_k - xbar with
    `relative`) | E drift_k | xbar | t/T] (3 d + 1) float32 into `observations` (B, N, 3 d + 1)
    from the path means (B, N, d), targets (B, d) and t/T (B,), as
    `agent_envs.envs.observation.agent_observations` ("absolute" or "relative" layout): the
    offsets in float64, each entry cast to float32, clipped to [low, high] (3 d + 1,) by
    `epilogue`'s rule (np.clip's). Every array C-contiguous."""
    b_count, n, d = mean_positions.shape
    width = 3 * d + 1
    for b in range(b_count):
        target = targets[b]
        fraction = np.float32(time_fractions[b])
        for k in range(n):
            obs = observations[b, k]
            for c in range(d):
                position = mean_positions[b, k, c]
                if relative:
                    position = position - target[c]
                obs[c] = np.float32(position)
                obs[d + c] = np.float32(mean_drift[b, k, c])
                obs[2 * d + c] = np.float32(target[c])
            obs[3 * d] = fraction
            for i in range(width):
                v = obs[i]
                if not (v > low[i] or v != v):
                    v = low[i]
                if not (v < high[i] or v != v):
                    v = high[i]
                obs[i] = v


@njit(cache=True, error_model="numpy")
def prologue_agents(
    actions: np.ndarray,
    max_control: float,
    x: np.ndarray,
    drift: np.ndarray,
    targets: np.ndarray,
    gamma: float,
    controls: np.ndarray,
    costs: np.ndarray,
    rhs: np.ndarray,
    per_agent: np.ndarray,
) -> bool:
    """`prologue` and then, where it wrote, `agent_costs` of x and its controls into
    `per_agent` (B, N): the PettingZoo env's compiled step in one call instead of two (the
    same two functions, so the same bits)."""
    if not prologue(actions, max_control, x, drift, targets, gamma, controls, costs, rhs):
        return False
    agent_costs(x, controls, targets, gamma, per_agent)
    return True


@njit(cache=True, error_model="numpy")
def epilogue_agents(
    x_next: np.ndarray,
    drift_next: np.ndarray,
    threshold: float,
    targets: np.ndarray,
    time_fractions: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    absolute: bool,
    mean_positions: np.ndarray,
    mean_drift: np.ndarray,
    observations: np.ndarray,
    diverged: np.ndarray,
    agent_low: np.ndarray,
    agent_high: np.ndarray,
    relative: bool,
    rows: np.ndarray,
) -> None:
    """`epilogue` and then `agent_rows` of its path means at the same t/T into `rows`
    (B, N, 3 d + 1) float32, clipped to [agent_low, agent_high]: the PettingZoo env's compiled
    step in one call instead of two (the same two functions, so the same bits; the rows of a
    diverged env are not used)."""
    epilogue(
        x_next, drift_next, threshold, targets, time_fractions, low, high, absolute,
        mean_positions, mean_drift, observations, diverged,
    )  # fmt: skip
    agent_rows(
        mean_positions, mean_drift, targets, time_fractions, agent_low, agent_high, relative, rows
    )
