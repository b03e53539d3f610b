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

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from agent_envs import arrays, native
from agent_envs.dynamics.kernels import CuckerSmaleKernel, InteractionKernel
from agent_envs.dynamics.laplacian import (
    FrozenLaplacian,
    KernelWorkspace,
    UpperTriangle,
    compiled_cucker_smale_drift,
    fill_cucker_smale,
    krylov_bounds,
    readonly_view,
)
from agent_envs.dynamics.operators import (
    AUTO_MATRIX_FREE_MIN_AGENTS,
    DENSE_MEMORY_BUDGET_BYTES,
    LinearizationOperator,
    check_linear_operator,
    dense_bytes,
    exact_applies,
    grid_applies,
)
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

    matrix: Any  # an array, or an operator (`@`, scalar `*`: dynamics.operators, .laplacian)
    per_coordinate: bool
    symmetric: bool
    #: (||A||_inf per batch member, width of spec(A) without its eigenvalue 0 or None, the
    #: bottom of an interval of that width holding spec(A) on 1^perp or None), numpy arrays of
    #: the batch shape (the bottom a float), for the Krylov phi-action (scaled with A by
    #: `scaled_bounds`)
    bounds: tuple[np.ndarray, np.ndarray | None, float | None] | None = None

    def scaled_bounds(self, c: float) -> tuple[np.ndarray, np.ndarray | None, float | None] | None:
        """`bounds` of c A (the interval's bottom for c > 0 only: c A flips it otherwise)."""
        if self.bounds is None:
            return None
        norms, widths, low = self.bounds
        scaled_low = c * low if low is not None and np.all(np.asarray(c) > 0) else None
        return abs(c) * norms, None if widths is None else abs(c) * widths, scaled_low

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

    `linear_operator` chooses how the drift and the linearizations are evaluated:
    ``"dense"`` forms the (..., N, N) matrix L(x) (and the (..., Nd, Nd) exact Jacobian);
    ``"matrix_free"`` uses `LinearizationOperator` (kernel sums without P; numpy only; the
    exact Jacobian only for d = 1 with the Cucker-Smale kernel); ``"auto"`` (default) is
    matrix-free for numpy states with the Cucker-Smale kernel when d = 1 and N >= 1000 or
    d = 2 and N >= 2000 (`AUTO_MATRIX_FREE_MIN_AGENTS`), or when the dense matrices of a step
    would exceed `DENSE_MEMORY_BUDGET_BYTES`, and dense otherwise.

    `threads` (default 1): the compiled passes over a batch's members (the kernel pass, and
    the fused exponential Rosenbrock-Euler step of the envs' models) run on that many of
    numba's threads, in contiguous spans of members; the results are the same bit for bit
    (each member is computed alone). At most `agent_envs.native.max_compiled_threads()`; 1
    without numba.
    """

    _threads = 1

    def __init__(self, params: SwarmParams, linear_operator: str = "auto") -> None:
        self.params = params
        self.kernel: InteractionKernel = kernel_from_params(params)
        self.n_agents = params.n_agents
        self.dim = params.dim
        self.sigma = params.sigma
        self.linear_operator = check_linear_operator(linear_operator)
        self._workspace = KernelWorkspace()
        self._matrix_free_answers: dict[tuple[Any, ...], bool] = {}
        kernel = self.kernel
        # p_max = w / alpha^2 = P_kk >= every P_kl: the symmetric Cucker-Smale kernel's peak
        self._peak: float | None = None
        if isinstance(kernel, CuckerSmaleKernel) and kernel.weights.ndim == 0:
            self._peak = float(kernel.weights) / kernel.alpha**2
            native.available("kernel")  # its one-time load falls here, not in a step

    def __setstate__(self, state: dict[str, Any]) -> None:
        """Unpickling: a model pickled before `matrix_free` kept its answers gets an empty
        memo of them."""
        self.__dict__.update(state)
        self.__dict__.setdefault("_matrix_free_answers", {})
        if self.__dict__.get("_threads", 1) > 1:
            # threads are this process's setting: at most what numba allows here (1 without
            # numba); the results are the same on any number
            self._threads = min(self._threads, native.max_compiled_threads())

    @property
    def threads(self) -> int:
        """Threads of the compiled passes over a batch's members (see the class docstring)."""
        return self._threads

    @threads.setter
    def threads(self, value: int) -> None:
        # (validated only: compiling or running a threaded pass starts numba's threads, which
        # the first threaded call does; the envs load them in their first reset)
        self._threads = native.check_compiled_threads(value, "threads")

    def _uses_workspace(self, x: Any) -> bool:
        """Whether x takes the workspace path: numpy, the Cucker-Smale kernel, dense."""
        return (
            isinstance(x, np.ndarray)
            and isinstance(self.kernel, CuckerSmaleKernel)
            and not self.matrix_free(x)
        )

    def _laplacian(self, x: np.ndarray) -> tuple[FrozenLaplacian, np.ndarray]:
        """L(x) as a `FrozenLaplacian` over the workspace, and the drift L(x) x (fresh).

        One kernel pass into the workspace's P, one product P [x | 1] = [P x | s], then
        F = (P x - s * x) / N; nothing of size (..., N, N) is allocated after the first call.
        With numba, for the symmetric kernel with a scalar weight, the compiled pass
        (`agent_envs.native.kernel`) writes P's lower triangle and returns s and F
        instead (the operator fills the upper triangle if a consumer of the whole P asks).
        """
        kernel = self.kernel
        ws = self._workspace
        p, augmented, product, scratch = ws.buffers(tuple(x.shape))
        ws.generation += 1
        compiled = self.compiled_pass_parameters(x)
        if compiled is not None:
            # the symmetric kernel with a scalar weight: P's lower triangle, s and L(x) x in one
            # compiled pass; the upper triangle is filled if a consumer of the whole P asks
            row_sums, drift = compiled_cucker_smale_drift(x, *compiled, p, self.threads)
            return self._workspace_operator(p, row_sums, UpperTriangle(p)), drift
        weights = kernel.weights if kernel._scalar_weight is None else kernel._scalar_weight
        fill_cucker_smale(x, kernel.alpha, weights, out=p, scratch=scratch)
        d = x.shape[-1]
        augmented[..., :d] = x
        np.matmul(p, augmented, out=product)
        row_sums = product[..., d].copy()
        drift = product[..., :d] - row_sums[..., None] * x
        drift /= self.n_agents
        return self._workspace_operator(p, row_sums), drift

    def _workspace_operator(
        self, p: np.ndarray, row_sums: np.ndarray, upper: UpperTriangle | None = None
    ) -> FrozenLaplacian:
        """L(x) over the workspace's P (just written; `upper` where only its lower triangle
        was) and its row sums, at this generation."""
        ws = self._workspace
        return FrozenLaplacian(
            readonly_view(p),
            row_sums,
            symmetric=bool(self.kernel.symmetric),
            peak=self._peak,
            workspace=ws,
            generation=ws.generation,
            upper=upper,
        )

    def compiled_pass_parameters(self, x: Any) -> tuple[float, float] | None:
        """(w, alpha^2) when the compiled kernel pass serves x (float64 numpy states, the
        symmetric Cucker-Smale kernel with a scalar weight w, numba loaded), else None."""
        if (
            self._peak is None
            or not isinstance(x, np.ndarray)
            or x.dtype != np.float64
            or not native.available("kernel")
        ):
            return None
        kernel = self.kernel
        weights = kernel.weights if kernel._scalar_weight is None else kernel._scalar_weight
        return float(weights), float(kernel.alpha**2)

    def matrix_free(self, x: Any, kind: str = "frozen") -> bool:
        """Whether the drift and the `kind` linearization at x go matrix-free (see class doc).

        Raises ValueError where the matrix-free path is needed (forced, or the dense matrices
        over budget) but does not exist: torch states, the exact Jacobian for d > 1 or
        another kernel.

        The answer depends only on x's type and shape, `kind` and the memory budget (the
        model's parameters are fixed): it is kept per (type, shape, kind, budget); an env step
        asks four or five times.
        """
        key = (type(x), tuple(x.shape), kind, DENSE_MEMORY_BUDGET_BYTES)
        known = self._matrix_free_answers.get(key)
        if known is None:
            known = self._matrix_free(x, kind)
            if len(self._matrix_free_answers) >= 8:  # a few shapes per model in practice
                self._matrix_free_answers.clear()
            self._matrix_free_answers[key] = known
        return known

    def _matrix_free(self, x: Any, kind: str) -> bool:
        """`matrix_free` computed (it raises where the matrix-free path is needed but missing:
        that is never kept)."""
        n_paths = math.prod(x.shape[:-2])
        needed = dense_bytes(self.n_agents, self.dim, n_paths, kind)
        if self.linear_operator == "dense":
            return False
        if self.linear_operator == "auto":
            if arrays.is_torch(x):
                return False
            wanted = needed > DENSE_MEMORY_BUDGET_BYTES or (
                grid_applies(self.kernel, self.dim)
                and self.n_agents >= AUTO_MATRIX_FREE_MIN_AGENTS[self.dim]
            )
        else:
            wanted = True
        if not wanted:
            return False
        if arrays.is_torch(x):
            raise ValueError(
                "linear_operator='matrix_free' works on numpy states; use 'dense' or 'auto' "
                "with torch"
            )
        if kind == "exact" and not exact_applies(self.kernel, self.dim):
            raise ValueError(
                "jacobian='exact' has a matrix-free form only for d = 1 and the Cucker-Smale "
                f"kernel (the dense Jacobian of N = {self.n_agents}, d = {self.dim} needs "
                f"{needed / 2**30:.1f} GiB); use jacobian='frozen' or linear_operator='dense'"
            )
        return True

    def linearization_operator(self, x: Any, kind: str = "frozen") -> LinearizationOperator:
        """L(x) (``"frozen"``) or the exact Jacobian (``"exact"``, d = 1) as a matrix-free
        operator (`agent_envs.dynamics.operators`); x (..., N, d), numpy."""
        return LinearizationOperator(self.kernel, self._check_state(x), kind)

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
        """L(x) = (P(x) - diag(P(x) 1)) / N; shape (..., N, N), a fresh array."""
        return self._frozen_with_row_sums(x)[0]

    def _frozen_with_row_sums(self, x: Any) -> tuple[Any, Any]:
        """(L(x), s = P(x) 1): the Array-API path (torch, user kernels, the reference)."""
        p = self.interaction_matrix(x)
        xp = arrays.namespace(p)
        if not isinstance(self.kernel, CuckerSmaleKernel) and isinstance(p, np.ndarray):
            # the in-place steps below may only write into an array we own: a user kernel may
            # return a cached, read-only or broadcast array
            p = np.array(p, dtype=float, copy=True)
        row_sums = xp.sum(p, axis=-1)
        p = arrays.subtract_diagonal(p, row_sums)
        return arrays.divide_fresh(p, self.n_agents), row_sums

    def interaction_drift(self, x: Any) -> Any:
        """(1/N) sum_l p(x_k, x_l)(x_l - x_k) = L(x) x; shape (..., N, d)."""
        x = self._check_state(x)
        if self.matrix_free(x):
            return self.linearization_operator(x).drift()
        if self._uses_workspace(x):
            return self._laplacian(x)[1]
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
        if self.matrix_free(x, kind):
            operator = self.linearization_operator(x, kind)
            f = operator.drift()
            if u is not None:
                f = f + u
            # in d = 1 the exact Jacobian is symmetric like L(x) for a radial kernel
            return f, Linearization(operator, True, operator.symmetric)
        symmetric = bool(self.kernel.symmetric)
        if kind == "frozen" and self._uses_workspace(x):
            operator, f = self._laplacian(x)
            if u is not None:
                f = f + u
            return f, Linearization(operator, True, symmetric)
        frozen, row_sums = self._frozen_with_row_sums(x)
        f = frozen @ x
        if u is not None:
            f = f + u
        if kind == "frozen":
            bounds = None
            if isinstance(self.kernel, CuckerSmaleKernel):
                # the same bounds the workspace path reads off its operator (torch, reference)
                diagonal = self.kernel.weights / self.kernel.alpha**2
                norms, widths = krylov_bounds(
                    arrays.to_numpy(row_sums), diagonal, self.n_agents, self._peak, symmetric
                )
                # the bottom -p_max of spec(L) on 1^perp, as FrozenLaplacian.krylov_bounds
                bounds = (norms, widths, None if widths is None else -1.0 * self._peak)
            return f, Linearization(frozen, True, symmetric, bounds)
        # r ⊗ dp/dy is a symmetric block only for radial kernels (p a function of |x - y|).
        symmetric = symmetric and bool(getattr(self.kernel, "radial", False))
        return f, Linearization(self.jacobian(x), self.dim == 1, symmetric)
