"""The linearization cache: a `SwarmModel` that keeps L(x) of the last state it saw.

An env step needs the frozen linearization L(x) = (P(x) - diag(P(x) 1)) / N at the new state
twice: for the observation's interaction drift L(x^{n+1}) x^{n+1}, and at the start of the
next integrator step, where every scheme evaluates F(x, u) = L(x) x + u. `LinearizationCache`
keeps the last L(x), keyed by the identity of the state array, so the kernel matrix (or the
matrix-free operator of large swarms) is built once per step instead of twice.

It is also the model side of the exponential integrators' fused step
(`agent_envs.integrators.base.LinearizationCachingModel`): `fused_relinearization` hands the
integrator the workspace's P to write the next kernel pass into, `adopt_linearization` keeps
what it wrote as L(x^{n+1}) and `discard_linearization` forgets a P it wrote in part.

Users: the single envs' episode (`agent_envs.envs.episode.SwarmEpisode`), the native vector env
(numpy or torch, one model per block of envs) and the analytic-policy-gradient learner's torch
rollout (`agent_envs.training.learners.apg_rollout.ClosedLoop`).
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np

from agent_envs import arrays
from agent_envs.dynamics.laplacian import FrozenLaplacian, UpperTriangle
from agent_envs.dynamics.operators import LinearizationOperator
from agent_envs.dynamics.swarm import SwarmModel
from agent_envs.params import SwarmParams


class LinearizationCache(SwarmModel):
    """`SwarmModel` that remembers L(x) for the last state array it saw (by identity).

    On the numpy workspace path (`agent_envs.dynamics.laplacian`) it keeps the `FrozenLaplacian`
    and the drift, valid while the workspace still holds that P (`FrozenLaplacian.current`);
    on the Array-API path the matrix L(x) and the row sums P(x) 1; on the matrix-free path the
    `LinearizationOperator`. A numpy state is cached only when it is read-only (the envs mark
    theirs so and never write into them), and the cached arrays are made read-only too, so a
    stale or corrupted hit is impossible.

    torch tensors cannot be made read-only: they are cached only with `cache_tensors=True`,
    for an owner that builds a new state tensor every step and never writes into one (the
    native vector env on torch). Sharing one L(x) between two uses changes nothing forward,
    but the backward pass then sums the two uses' gradients before going through L(x) once
    instead of after, which moves gradients by round-off: a differentiated rollout that must
    reproduce earlier gradients bit for bit leaves it off.

    Args:
        params: the dynamics (`SwarmModel`).
        linear_operator: "auto" | "dense" | "matrix_free" (`SwarmModel`).
        cache_tensors: whether torch states are cached (above).
        fallbacks: the owning env's ``plan_fallbacks`` (`agent_envs.envs.step_plan`), where
            `discard_linearization` counts a fused step that gave up ("fused-gave-up"); a
            fresh counter by default.
        threads: numba's threads for the compiled passes (`SwarmModel.threads`).
    """

    def __init__(
        self,
        params: SwarmParams,
        linear_operator: str = "auto",
        *,
        cache_tensors: bool = False,
        fallbacks: Counter[str] | None = None,
        threads: int = 1,
    ) -> None:
        super().__init__(params, linear_operator)
        self.fallbacks: Counter[str] = Counter() if fallbacks is None else fallbacks
        self._cache_tensors = cache_tensors
        self._cached_state: Any = None
        self._cached_matrix: Any = None
        self.threads = threads

    def clear(self) -> None:
        """Forget the cached state and linearization (a torch owner drops its autograd graph)."""
        self._cached_state = self._cached_matrix = None

    def _frozen_with_row_sums(self, x: Any) -> tuple[Any, Any]:
        # the Array-API path: (L(x), P(x) 1), cached as a list to tell it from the workspace's
        cached = self._cached_matrix
        if x is self._cached_state and isinstance(cached, list):
            return cached[0], cached[1]
        matrix, row_sums = super()._frozen_with_row_sums(x)
        if isinstance(x, np.ndarray) and not x.flags.writeable:
            matrix.flags.writeable = False
            row_sums.flags.writeable = False
            self._cached_state, self._cached_matrix = x, [matrix, row_sums]
        elif self._cache_tensors and arrays.is_torch(x):
            self._cached_state, self._cached_matrix = x, [matrix, row_sums]
        return matrix, row_sums

    def _laplacian(self, x: np.ndarray) -> tuple[Any, np.ndarray]:
        # the workspace path (numpy, Cucker-Smale, dense): the operator over the model's P and
        # the drift, kept while P is still the workspace's (the next evaluation overwrites it)
        cached = self._cached_matrix
        if x is self._cached_state and isinstance(cached, tuple) and cached[0].current:
            return cached
        found = super()._laplacian(x)
        if not x.flags.writeable:
            found[1].flags.writeable = False
            self._cached_state, self._cached_matrix = x, found
        else:
            self._cached_state = self._cached_matrix = None
        return found

    def linearization_operator(self, x: np.ndarray, kind: str = "frozen") -> LinearizationOperator:
        # the matrix-free L(x) (large N), cached like the matrix (it holds no mutable state)
        cached = self._cached_matrix
        if x is self._cached_state and getattr(cached, "kind", None) == kind:
            return cached
        operator = super().linearization_operator(x, kind)
        if isinstance(x, np.ndarray) and not x.flags.writeable:
            self._cached_state, self._cached_matrix = x, operator
        return operator

    def cached_linearization(self, x: Any) -> tuple[FrozenLaplacian, np.ndarray] | None:
        """(L(x) over the workspace's P, the drift L(x) x) kept for the state array `x` (by
        identity) while the workspace still holds its P, else None (nothing is computed)."""
        cached = self._cached_matrix
        if x is self._cached_state and isinstance(cached, tuple) and cached[0].current:
            return cached
        return None

    def fused_relinearization(self, x: Any) -> tuple[np.ndarray, float, float] | None:
        """What an exponential integrator needs to take the kernel pass at its next state in
        its own compiled pass, member by member (`agent_envs.native.lanczos.
        frozen_advance`): (the workspace's P for x's shape, writable; w; alpha^2), or None
        where the compiled kernel pass does not serve x or x is not on the dense workspace path.
        The integrator then hands the result to `adopt_linearization`, or calls
        `discard_linearization` if it wrote part of P and gave up."""
        compiled = self.compiled_pass_parameters(x)
        if compiled is None or not self._uses_workspace(x):
            return None
        return (self._workspace.buffers(tuple(x.shape))[0], *compiled)

    def adopt_linearization(self, x_next: np.ndarray, row_sums: Any, drift: Any) -> None:
        """Keep L(x_next), whose P (its lower triangle: `UpperTriangle`) the integrator wrote
        into the workspace, with its row sums and drift L(x_next) x_next, as
        `_laplacian(x_next)` would have (x_next, the integrator's fresh array, and the drift
        are made read-only)."""
        ws = self._workspace
        ws.generation += 1
        shape = x_next.shape  # (a tuple: the workspace's key as is)
        p = ws.buffers(shape)[0]
        operator = self._workspace_operator(p, row_sums.reshape(shape[:-1]), UpperTriangle(p))
        drift = drift.reshape(shape)
        x_next.flags.writeable = False
        drift.flags.writeable = False
        self._cached_state, self._cached_matrix = x_next, (operator, drift)

    def discard_linearization(self) -> None:
        """The workspace's P no longer holds the kernel of any state (an integrator wrote part
        of it): the operators built on it stop being current, and nothing is cached. Counted
        in `fallbacks` as "fused-gave-up" (the only caller is the fused step giving up)."""
        self.fallbacks["fused-gave-up"] += 1
        self._workspace.generation += 1
        self.clear()
