"""Actions of the phi-functions of a matrix on a block of vectors.

    phi_0(z) = e^z,   phi_1(z) = (e^z - 1)/z,   phi_2(z) = (e^z - 1 - z)/z^2,
    phi_p(A) = int_0^1 e^{(1-s)A} s^{p-1}/(p-1)! ds      (p >= 1)

`phi_action(A, V, order)` returns phi_order(A) V for A of shape (..., n, n) and V of shape
(..., n, k), batched over leading axes. Three strategies, one implementation each:

- ``"expm"``: the exponential of the augmented (n + p k) block matrix
  [[A, V, 0], [0, 0, I], [0, 0, 0]] (Sidje's Expokit trick), via `scipy.linalg.expm`
  (Pade with scaling and squaring). Dense, O((n+pk)^3); the reference for small n.
- ``"eigh"``: A = Q diag(lambda) Q^T for symmetric A, phi_p(A) V = Q phi_p(lambda) Q^T V.
- ``"krylov"``: Arnoldi (with classical Gram-Schmidt run twice) builds an orthonormal basis
  Q_m of span{v, Av, ..., A^{m-1} v} and H_m = Q_m^T A Q_m; then
  phi_p(A) v ~ |v| Q_m phi_p(H_m) e_1, the small phi evaluated by "expm". The dimension m grows
  until two successive approximations agree to `rtol` (checked every few steps) or a happy
  breakdown; O(m n^2) for a dense A, so the method of choice for large n. If it has not
  converged at `max_krylov_dim`, a `RuntimeWarning` is issued and the dense method is used.

``"auto"`` picks "expm" for n <= 64, "eigh" for a single symmetric matrix with n <= 128, and
"krylov" otherwise: the crossovers measured by benchmarks/bench_integrators.py on 2 cores with
one BLAS thread (at n = 100, one path: eigh 0.7 ms, expm 1.2 ms, krylov 1.0 ms; with 20 paths
krylov wins; at n >= 200 krylov wins by 2.5x-7x).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import scipy.linalg

PHI_METHODS = ("auto", "expm", "eigh", "krylov")
_AUTO_EXPM_MAX = 64
_AUTO_EIGH_MAX = 128


def phi_scalar(z: np.ndarray, order: int) -> np.ndarray:
    """phi_order(z) elementwise for real or complex z, accurate near z = 0 (Taylor series)."""
    z = np.asarray(z)
    if order == 0:
        return np.exp(z)
    if order == 1:
        # expm1(z)/z is accurate to round-off for every z != 0 (no cancellation), and the
        # masked Taylor branch below costs ~70 us of numpy overhead on small arrays.
        nonzero = z != 0
        with np.errstate(over="ignore"):
            return np.where(nonzero, np.expm1(z) / np.where(nonzero, z, 1), 1.0)
    small = np.abs(z) < 0.1
    out = np.empty_like(z, dtype=np.result_type(z, float))
    zs = z[small]
    # Taylor: phi_p(z) = sum_j z^j / (j + p)!
    acc = np.zeros_like(zs, dtype=out.dtype)
    term = np.ones_like(zs, dtype=out.dtype) / math.factorial(order)
    for j in range(16):
        acc = acc + term
        term = term * zs / (j + order + 1)
    out[small] = acc
    zl = z[~small]
    val = np.expm1(zl)
    for j in range(1, order):
        val = val - zl**j / math.factorial(j)
    out[~small] = val / zl**order
    return out


def _augmented_expm(a: np.ndarray, v: np.ndarray, order: int) -> np.ndarray:
    n, k = a.shape[-1], v.shape[-1]
    size = n + order * k
    aug = np.zeros((*a.shape[:-2], size, size), dtype=np.result_type(a, v))
    aug[..., :n, :n] = a
    aug[..., :n, n : n + k] = v
    for j in range(1, order):
        rows = slice(n + (j - 1) * k, n + j * k)
        cols = slice(n + j * k, n + (j + 1) * k)
        aug[..., rows, cols] = np.eye(k)
    expo = scipy.linalg.expm(aug)
    return expo[..., :n, n + (order - 1) * k :]


def _eigh_action(a: np.ndarray, v: np.ndarray, order: int) -> np.ndarray:
    lam, q = np.linalg.eigh(a)
    coef = np.swapaxes(q, -1, -2) @ v
    return q @ (phi_scalar(lam, order)[..., None] * coef)


def _small_phi_e1(hess: np.ndarray, order: int, symmetric: bool) -> np.ndarray:
    """phi_order(H) e_1 for a batch of small (m, m) matrices H; returns (..., m)."""
    m = hess.shape[-1]
    if symmetric:
        # Arnoldi on a symmetric matrix gives a symmetric tridiagonal H (up to round-off).
        lam, q = np.linalg.eigh(0.5 * (hess + np.swapaxes(hess, -1, -2)))
        return (q @ (phi_scalar(lam, order) * q[..., 0, :])[..., None])[..., 0]
    e1 = np.zeros((*hess.shape[:-2], m, 1))
    e1[..., 0, 0] = 1.0
    return _augmented_expm(hess, e1, order)[..., 0]


def _krylov_action(
    a: np.ndarray,
    v: np.ndarray,
    order: int,
    rtol: float,
    max_dim: int,
    symmetric: bool = False,
    check_every: int = 4,
) -> np.ndarray | None:
    n = a.shape[-1]
    max_dim = min(max_dim, n)
    batch = np.broadcast_shapes(a.shape[:-2], v.shape[:-2])
    v = np.broadcast_to(v, (*batch, *v.shape[-2:]))
    k = v.shape[-1]
    beta = np.linalg.norm(v, axis=-2)  # (..., k)
    safe_beta = np.where(beta > 0, beta, 1.0)
    basis = np.zeros((max_dim + 1, *batch, n, k))
    basis[0] = v / safe_beta[..., None, :]
    hess = np.zeros((*batch, k, max_dim + 1, max_dim))
    scale = np.max(np.abs(a), axis=(-2, -1), keepdims=True)[..., 0]  # (..., 1) for breakdown
    prev = None
    coeffs = None
    converged = False
    for j in range(max_dim):
        w = a @ basis[j]  # (..., n, k)
        for _ in range(2):  # CGS2: Gram-Schmidt twice keeps the basis orthonormal
            h = np.einsum("j...nk,...nk->...kj", basis[: j + 1], w)
            w = w - np.einsum("j...nk,...kj->...nk", basis[: j + 1], h)
            hess[..., : j + 1, j] += h
        h_next = np.linalg.norm(w, axis=-2)  # (..., k)
        hess[..., j + 1, j] = h_next
        breakdown = h_next <= 1e-12 * (scale + 1e-300)
        basis[j + 1] = np.where(
            breakdown[..., None, :], 0.0, w / np.where(breakdown, 1.0, h_next)[..., None, :]
        )
        m = j + 1
        converged = bool(np.all(breakdown)) or m == n
        done = converged or m == max_dim
        if m % check_every and not done:
            continue
        coeffs = _small_phi_e1(hess[..., :m, :m], order, symmetric)  # (..., k, m)
        if prev is not None and not done:
            diff = np.linalg.norm(coeffs[..., : prev.shape[-1]] - prev, axis=-1)
            diff = np.sqrt(diff**2 + np.sum(coeffs[..., prev.shape[-1] :] ** 2, axis=-1))
            size = np.linalg.norm(coeffs, axis=-1)
            if np.all(diff <= rtol * size + 1e-300):
                done = converged = True
        if done:
            break
        prev = coeffs
    assert coeffs is not None
    if not converged:
        return None
    m = coeffs.shape[-1]
    out = np.einsum("j...nk,...kj->...nk", basis[:m], coeffs)
    return out * beta[..., None, :]


def auto_phi_method(size: int, n_matrices: int, symmetric: bool) -> str:
    """The strategy ``method="auto"`` uses for `n_matrices` matrices of shape (size, size).

    Public so that a caller that batches several independent problems together (the native
    vector env stacks its envs on a leading axis) can fix the strategy each problem would get
    on its own, and so compute each one exactly as an unbatched call would.
    """
    if size <= _AUTO_EXPM_MAX:
        return "expm"
    if symmetric and size <= _AUTO_EIGH_MAX and n_matrices == 1:
        return "eigh"
    return "krylov"


def _auto_method(a: np.ndarray, v: np.ndarray, symmetric: bool) -> str:
    n_matrices = int(np.prod(np.broadcast_shapes(a.shape[:-2], v.shape[:-2]), dtype=int))
    return auto_phi_method(a.shape[-1], n_matrices, symmetric)


def phi_action(
    a: np.ndarray,
    v: np.ndarray,
    order: int = 1,
    *,
    method: str = "auto",
    symmetric: bool = False,
    rtol: float = 1e-10,
    max_krylov_dim: int = 100,
) -> np.ndarray:
    """phi_order(A) V for A (..., n, n) and V (..., n, k); returns (..., n, k).

    Args:
        a: the (already time-step scaled) matrix, e.g. tau J.
        v: the block of vectors.
        order: p >= 1.
        method: "auto", "expm", "eigh" (requires `symmetric=True`) or "krylov".
        symmetric: whether A is symmetric (enables "eigh").
        rtol: relative tolerance of the Krylov approximation.
        max_krylov_dim: largest Krylov dimension tried.
    """
    if order < 1:
        raise ValueError(f"order must be >= 1, got {order}")
    if method not in PHI_METHODS:
        raise ValueError(f"method must be one of {PHI_METHODS}, got {method!r}")
    a = np.asarray(a, dtype=float)
    v = np.asarray(v, dtype=float)
    if a.shape[-1] != a.shape[-2] or v.shape[-2] != a.shape[-1]:
        raise ValueError(f"shapes do not fit: A {a.shape}, V {v.shape}")
    if method == "auto":
        method = _auto_method(a, v, symmetric)
    if method == "eigh":
        if not symmetric:
            raise ValueError("method='eigh' needs a symmetric matrix (symmetric=True)")
        return _eigh_action(a, v, order)
    if method == "expm":
        return _augmented_expm(a, v, order)
    result = _krylov_action(a, v, order, rtol, max_krylov_dim, symmetric)
    if result is None:
        fallback = "eigh" if symmetric else "expm"
        warnings.warn(
            f"Krylov phi-action did not reach rtol={rtol} within max_krylov_dim="
            f"{max_krylov_dim} (matrix size {a.shape[-1]}); falling back to dense '{fallback}'",
            RuntimeWarning,
            stacklevel=2,
        )
        return _eigh_action(a, v, order) if symmetric else _augmented_expm(a, v, order)
    return result
