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
A model that keeps its linearization for the next step may also offer
`fused_relinearization(x)`, `adopt_linearization(x_next, row_sums, drift)` and
`discard_linearization()` (the envs' model, `agent_envs.envs.episode`): the exponential
schemes then take the next kernel pass in the same compiled call as the step
(`agent_envs.integrators.exponential`), with the same result.
States are numpy arrays or torch tensors (`agent_envs.arrays`); the schemes only use
operators and the model, so they run (and differentiate, on torch) on either.
"""

from __future__ import annotations

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
