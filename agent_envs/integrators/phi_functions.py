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
from typing import Any

import numpy as np

from agent_envs import arrays

PHI_METHODS = ("auto", "expm", "eigh", "krylov")
_AUTO_EXPM_MAX = 64
_AUTO_EIGH_MAX = 128
_TAYLOR_TERMS = 16


def phi_scalar(z: Any, order: int) -> Any:
    """phi_order(z) elementwise for real z (numpy or torch), accurate near z = 0.

    |z| < 0.1: the Taylor series sum_j z^j / (j + p)!, 16 terms (Horner); otherwise
    (e^z - sum_{j<p} z^j / j!) / z^p with expm1. phi_1 is expm1(z)/z, accurate to round-off for
    every z != 0. Both branches are evaluated on safe arguments and combined with `where`, so
    autograd never sees a division by zero.
    """
    if not (arrays.is_torch(z) or isinstance(z, np.ndarray)):
        z = np.asarray(z, dtype=float)
    xp = arrays.namespace(z)
    if order == 0:
        return xp.exp(z)
    nonzero = z != 0
    z_safe = xp.where(nonzero, z, 1.0)
    if order == 1:
        with np.errstate(over="ignore"):
            return xp.where(nonzero, xp.expm1(z_safe) / z_safe, 1.0)
    small = xp.abs(z) < 0.1
    zs = xp.where(small, z, 0.0)
    acc = xp.zeros_like(zs) + 1.0 / math.factorial(_TAYLOR_TERMS - 1 + order)
    for j in range(_TAYLOR_TERMS - 2, -1, -1):
        acc = acc * zs + 1.0 / math.factorial(j + order)
    zl = xp.where(small, 1.0, z)
    with np.errstate(over="ignore", invalid="ignore"):
        val = xp.expm1(zl)
        power = zl
        for j in range(1, order):
            val = val - power / math.factorial(j)
            power = power * zl
        return xp.where(small, acc, val / power)


def phi_derivative(z: Any, order: int) -> Any:
    """phi_order'(z) = phi_order(z) - order phi_{order+1}(z) (from the Taylor series)."""
    return phi_scalar(z, order) - order * phi_scalar(z, order + 1)


def _augmented_expm(a: Any, v: Any, order: int) -> Any:
    """phi_order(A) V as a block of exp([[A, V, 0], [0, 0, I], [0, 0, 0]]) (Sidje)."""
    xp = arrays.namespace(a, v)
    n, k = a.shape[-1], v.shape[-1]
    size = n + order * k
    batch = tuple(np.broadcast_shapes(tuple(a.shape[:-2]), tuple(v.shape[:-2])))
    if arrays.is_numpy_namespace(xp):
        aug = np.zeros((*batch, size, size), dtype=np.result_type(a, v))
        aug[..., :n, :n] = a
        aug[..., :n, n : n + k] = v
        for j in range(1, order):
            aug[..., n + (j - 1) * k : n + j * k, n + j * k : n + (j + 1) * k] = np.eye(k)
    else:
        top = [xp.broadcast_to(a, (*batch, n, n)), xp.broadcast_to(v, (*batch, n, k))]
        if order > 1:
            top.append(arrays.zeros((*batch, n, (order - 1) * k), like=a))
        lower = np.zeros((order * k, size))
        for j in range(1, order):
            lower[(j - 1) * k : j * k, n + j * k : n + (j + 1) * k] = np.eye(k)
        lower = xp.broadcast_to(arrays.asarray(lower, like=a), (*batch, order * k, size))
        aug = xp.concat([xp.concat(top, axis=-1), lower], axis=-2)
    expo = arrays.expm(aug)
    return expo[..., :n, n + (order - 1) * k :]


def _eigh_action(a: Any, v: Any, order: int) -> Any:
    return arrays.symmetric_function_action(
        a, v, lambda lam: phi_scalar(lam, order), lambda lam: phi_derivative(lam, order)
    )


def _small_phi_e1(hess: Any, order: int, symmetric: bool) -> Any:
    """phi_order(H) e_1 for a batch of small (m, m) matrices H; returns (..., m)."""
    xp = arrays.namespace(hess)
    m = hess.shape[-1]
    e1 = np.zeros((m, 1))
    e1[0, 0] = 1.0
    e1 = arrays.asarray(e1, like=hess)
    if symmetric:
        # Arnoldi on a symmetric matrix gives a symmetric tridiagonal H (up to round-off).
        return _eigh_action(hess, e1, order)[..., 0]
    e1 = xp.broadcast_to(e1, (*hess.shape[:-2], m, 1))
    return _augmented_expm(hess, e1, order)[..., 0]


def _hessenberg(columns: list[Any], subdiag: list[Any], m: int) -> Any:
    """H (..., m, m) from its columns h_j (..., j + 1) and subdiagonal entries (...)."""
    xp = arrays.namespace(columns[0])
    cols = []
    for j in range(m):
        parts = [columns[j]]
        if j + 1 < m:
            parts.append(subdiag[j][..., None])
        if j + 2 < m:
            parts.append(arrays.zeros((*columns[j].shape[:-1], m - j - 2), like=columns[j]))
        cols.append(xp.concat(parts, axis=-1))
    return xp.stack(cols, axis=-1)


def _krylov_action(
    a: Any,
    v: Any,
    order: int,
    rtol: float,
    max_dim: int,
    symmetric: bool = False,
    check_every: int = 4,
) -> Any | None:
    """Arnoldi (CGS2) on each column of V; returns None when not converged at max_dim.

    The columns are handled as rows internally: W (..., k, n). The basis vectors are kept in a
    list and stacked, never written in place, so autograd differentiates through the final
    basis and Hessenberg matrix; the convergence test reads detached values.
    """
    xp = arrays.namespace(a, v)
    n = a.shape[-1]
    max_dim = min(max_dim, n)
    at = xp.matrix_transpose(a)
    rows = xp.matrix_transpose(v)  # (..., k, n)
    beta = xp.linalg.vector_norm(rows, axis=-1)  # (..., k)
    safe_beta = xp.where(beta > 0, beta, 1.0)
    basis = [rows / safe_beta[..., None]]
    stacked = basis[0][..., None, :]  # (..., k, j + 1, n)
    scale = xp.max(xp.abs(a), axis=(-2, -1))[..., None]  # (..., 1) for the breakdown test
    columns: list[Any] = []
    subdiag: list[Any] = []
    prev = None
    coeffs = None
    converged = False
    for j in range(max_dim):
        w = basis[j] @ at  # (..., k, n): A q_j for each column
        h_total = None
        for _ in range(2):  # CGS2: Gram-Schmidt twice keeps the basis orthonormal
            h = (stacked @ w[..., None])[..., 0]  # (..., k, j + 1)
            w = w - (h[..., None, :] @ stacked)[..., 0, :]
            h_total = h if h_total is None else h_total + h
        h_next = xp.linalg.vector_norm(w, axis=-1)  # (..., k)
        columns.append(h_total)
        subdiag.append(h_next)
        breakdown = h_next <= 1e-12 * (scale + 1e-300)
        q_next = xp.where(
            breakdown[..., None], 0.0, w / xp.where(breakdown, 1.0, h_next)[..., None]
        )
        basis.append(q_next)
        stacked = xp.concat([stacked, q_next[..., None, :]], axis=-2)
        m = j + 1
        converged = bool(xp.all(breakdown)) or m == n
        done = converged or m == max_dim
        if m % check_every and not done:
            continue
        coeffs = _small_phi_e1(_hessenberg(columns, subdiag, m), order, symmetric)  # (..., k, m)
        if prev is not None and not done:
            c, p = arrays.to_numpy(coeffs), arrays.to_numpy(prev)
            diff = np.linalg.norm(c[..., : p.shape[-1]] - p, axis=-1)
            diff = np.sqrt(diff**2 + np.sum(c[..., p.shape[-1] :] ** 2, axis=-1))
            size = np.linalg.norm(c, axis=-1)
            if np.all(diff <= rtol * size + 1e-300):
                done = converged = True
        if done:
            break
        prev = coeffs
    assert coeffs is not None
    if not converged:
        return None
    m = coeffs.shape[-1]
    out = (coeffs[..., None, :] @ stacked[..., :m, :])[..., 0, :]  # (..., k, n)
    return xp.matrix_transpose(out * beta[..., None])


def _auto_method(a: Any, v: Any, symmetric: bool) -> str:
    n = a.shape[-1]
    batch = np.broadcast_shapes(tuple(a.shape[:-2]), tuple(v.shape[:-2]))
    n_matrices = int(np.prod(batch, dtype=int))
    if n <= _AUTO_EXPM_MAX:
        return "expm"
    if symmetric and n <= _AUTO_EIGH_MAX and n_matrices == 1:
        return "eigh"
    return "krylov"


def phi_action(
    a: Any,
    v: Any,
    order: int = 1,
    *,
    method: str = "auto",
    symmetric: bool = False,
    rtol: float = 1e-10,
    max_krylov_dim: int = 100,
) -> Any:
    """phi_order(A) V for A (..., n, n) and V (..., n, k); returns (..., n, k).

    numpy or torch arrays (see `agent_envs.arrays`); on torch every strategy is differentiable.

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
    if not (arrays.is_torch(a) or arrays.is_torch(v)):
        a = np.asarray(a, dtype=float)
        v = np.asarray(v, dtype=float)
    if a.shape[-1] != a.shape[-2] or v.shape[-2] != a.shape[-1]:
        raise ValueError(f"shapes do not fit: A {tuple(a.shape)}, V {tuple(v.shape)}")
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
