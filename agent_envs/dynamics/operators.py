"""The linearizations of the drift as matrix-free linear operators, and the choice of path.

    L(x) v = (1/N) (P v - (P 1) * v),      P[k, l] = p(x_k, x_l),

for a block of vectors v (..., N, k), and the drift L(x) x, evaluated by the kernel sums of
`agent_envs.dynamics.kernel_sums` without forming P: the grid sum for d = 1 and the
Cucker-Smale kernel (O(N) per product), the chunked pairwise sum otherwise (O(N^2) time,
O(N * block) memory). The dense (..., N, N) matrix of `SwarmModel.frozen_linearization`
stays the path for small N and the reference.

In d = 1 the exact Jacobian (`eq:jac`) has the same structure, J v = (1/N)(G v - (G 1) * v),
with G[k, l] = w_l (alpha^2 - r^2)/(alpha^2 + r^2)^2 for the Cucker-Smale kernel, another
translation-invariant profile for the grid sum; for d > 1 (d x d blocks) or other kernels it
has no matrix-free form here, and asking for one raises `ValueError`.

`LinearizationOperator` supports what the exponential integrators do with a matrix:
``op @ v``, ``c * op`` (a scaled operator sharing the kernel sums), `shape`, `symmetric`, and
a bound `norm_inf` >= ||c A||_inf used by the Krylov phi-action
(`agent_envs.integrators.phi_functions.phi_action` accepts it in place of a matrix).
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from agent_envs.dynamics.kernel_sums import (
    DEFAULT_TOLERANCE,
    ChunkedKernelSum,
    GridKernelSum,
)
from agent_envs.dynamics.kernels import CuckerSmaleKernel, InteractionKernel

LINEAR_OPERATORS = ("auto", "dense", "matrix_free")
# "auto" goes matrix-free from this N on for the Cucker-Smale kernel in d = 1, 2: the crossover
# of one SERB step, dense vs matrix-free, measured by benchmarks/bench_large_swarms.py
# (tables 2 and 3). d = 1 moved from 500 to 1000 once the dense kernel pass was compiled: in
# table 2 (docs/results/benchmarks/other/bench_large_swarms_crossover.txt) dense / matrix-free
# is 0.11 (1 path) and 0.27 (20 paths) at N = 500, 0.83 and 1.52 at N = 1000, 1.46 and 2.44 at
# N = 1400: the crossover is near N = 1100 with one path and 850 with 20, so 1000 loses at
# most ~1.5x on either side (500 lost up to 9x).
AUTO_MATRIX_FREE_MIN_AGENTS = {1: 1000, 2: 2000}
# The grid sum replaces the chunked one from this N on (d = 2: below it the O(N^2) chunked
# product is cheaper than the grid's 2-D FFTs; measured 0.07 s vs 0.10 s at N = 5000, 0.32 s
# vs 0.11 s at N = 10^4, for x uniform on [-1, 1]^2, alpha = 0.1).
GRID_MIN_AGENTS = {1: 0, 2: 6000}
# ... and whenever the dense matrices of one step would exceed this many bytes (any d, kernel).
DENSE_MEMORY_BUDGET_BYTES = 2 * 2**30
# float64 (N, N) arrays alive at once in a dense frozen step: P and L, plus the (N, N, d)
# difference temporaries of `kernel.value` for d > 1 (2 + d in all); the exact Jacobian
# needs about (2 + 3 d) (N d)^2 floats.
# From this N on, a d = 1 Cucker-Smale swarm too wide for the grid warns that it falls back to
# the O(N^2) chunked sum (seconds per product there).
_WARN_CHUNKED_MIN_AGENTS = 20_000


def check_linear_operator(value: Any) -> str:
    """`value` if it is one of `LINEAR_OPERATORS`, else a ValueError naming the parameter."""
    if not isinstance(value, str) or value not in LINEAR_OPERATORS:
        raise ValueError(f"linear_operator must be one of {LINEAR_OPERATORS}, got {value!r}")
    return value


def dense_bytes(n_agents: int, dim: int, n_paths: int, kind: str) -> int:
    """Bytes of the dense matrices one step of `kind` ("frozen" | "exact") keeps alive."""
    if kind == "frozen":
        return 8 * (2 + dim) * n_paths * n_agents**2
    return 8 * (2 + 3 * dim) * n_paths * (n_agents * dim) ** 2


def grid_applies(kernel: InteractionKernel, dim: int) -> bool:
    """Whether the grid sum applies: d <= 2 and a `CuckerSmaleKernel`."""
    return dim in GRID_MIN_AGENTS and isinstance(kernel, CuckerSmaleKernel)


def exact_applies(kernel: InteractionKernel, dim: int) -> bool:
    """Whether the exact Jacobian has a matrix-free form: d = 1 and a `CuckerSmaleKernel`."""
    return dim == 1 and isinstance(kernel, CuckerSmaleKernel)


def _lorentzian_2d(alpha: float):
    a2 = alpha * alpha

    def lorentzian(r: np.ndarray) -> np.ndarray:  # p / w for r (..., 2)
        return 1.0 / (a2 + r[..., 0] * r[..., 0] + r[..., 1] * r[..., 1])

    return lorentzian


def _profiles(alpha: float):
    """g(r), r = x_k - x_l, with p(x_k, x_l) = w_l g(r) and its relatives (d = 1)."""
    a2 = alpha * alpha

    def lorentzian(r: np.ndarray) -> np.ndarray:  # p / w
        return 1.0 / (a2 + r * r)

    def attraction(r: np.ndarray) -> np.ndarray:  # (x_l - x_k) p / w
        return -r / (a2 + r * r)

    def jacobian(r: np.ndarray) -> np.ndarray:  # (p + (x_l - x_k) dp/dy) / w
        d = a2 + r * r
        return (a2 - r * r) / (d * d)

    return lorentzian, attraction, jacobian


class _PathSums:
    """Kernel sums of one path's positions x (N, d) for the `kind` linearization A.

    A v = (1/N)(G v - (G 1) * v) with G = P for the frozen L(x), and, for the exact Jacobian in
    d = 1 (`eq:jac`: J_kl = (1/N) w_l (alpha^2 - r^2)/(alpha^2 + r^2)^2 for l != k, and
    J_kk = -(1/N) sum_{l != k} of the same), G[k, l] = w_l (alpha^2 - r_kl^2)/(alpha^2 + r_kl^2)^2.
    Keeps the row sums G 1, the drift L(x) x and the row sums of P (|G| <= P entrywise, so
    2 max(P 1)/N bounds ||A||_inf for both kinds).
    """

    def __init__(self, kernel: InteractionKernel, x: np.ndarray, kind: str, tol: float, block: int):
        n = x.shape[0]
        self.grid = None
        self.chunked = None
        self.grid_1d = x.shape[1] == 1
        self._profile = 0 if kind == "frozen" else 2
        finite = bool(np.all(np.isfinite(x)))
        use_grid = finite and self._use_grid(kernel, x, tol)
        if not finite:
            # a non-finite state (a diverging path): NaN sums, as the dense matrix would give,
            # so the caller's divergence check sees them
            self.row_sums = self.p_row_sums = np.full(n, np.nan)
            self.drift = np.full(x.shape, np.nan)
        elif use_grid and self.grid_1d:
            # the exact Jacobian's profile has double poles: one digit finer for the same tol
            grid_tol = tol if kind == "frozen" else tol / 10
            self.grid = GridKernelSum(
                x[:, 0], _profiles(kernel.alpha), kernel.weights, kernel.alpha, grid_tol
            )
            select = (0, 1) if kind == "frozen" else (0, 1, self._profile)
            sums = self.grid(np.ones((n, 1)), select=select)
            self.p_row_sums = sums[0][:, 0]
            self.drift = sums[1] / n
            self.row_sums = sums[-1][:, 0] if kind == "exact" else self.p_row_sums
        elif kind == "exact":
            raise ValueError(
                "the matrix-free exact Jacobian needs d = 1, the Cucker-Smale kernel and a "
                "swarm narrow enough for the grid sum; use jacobian='frozen'"
            )
        else:
            if use_grid:  # d = 2: P 1 and P x from one product
                self.grid = GridKernelSum(
                    x, [_lorentzian_2d(kernel.alpha)], kernel.weights, kernel.alpha, tol
                )
                both = self.grid(np.concatenate([np.ones((n, 1)), x], axis=1))[0]
                self.row_sums, px = both[:, 0], both[:, 1:]
            else:
                self.chunked = ChunkedKernelSum(kernel, x, block)
                self.row_sums, px = self.chunked.row_sums_and_product(x)
            self.p_row_sums = self.row_sums
            self.drift = (px - self.row_sums[:, None] * x) / n

    @staticmethod
    def _use_grid(kernel: InteractionKernel, x: np.ndarray, tol: float) -> bool:
        n, dim = x.shape
        if not grid_applies(kernel, dim) or n < GRID_MIN_AGENTS[dim]:
            return False
        if GridKernelSum.fits(x, kernel.alpha, tol):
            return True
        if n >= _WARN_CHUNKED_MIN_AGENTS:
            warnings.warn(
                f"the swarm spans {np.ptp(x, axis=0)}, too wide for the grid sum at "
                f"alpha = {kernel.alpha:g}; using the O(N^2) chunked sum for N = {n}",
                RuntimeWarning,
                stacklevel=6,
            )
        return False

    def product(self, v: np.ndarray) -> np.ndarray:
        """G v for v (N, k)."""
        if self.grid is not None:
            return self.grid(v, select=(self._profile if self.grid_1d else 0,))[0]
        if self.chunked is not None:
            return self.chunked(v)
        return np.full(v.shape, np.nan)


class LinearizationOperator:
    """c A for positions x (..., N, d) (numpy), A = L(x) or the exact Jacobian, without P.

    Args:
        kernel: the interaction kernel.
        x: positions (..., N, d); one set of kernel sums per leading index (path).
        kind: "frozen" (L(x), any d and kernel) or "exact" (dF/dx; d = 1, Cucker-Smale).
        tol: relative accuracy of the grid sums (d = 1, Cucker-Smale).
        block: rows per block of the chunked sums (0: chosen from N).
    """

    def __init__(
        self,
        kernel: InteractionKernel,
        x: np.ndarray,
        kind: str = "frozen",
        tol: float = DEFAULT_TOLERANCE,
        block: int = 0,
    ) -> None:
        if kind not in ("frozen", "exact"):
            raise ValueError(f"kind must be 'frozen' or 'exact', got {kind!r}")
        x = np.asarray(x, dtype=float)
        if x.ndim < 2:
            raise ValueError(f"positions must have shape (..., N, d), got {x.shape}")
        self.batch_shape = tuple(x.shape[:-2])
        self.n_agents = x.shape[-2]
        flat = x.reshape(-1, *x.shape[-2:])
        self._paths = [_PathSums(kernel, xi, kind, tol, block) for xi in flat]
        self.kind = kind
        self.symmetric = bool(kernel.symmetric)  # the exact J too: d = 1, a radial kernel
        self.scale = 1.0
        self._max_row_sum = max(float(np.max(ps.p_row_sums)) for ps in self._paths)
        if not np.isfinite(self._max_row_sum):
            self._max_row_sum = np.inf

    @property
    def shape(self) -> tuple[int, ...]:
        return (*self.batch_shape, self.n_agents, self.n_agents)

    @property
    def dtype(self) -> np.dtype:
        return np.dtype(float)

    @property
    def norm_inf(self) -> float:
        """||c A||_inf <= 2 |c| max_k (P 1)_k / N (P >= 0, and |G| <= P entrywise)."""
        return 2.0 * abs(self.scale) * self._max_row_sum / self.n_agents

    def drift(self) -> np.ndarray:
        """L(x) x, shape (..., N, d) (without the scale c)."""
        out = np.stack([ps.drift for ps in self._paths])
        return out.reshape(*self.batch_shape, *out.shape[-2:])

    def matvec(self, v: Any) -> np.ndarray:
        """c L(x) v for v (..., N, k) broadcasting against the operator's batch shape."""
        v = np.asarray(v, dtype=float)
        if v.ndim < 2 or v.shape[-2] != self.n_agents:
            raise ValueError(f"v must have shape (..., {self.n_agents}, k), got {v.shape}")
        batch = np.broadcast_shapes(self.batch_shape, v.shape[:-2])
        if batch != self.batch_shape:
            raise ValueError(f"v's batch shape {v.shape[:-2]} does not fit {self.batch_shape}")
        vb = np.broadcast_to(v, (*batch, *v.shape[-2:])).reshape(-1, *v.shape[-2:])
        factor = self.scale / self.n_agents
        out = np.empty_like(vb)
        for i, (ps, vi) in enumerate(zip(self._paths, vb, strict=True)):
            prod = ps.product(vi)  # a fresh (N, k) array: updated in place
            prod -= ps.row_sums[:, None] * vi
            np.multiply(prod, factor, out=out[i])
        return out.reshape(*batch, *v.shape[-2:])

    def __matmul__(self, v: Any) -> np.ndarray:
        return self.matvec(v)

    def scaled(self, c: float) -> LinearizationOperator:
        """c times this operator (shares the kernel sums)."""
        new = object.__new__(LinearizationOperator)
        new.__dict__.update(self.__dict__)
        new.scale = self.scale * float(c)
        return new

    def __mul__(self, c: float) -> LinearizationOperator:
        if not np.isscalar(c):
            return NotImplemented
        return self.scaled(c)

    __rmul__ = __mul__

    def dense(self) -> np.ndarray:
        """c L(x) as a dense (..., N, N) array, column by column (for tests and small N)."""
        eye = np.broadcast_to(
            np.eye(self.n_agents), (*self.batch_shape, self.n_agents, self.n_agents)
        )
        return self.matvec(eye)

    def __repr__(self) -> str:
        return (
            f"LinearizationOperator(N={self.n_agents}, batch={self.batch_shape}, "
            f"scale={self.scale:g})"
        )
