"""Interaction kernels p(x_k, x_l) and their partial derivatives.

A kernel is evaluated on *pairs*: `xk` has shape (..., N, 1, d) and `xl` has shape
(..., 1, N, d), so that broadcasting gives every ordered pair (k, l). `value` returns the
(..., N, N) matrix P with P[..., k, l] = p(x_k, x_l); `grad_x` and `grad_y` return the
(..., N, N, d) arrays of the partial gradients dp/dx and dp/dy at (x_k, x_l). The last axis of
length N of `value` is the index l, so a kernel that depends on the index of the second agent
(like the non-symmetric kernel of `eq:nonsymmker`) multiplies by a weight array of shape (N,).

Users plug in their own kernel by writing a class with these three methods and a boolean
attribute `symmetric` (True when p(x, y) = p(y, x) for every pair, which makes the frozen
linearization L(x) a symmetric matrix). The exact Jacobian is symmetric only when, in addition,
p depends on |x - y| alone; a kernel says so with the optional attribute `radial = True`
(otherwise the exponential integrators treat the exact Jacobian as non-symmetric).

Kernels receive numpy arrays or torch tensors (see `agent_envs.arrays`) and must answer in the
same library; write them with array methods/operators or `arrays.namespace(xk)`.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from agent_envs import arrays


@runtime_checkable
class InteractionKernel(Protocol):
    """What the dynamics need from an interaction kernel (see the module docstring)."""

    symmetric: bool

    def value(self, xk: np.ndarray, xl: np.ndarray) -> np.ndarray:
        """p(x_k, x_l): (..., N, N) from xk (..., N, 1, d) and xl (..., 1, N, d)."""
        ...

    def grad_x(self, xk: np.ndarray, xl: np.ndarray) -> np.ndarray:
        """dp/dx at (x_k, x_l): (..., N, N, d)."""
        ...

    def grad_y(self, xk: np.ndarray, xl: np.ndarray) -> np.ndarray:
        """dp/dy at (x_k, x_l): (..., N, N, d)."""
        ...


class CuckerSmaleKernel:
    """Cucker-Smale-like kernel ``p(x_k, x_l) = w_l / (alpha^2 + |x_k - x_l|^2)``.

    With one weight ``w = 1/eps`` this is the symmetric kernel of `eq:symmker`; with weights
    ``w_l = 1/eps_l``, ``eps_l = eps_min + (eps_max - eps_min)(l-1)/(N-1)``, it is the
    non-symmetric kernel of `eq:nonsymmker`.

    Gradients, with r = x_l - x_k and D = alpha^2 + |r|^2:
    ``dp/dx = 2 w_l r / D^2`` and ``dp/dy = -2 w_l r / D^2``.
    """

    def __init__(self, alpha: float, weights: float | np.ndarray) -> None:
        if not alpha > 0:
            raise ValueError(f"alpha must be > 0, got {alpha}")
        w = np.asarray(weights, dtype=float)
        if w.ndim > 1 or not np.all(np.isfinite(w)) or np.any(w <= 0):
            raise ValueError("weights must be a positive finite scalar or 1-D array")
        self.alpha = float(alpha)
        self.weights = w
        self._scalar_weight = float(w) if w.ndim == 0 else None
        self._weights_cache: dict = {}
        self.symmetric = bool(w.ndim == 0 or np.all(w == w.flat[0]))
        self.radial = True  # p depends on |x_k - x_l| (and the index l): see the module doc

    @classmethod
    def symmetric_kernel(cls, alpha: float, epsilon: float) -> CuckerSmaleKernel:
        """The kernel of `eq:symmker` with stiffness epsilon."""
        return cls(alpha, 1.0 / epsilon)

    @classmethod
    def nonsymmetric_kernel(
        cls, alpha: float, epsilon_min: float, epsilon_max: float, n_agents: int
    ) -> CuckerSmaleKernel:
        """The kernel of `eq:nonsymmker`: eps_l linear from eps_min (l = 1) to eps_max (l = N)."""
        eps = np.linspace(epsilon_min, epsilon_max, n_agents)
        kernel = cls(alpha, 1.0 / eps)
        kernel.symmetric = epsilon_min == epsilon_max
        return kernel

    def _weights_like(self, x):
        """The weights w as a float, or as an (N,) array of x's library and device."""
        if self._scalar_weight is not None:
            return self._scalar_weight
        if not arrays.is_torch(x):
            return self.weights
        key = (x.device, x.dtype)
        if key not in self._weights_cache:
            self._weights_cache[key] = arrays.asarray(self.weights, like=x)
        return self._weights_cache[key]

    def _denominator(self, xk, xl):
        r = xl - xk
        xp = arrays.namespace(r)
        if r.shape[-1] == 1:
            return r, self.alpha**2 + r[..., 0] * r[..., 0]
        return r, self.alpha**2 + xp.sum(r * r, axis=-1)

    def value(self, xk, xl):
        if xk.shape[-1] == 1 and not arrays.is_torch(xk):
            # numpy, d = 1: the same arithmetic in one (..., N, N) buffer (no large temporaries)
            r = xl[..., 0] - xk[..., 0]
            np.multiply(r, r, out=r)
            r += self.alpha**2
            return np.divide(self._weights_like(xk), r, out=r)
        _, denom = self._denominator(xk, xl)
        return self._weights_like(xk) / denom

    def grad_x(self, xk, xl):
        r, denom = self._denominator(xk, xl)
        return (2.0 * self._weights_like(xk) / denom**2)[..., None] * r

    def grad_y(self, xk: np.ndarray, xl: np.ndarray) -> np.ndarray:
        return -self.grad_x(xk, xl)

    def __repr__(self) -> str:
        return f"CuckerSmaleKernel(alpha={self.alpha}, symmetric={self.symmetric})"


#: How to write a kernel that works on numpy and torch (shown when a kernel answers in the
#: wrong library).
ARRAY_GENERIC_HINT = (
    "write it with array operators and methods, or take the namespace of its input: "
    "`xp = arrays.namespace(xk); d2 = xp.sum((xk - xl) ** 2, axis=-1); return xp.exp(-d2)` "
    "(agent_envs.arrays), not np.sum / np.exp"
)


def check_kernel_library(kernel: InteractionKernel, like: object, dim: int) -> None:
    """Probe `kernel` once on a tiny input of `like`'s array library (numpy or torch, with its
    device and dtype): `value`, `grad_x` and `grad_y` must run and answer in that library.

    The core's torch paths (`simulate(..., backend="torch")`, the optimal-control solver, the
    learners trained through it) call this at model construction, so that a kernel written with
    numpy functions fails with one `TypeError` naming the kernel class and the fix, instead of
    deep inside a step. Shapes: xk (2, 1, d), xl (1, 2, d), as the dynamics call it.
    """
    xk = arrays.asarray(np.array([[[0.0] * dim], [[0.5] * dim]]), like=like)
    xl = arrays.asarray(np.array([[[0.0] * dim, [0.5] * dim]]), like=like)
    library = "torch" if arrays.is_torch(like) else "numpy"
    name = type(kernel).__name__
    for method in ("value", "grad_x", "grad_y"):
        try:
            answer = getattr(kernel, method)(xk, xl)
        except Exception as exc:  # any failure of user code on this library is the same error
            raise TypeError(
                f"kernel {name}.{method} failed on {library} input ({type(exc).__name__}: "
                f"{exc}); kernels receive numpy arrays or torch tensors and must answer in "
                f"the same library: {ARRAY_GENERIC_HINT}"
            ) from exc
        if arrays.is_torch(answer) != arrays.is_torch(like):
            raise TypeError(
                f"kernel {name}.{method} answered a {type(answer).__name__} for {library} "
                f"input; kernels must answer in their input's library: {ARRAY_GENERIC_HINT}"
            )
