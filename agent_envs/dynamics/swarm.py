"""The swarm's drift F(t, x, u), its exact Jacobian J(x) and its frozen-kernel linearization L(x).

State arrays have shape (..., N, d): any leading batch axes (Brownian paths, envs), then the
N agents, then the d coordinates. With P[k, l] = p(x_k, x_l) and s_k = sum_l P[k, l], the
drift of `eq:dynamics` / `eq:dyn_matrix` is

    F_k(x, u) = (1/N) sum_l p(x_k, x_l) (x_l - x_k) + u_k  =  (L(x) x)_k + u_k,

with the frozen-kernel linearization L(x) = (P(x) - diag(s(x))) / N, an (N, N) matrix that acts
on every coordinate alike (as an Nd x Nd matrix it is L ⊗ I_d). L(x) is minus a weighted graph
Laplacian: its eigenvalues have non-positive real part for every x.

The exact Jacobian dF/dx (`eq:jac`, entries below `eq:exp_int_discr`, generalized to d >= 1)
is an (Nd, Nd) matrix made of d x d blocks, with r_kl = x_l - x_k:

    J_kl = (1/N) (r_kl ⊗ dp/dy(x_k, x_l) + p(x_k, x_l) I_d)            (l != k)
    J_kk = (1/N) sum_{l != k} (r_kl ⊗ dp/dx(x_k, x_l) - p(x_k, x_l) I_d)

For the Cucker-Smale kernel, ``r ⊗ dp/dy = -2 w r r^T / D^2``, so J_kl = 0 in d = 1 exactly
when |x_k - x_l| = alpha and it turns negative for agents farther apart than alpha: the exact
Jacobian is then indefinite (positive eigenvalues), unlike L(x).

The swarm's drift does not depend on t; the argument is there so that every drift model (a
closed loop with a time-dependent feedback law, for instance) has the same signature
`drift(t, x, u)`. Every method takes numpy arrays or torch tensors (see `agent_envs.arrays`)
and answers in the same library; on torch it is differentiable.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from agent_envs import arrays
from agent_envs.dynamics.kernels import CuckerSmaleKernel, InteractionKernel
from agent_envs.params import SwarmParams


def kernel_from_params(params: SwarmParams) -> InteractionKernel:
    """The kernel object named by `params.kernel` (a user kernel is returned as is)."""
    if params.kernel == "symmetric":
        return CuckerSmaleKernel.symmetric_kernel(params.alpha, params.epsilon)
    if params.kernel == "nonsymmetric":
        return CuckerSmaleKernel.nonsymmetric_kernel(
            params.alpha, params.epsilon_min, params.epsilon_max, params.n_agents
        )
    return params.kernel


@dataclass(frozen=True)
class Linearization:
    """A matrix A used by the exponential integrators, with how it acts on a state.

    `per_coordinate=True`: A has shape (..., N, N) and acts on a state (..., N, d) column by
    column (the frozen L(x)). `per_coordinate=False`: A has shape (..., Nd, Nd) and acts on the
    flattened state (..., Nd) (the exact Jacobian).
    """

    matrix: Any
    per_coordinate: bool
    symmetric: bool

    def as_columns(self, v: Any) -> Any:
        """The state-shaped v (..., N, d) as the block of vectors A acts on."""
        if self.per_coordinate:
            return v
        xp = arrays.namespace(v)
        return xp.reshape(v, (*v.shape[:-2], v.shape[-2] * v.shape[-1], 1))

    def from_columns(self, w: Any, like: Any) -> Any:
        """Inverse of `as_columns`: back to the state shape of `like`."""
        if self.per_coordinate and tuple(w.shape) == tuple(like.shape):
            return w
        xp = arrays.namespace(w)
        return xp.reshape(w, tuple(like.shape))

    def apply(self, v: Any) -> Any:
        """A v for a state-shaped v (..., N, d)."""
        return self.from_columns(self.matrix @ self.as_columns(v), v)


class SwarmModel:
    """Drift, Jacobian and frozen linearization of the swarm SDE for given `SwarmParams`.

    The integrators see only `drift`, `drift_and_linearization` and `sigma` (the `DriftModel`
    protocol of `agent_envs.integrators.base`); the controllers and envs use
    `interaction_drift` and `interaction_matrix`. Every method is batched over leading axes.
    The model holds only the dynamics (kernel, noise, N, d): the target and gamma are cost
    parameters and do not enter it.
    """

    def __init__(self, params: SwarmParams) -> None:
        self.params = params
        self.kernel: InteractionKernel = kernel_from_params(params)
        self.n_agents = params.n_agents
        self.dim = params.dim
        self.sigma = params.sigma

    def _check_state(self, x: Any) -> Any:
        if not arrays.is_torch(x):
            x = np.asarray(x, dtype=float)
        if x.ndim < 2 or tuple(x.shape[-2:]) != (self.n_agents, self.dim):
            raise ValueError(
                f"state must have shape (..., {self.n_agents}, {self.dim}), got {tuple(x.shape)}"
            )
        return x

    def interaction_matrix(self, x: Any) -> Any:
        """P(x) with P[..., k, l] = p(x_k, x_l); shape (..., N, N)."""
        x = self._check_state(x)
        return self.kernel.value(x[..., :, None, :], x[..., None, :, :])

    def frozen_linearization(self, x: Any) -> Any:
        """L(x) = (P(x) - diag(P(x) 1)) / N; shape (..., N, N)."""
        p = self.interaction_matrix(x)
        xp = arrays.namespace(p)
        p = arrays.subtract_diagonal(p, xp.sum(p, axis=-1))
        return arrays.divide_fresh(p, self.n_agents)

    def interaction_drift(self, x: Any) -> Any:
        """(1/N) sum_l p(x_k, x_l)(x_l - x_k) = L(x) x; shape (..., N, d)."""
        x = self._check_state(x)
        return self.frozen_linearization(x) @ x

    def drift(self, t: float, x: Any, u: Any = None) -> Any:
        """F(t, x, u) = L(x) x + u of `eq:dyn_matrix`; x and u broadcast to (..., N, d)."""
        f = self.interaction_drift(x)
        return f if u is None else f + u

    def jacobian(self, x: Any) -> Any:
        """The exact Jacobian dF/dx (see the module docstring); shape (..., Nd, Nd).

        Rows and columns are ordered agent-major: index k*d + i is coordinate i of agent k.
        """
        x = self._check_state(x)
        xp = arrays.namespace(x)
        n, d = self.n_agents, self.dim
        xk, xl = x[..., :, None, :], x[..., None, :, :]
        r = xl - xk  # (..., N, N, d)
        p = self.kernel.value(xk, xl)  # (..., N, N)
        gx = self.kernel.grad_x(xk, xl)
        gy = self.kernel.grad_y(xk, xl)
        eye_d = arrays.asarray(np.eye(d), like=x)
        # Off-diagonal blocks for every (k, l); at l = k they hold p_kk I / N, which the
        # diagonal sum below cancels by including its own l = k term (-p_kk I / N).
        blocks = r[..., :, None] * gy[..., None, :] + p[..., None, None] * eye_d  # (..,N,N,d,d)
        diag_blocks = xp.sum(
            r[..., :, None] * gx[..., None, :] - p[..., None, None] * eye_d, axis=-3
        )
        blocks = arrays.divide_fresh(arrays.add_diagonal_blocks(blocks, diag_blocks), n)
        # (..., N, N, d, d) -> (..., N, d, N, d) -> (..., Nd, Nd)
        blocks = xp.moveaxis(blocks, -2, -3)
        return xp.reshape(blocks, (*x.shape[:-2], n * d, n * d))

    def drift_and_linearization(
        self, t: float, x: Any, u: Any, kind: str
    ) -> tuple[Any, Linearization]:
        """F(t, x, u) and the ``"exact"`` or ``"frozen"`` linearization, sharing L(x)."""
        if kind not in ("exact", "frozen"):
            raise ValueError(f"jacobian must be 'exact' or 'frozen', got {kind!r}")
        x = self._check_state(x)
        frozen = self.frozen_linearization(x)
        f = frozen @ x
        if u is not None:
            f = f + u
        symmetric = bool(self.kernel.symmetric)
        if kind == "frozen":
            return f, Linearization(frozen, True, symmetric)
        # r ⊗ dp/dy is a symmetric block only for radial kernels (p a function of |x - y|).
        symmetric = symmetric and bool(getattr(self.kernel, "radial", False))
        return f, Linearization(self.jacobian(x), self.dim == 1, symmetric)
