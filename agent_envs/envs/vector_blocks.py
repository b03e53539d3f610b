"""The native vector env's numpy passes over its batch, one block of envs at a time.

The state of B envs is one (B, P, N, d) array. Where a pass over it is numpy's (no numba, or a
kernel or Jacobian numba does not serve), the envs are stepped in balanced blocks of at most
`BLOCK_BYTES` of kernel matrices (`StepPlan.blocks`, `StepPlan.envs_per_block`), each block with
its own `LinearizationCache`, so that a block's P(x) (B_block x P x N x N floats) stays in the
cache while the Krylov iteration multiplies with it. Every env's arithmetic is the same as in
one call over the batch (the core works member by member), so the blocks change no bit.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np

from agent_envs.dynamics.linearization_cache import LinearizationCache
from agent_envs.envs.episode import advance_paths, mean_interaction_drift
from agent_envs.envs.episode_config import EpisodeConfig
from agent_envs.integrators import Integrator

#: Bytes of kernel matrices one block of envs holds at most (numpy passes over the whole batch:
#: without numba, or a kernel or Jacobian numba does not serve): the envs are stepped in
#: balanced blocks of at most this size, so that a block's P(x) (B_block x P x N x N floats)
#: stays in the cache while the Krylov iteration multiplies with it, instead of streaming the
#: whole batch's P from memory at every product (N = 100, 20 paths, B = 16: 25.6 MB per product
#: in one batch). 8 MiB measured best of 1, 2, 4, 8 MiB and one batch on a 32 MiB L3
#: (benchmarks/bench_vector_batching.py prints the vector env's figures). Where every pass runs
#: member by member (`step_plan.member_by_member`), one block (`StepPlan.blocks`).
BLOCK_BYTES = 2**23


class EnvBlocks:
    """The blocks of a native vector env's batch and their models.

    Attributes:
        slices: the envs of each block, `slice`s of the batch axis (balanced: the blocks differ
            by at most one env).
        models: one `LinearizationCache` per block; the first is the env's own model, the
            others share its fallbacks counter and threads.

    The block models key their cached L(x) by the identity of the block's view of the state,
    so the views of the current state are kept (`views_of`) and handed out again.
    """

    def __init__(
        self,
        model: LinearizationCache,
        config: EpisodeConfig,
        num_envs: int,
        envs_per_block: int,
        fallbacks: Counter[str],
    ) -> None:
        self.slices = [
            slice(i, min(i + envs_per_block, num_envs)) for i in range(0, num_envs, envs_per_block)
        ]
        # (their threaded passes load in the env's first reset)
        self.models = [model] + [
            LinearizationCache(
                config.params, config.linear_operator, fallbacks=fallbacks, threads=model.threads
            )
            for _ in self.slices[1:]
        ]
        # the block views of the current state the block models last saw (their cache keys)
        self._views: list[Any] = []
        self._views_of: Any = None

    def __len__(self) -> int:
        return len(self.slices)

    def views_of(self, positions: Any) -> list[Any]:
        """The block views of `positions`: the ones the block models cached, if current."""
        if self._views_of is positions:
            return self._views
        return [positions[block] for block in self.slices]

    def mean_drift(self, positions: Any) -> Any:
        """E interaction drift (B, N, d) of `positions` (B, P, N, d), block by block
        (`episode.mean_interaction_drift`); the block models keep L(x) of their views for the
        next step."""
        if len(self.slices) == 1:
            return mean_interaction_drift(self.models[0], positions)
        positions.flags.writeable = False
        views = self.views_of(positions)
        drifts = [mean_interaction_drift(m, v) for m, v in zip(self.models, views, strict=True)]
        self._views, self._views_of = views, positions
        return np.concatenate(drifts)

    def advance(
        self,
        integrator: Integrator,
        x: Any,
        controls: Any,
        times: Any,
        dt: float,
        dw: Any,
        threshold: float,
    ) -> tuple[Any, Any, Any]:
        """`episode.advance_paths` of the whole batch x (B, P, N, d) with controls (B, N, d),
        times (B, 1, 1, 1) and increments dw (B, P, N, d), one block of envs at a time:
        (x^{n+1}, E drift (B, N, d), diverged (B,))."""
        if len(self.slices) == 1:
            return advance_paths(integrator, self.models[0], x, controls, times, dt, dw, threshold)
        parts = [
            advance_paths(
                integrator, model, view, controls[block], times[block], dt, dw[block], threshold
            )
            for model, view, block in zip(self.models, self.views_of(x), self.slices, strict=True)
        ]
        x_next = np.concatenate([part[0] for part in parts])
        x_next.flags.writeable = False
        self._views, self._views_of = [part[0] for part in parts], x_next
        drift = np.concatenate([part[1] for part in parts])
        diverged = np.concatenate([part[2] for part in parts])
        return x_next, drift, diverged
