"""The integrator interface shared by every time-stepping scheme.

An integrator is a small stateless object with

    step(model, x, u, t, dt, dW, du_dt=None) -> x_next

and class attributes `name`, `strong_order` (strong order for additive noise; the deterministic
order when sigma = 0 is `deterministic_order`) and `needs_jacobian`. Integrators never draw random
numbers: the Brownian increments `dW` (same shape as `x`, variance `dt`) come in from outside,
so every scheme can be compared on the same noise.

`model` is anything with `drift(t, x, u)`, `sigma` and, for exponential schemes,
`drift_and_linearization(t, x, u, kind)` (see `agent_envs.dynamics.swarm.SwarmModel`); a
closed-loop model whose drift includes a time-dependent feedback law fits the same protocol.
A model that keeps its linearization for the next step follows `LinearizationCachingModel`
(`agent_envs.dynamics.linearization_cache.LinearizationCache`, the envs' model): the
exponential schemes then take the next kernel pass in the same compiled call as the step
(`agent_envs.integrators.exponential`), with the same result.
States are numpy arrays or torch tensors (`agent_envs.arrays`); the schemes only use
operators and the model, so they run (and differentiate, on torch) on either.
"""

from __future__ import annotations

from collections import Counter
from typing import Any, ClassVar, Protocol

import numpy as np


class DriftModel(Protocol):
    """What an integrator needs from the dynamics."""

    sigma: float

    def drift(self, t: float, x: Any, u: Any = None) -> Any:
        """F(t, x, u), the state shape (..., N, d)."""
        ...

    def drift_and_linearization(self, t: float, x: Any, u: Any, kind: str):
        """(F(t, x, u), Linearization) for exponential schemes; kind "exact" or "frozen"."""
        ...


class LinearizationCachingModel(DriftModel, Protocol):
    """A `DriftModel` that keeps L(x) of its last state for the next step, and takes the next
    kernel pass from the exponential integrators' fused step (`RosenbrockEuler.fused_step`).

    The fused step asks `fused_relinearization(x)` for the workspace it may write P(x_next)
    into, then hands what it computed to `adopt_linearization` or, where a member's Lanczos
    gave up after writing part of P, calls `discard_linearization`. The integrators look the
    hooks up on the model (a plain `SwarmModel` has none: the general step runs); the one
    implementation is `agent_envs.dynamics.linearization_cache.LinearizationCache`.
    """

    #: the mid-step fallbacks by kind (`agent_envs.envs.step_plan.FALLBACKS`): the step counts
    #: "fused-declined" here, `discard_linearization` "fused-gave-up"
    fallbacks: Counter[str]
    #: numba's threads for the compiled passes over the batch's members
    threads: int

    def cached_linearization(self, x: Any) -> tuple[Any, Any] | None:
        """(L(x), L(x) x) kept for the state array x (by identity), or None."""
        ...

    def fused_relinearization(self, x: Any) -> tuple[np.ndarray, float, float] | None:
        """(the workspace's P for x's shape, w, alpha^2) for the compiled kernel pass at the
        step's next state, or None where the fused step does not serve x."""
        ...

    def adopt_linearization(self, x_next: np.ndarray, row_sums: Any, drift: Any) -> None:
        """Keep L(x_next), whose P the integrator wrote, with its row sums and drift."""
        ...

    def discard_linearization(self) -> None:
        """Forget the linearization: the workspace's P was written in part."""
        ...


class Integrator:
    """Base class: holds the metadata; subclasses implement `step`."""

    name: ClassVar[str]
    strong_order: ClassVar[float]
    deterministic_order: ClassVar[float]
    needs_jacobian: ClassVar[bool] = False

    def step(
        self,
        model: DriftModel,
        x: np.ndarray,
        u: np.ndarray | None,
        t: float,
        dt: float,
        dW: np.ndarray,
        du_dt: np.ndarray | None = None,
    ) -> np.ndarray:
        """Advance the state x (..., N, d) from t to t + dt with control u and increments dW."""
        raise NotImplementedError

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"
