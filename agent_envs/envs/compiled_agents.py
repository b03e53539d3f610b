"""The PettingZoo env's per-agent outputs in compiled calls (`agent_envs.native.step`, the
compiled path "step"), and their reference check.

After a compiled step (`agent_envs.envs.compiled_episode`), the PettingZoo env needs per agent
k the running cost |x_k^n - xbar|^2 + gamma |u_k^n|^2 (mean over the paths: its reward and
info) and the observation row [E x_k | E drift_k | xbar | t/T] (3 d + 1,) float32 of the
"absolute" or "relative" layout. `compiled_agent_costs` and `compiled_agent_rows` compute them
in one compiled call each (`module.agent_costs`, `module.agent_rows`), as a batch of B envs,
instead of about fifteen numpy calls; `agents_same_as_numpy`, part of the path's load check
(`fast_step.same_as_numpy`), checks both against those numpy calls (`costs.
agent_running_cost` and the mean over the paths; `observation.agent_observations`) bit for
bit on fixed random data, so where a value differs the whole path "step" stays off.

The PettingZoo env's compiled step takes both in its prologue's and epilogue's calls
(`module.prologue_agents`, `module.epilogue_agents`: `AgentOutputs` asks for them);
`combined_same_as_separate`, part of the same check, checks those against the separate calls.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from agent_envs.costs import agent_running_cost
from agent_envs.envs.observation import agent_observation_space, agent_observations

#: (B, P, N, d) of the check: one and several paths, N below, at and above numpy's pairwise
#: blocks, d = 1, 2 and 9 (a pairwise sum over the coordinates)
AGENT_CHECK_SHAPES = ((1, 1, 100, 1), (1, 20, 100, 1), (2, 3, 5, 2), (1, 2, 130, 3),
                      (1, 1, 300, 2), (1, 9, 17, 9), (1, 1, 2, 1))  # fmt: skip


class AgentOutputs(NamedTuple):
    """What the PettingZoo env asks of the compiled episode step besides the single env's:
    the per-agent costs (always) and the observation rows where `bounds`, the agent space's
    (low, high) (3 d + 1,) float32, are given (the "absolute" or `relative` layout; None for
    "swarm", whose rows numpy builds)."""

    bounds: tuple[np.ndarray, np.ndarray] | None
    relative: bool


def compiled_agent_costs(
    module: Any, x: np.ndarray, controls: np.ndarray, targets: np.ndarray, gamma: float
) -> np.ndarray:
    """`module.agent_costs`: for x (B, P, N, d), controls (B, N, d), targets (B, d) (float64,
    C-contiguous): the per-agent running costs, mean over the paths, (B, N)."""
    out = np.empty(x.shape[:1] + x.shape[2:3])
    module.agent_costs(x, controls, targets, gamma, out)
    return out


def compiled_agent_rows(
    module: Any,
    mean_positions: np.ndarray,
    mean_drift: np.ndarray,
    targets: np.ndarray,
    time_fractions: np.ndarray,
    bounds: tuple[np.ndarray, np.ndarray],
    relative: bool,
) -> np.ndarray:
    """`module.agent_rows`: the observation rows (B, N, 3 d + 1) float32 of the "absolute"
    (or `relative`) layout from the path means (B, N, d), targets (B, d), t/T (B,) and the
    agent space's (low, high) (3 d + 1,) float32."""
    b, n, d = mean_positions.shape
    out = np.empty((b, n, 3 * d + 1), dtype=np.float32)
    module.agent_rows(mean_positions, mean_drift, targets, time_fractions, *bounds, relative, out)
    return out


def _same_bits(a: np.ndarray, b: Any) -> bool:
    b = np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def agents_same_as_numpy(
    module: Any, shapes: tuple[tuple[int, int, int, int], ...] = AGENT_CHECK_SHAPES
) -> bool:
    """Whether `module.agent_costs` and `module.agent_rows` give the numpy calls' values bit
    for bit on fixed random data of `shapes` (B, P, N, d): states over six orders of
    magnitude, controls with signed zeros, path means beyond the bounds (the clip cuts), both
    layouts, env by env against `agent_running_cost(...).mean(axis=0)` and
    `agent_observations`."""
    rng = np.random.default_rng(20261128)
    for b, p, n, d in shapes:
        x = rng.standard_normal((b, p, n, d)) * 10.0 ** rng.uniform(-3, 3, (b, p, n, d))
        x.flags.writeable = False  # (read-only, as the env passes its state)
        controls = rng.uniform(-25.0, 25.0, (b, n, d))
        controls.flat[:2] = (-0.0, 0.0)
        targets = rng.standard_normal((b, d))
        means = rng.standard_normal((2, b, n, d)) * 10.0 ** rng.uniform(-3, 7, (2, b, n, d))
        fractions = rng.uniform(0.0, 1.0, b)
        fractions[0] = -0.0  # (a tie with the bound 0.0: np.clip gives +0.0)
        costs = compiled_agent_costs(module, x, controls, targets, 0.37)
        for layout in ("absolute", "relative"):
            space = agent_observation_space(d, 1e6, 1e5, layout)
            rows = compiled_agent_rows(
                module, means[0], means[1], targets, fractions, (space.low, space.high),
                layout == "relative",
            )  # fmt: skip
            for e in range(b):
                want = agent_observations(
                    means[0, e], means[1, e], targets[e], float(fractions[e]), space, layout
                )
                if not _same_bits(rows[e], want):
                    return False
        for e in range(b):
            want = agent_running_cost(x[e], controls[e], targets[e], 0.37).mean(axis=0)
            if not _same_bits(costs[e], want):
                return False
    return True


def combined_same_as_separate(module: Any) -> bool:
    """Whether `module.prologue_agents` and `module.epilogue_agents` give what
    `module.prologue` + `module.agent_costs` and `module.epilogue` + `module.agent_rows` give
    (each checked against numpy), bit for bit, on fixed random data of `AGENT_CHECK_SHAPES`
    (float32 and float64 actions; states, drifts and means beyond the bounds)."""
    rng = np.random.default_rng(20261129)
    for b, p, n, d in AGENT_CHECK_SHAPES:
        x = rng.standard_normal((b, p, n, d)) * 10.0 ** rng.uniform(-3, 6, (b, p, n, d))
        drift = rng.standard_normal((b, p, n, d)) * 10.0 ** rng.uniform(-3, 6, (b, p, n, d))
        x.flags.writeable = drift.flags.writeable = False  # (read-only, as the env's)
        targets = rng.standard_normal((b, d))
        fractions = rng.uniform(0.0, 1.0, b)
        for dtype, relative in ((np.float32, False), (np.float64, True)):
            actions = rng.uniform(-2.0, 2.0, (b, n, d)).astype(dtype)
            outs = [(np.empty((b, n, d)), np.empty(b), np.empty(x.shape), np.empty((b, n)))
                    for _ in range(2)]  # fmt: skip
            module.prologue(actions, 25.0, x, drift, targets, 0.37, *outs[0][:3])
            module.agent_costs(x, outs[0][0], targets, 0.37, outs[0][3])
            module.prologue_agents(actions, 25.0, x, drift, targets, 0.37, *outs[1])
            space = agent_observation_space(d, 1e6, 1e5, "relative" if relative else "absolute")
            low, high = (
                np.full(2 * n * d + d + 1, -1e6, np.float32),
                np.full(2 * n * d + d + 1, 1e6, np.float32),
            )
            ends = [(np.empty((b, n, d)), np.empty((b, n, d)),
                     np.empty((b, low.shape[0]), np.float32), np.empty(b, np.bool_),
                     np.empty((b, n, 3 * d + 1), np.float32)) for _ in range(2)]  # fmt: skip
            common = (x, drift, 1e6, targets, fractions, low, high, True)
            module.epilogue(*common, *ends[0][:4])
            module.agent_rows(ends[0][0], ends[0][1], targets, fractions, space.low,
                              space.high, relative, ends[0][4])  # fmt: skip
            module.epilogue_agents(*common, *ends[1][:4], space.low, space.high, relative,
                                   ends[1][4])  # fmt: skip
            for one, two in zip((*outs[0], *ends[0]), (*outs[1], *ends[1]), strict=True):
                if not _same_bits(one, two):
                    return False
    return True
