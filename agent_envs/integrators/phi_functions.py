"""Actions of the phi-functions of a matrix on a block of vectors.

    phi_0(z) = e^z,   phi_1(z) = (e^z - 1)/z,   phi_2(z) = (e^z - 1 - z)/z^2,
    phi_p(A) = int_0^1 e^{(1-s)A} s^{p-1}/(p-1)! ds      (p >= 1)

`phi_action(A, V, order)` returns phi_order(A) V for A of shape (..., n, n) and V of shape
(..., n, k), batched over leading axes. Three strategies, one implementation each:

- ``"expm"``: the exponential of the augmented (n + p k) block matrix
  [[A, V, 0], [0, 0, I], [0, 0, 0]] (Sidje's Expokit trick), via `scipy.linalg.expm` /
  `torch.linalg.matrix_exp` (Pade with scaling and squaring). Dense, O((n+pk)^3); the
  reference for small n.
- ``"eigh"``: A = Q diag(lambda) Q^T for symmetric A, phi_p(A) V = Q phi_p(lambda) Q^T V. On
  torch its gradient comes from the Daleckii-Krein formula with divided differences of phi_p
  (`agent_envs.arrays.symmetric_function_action`), finite at repeated eigenvalues (the frozen
  L(x) at consensus), where torch.linalg.eigh's own backward is not.
- ``"krylov"``: phi_p(A) v ~ |v| Q_m phi_p(H_m) e_1 on an orthonormal basis Q_m of
  span{v, Av, ..., A^{m-1} v}, H_m = Q_m^T A Q_m. Symmetric A: Lanczos (three-term recurrence,
  H_m tridiagonal, stopped by Saad's a posteriori error estimate); otherwise Arnoldi with
  classical Gram-Schmidt run twice, stopped when two successive approximations agree to
  `rtol`. O(m n^2) for a dense A, so the method of choice for large n and for batches; A may
  also be a matrix-free operator (`agent_envs.dynamics.operators.LinearizationOperator`,
  anything with `matvec`, `shape`, `norm_inf`, `scaled`), then only products are used. If it
  has not converged at `max_krylov_dim`, a `RuntimeWarning` is issued and the dense method is
  used. On torch it is differentiated through its final basis.

All three are written once for numpy and torch (`agent_envs.arrays`).

``"auto"`` picks "expm" for n <= 48, and for larger n "krylov" except for a single matrix with
n <= 80 (n <= 128 if it is not symmetric), where "expm" is still cheaper: the crossovers
measured on numpy by benchmarks/bench_integrators.py (table 1) with one BLAS thread.
For a gradient on torch (forward and backward, N = 100 batched over 20 paths),
benchmarks/bench_gradient.py measures "krylov" cheapest, then "eigh", with "expm" far behind
(matrix_exp's backward is a second exponential of a doubled matrix); the README has the numbers.
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np

from agent_envs import arrays

PHI_METHODS = ("auto", "expm", "eigh", "krylov")
# Crossovers of "auto" (measured by benchmarks/bench_integrators.py, one BLAS thread).
_AUTO_EXPM_MAX = 48
_AUTO_EXPM_SINGLE_MAX = 80
_AUTO_EXPM_SINGLE_NONSYMMETRIC_MAX = 128
_TAYLOR_TERMS = 16
# From this size on, Lanczos sums its basis vector by vector rather than stacking it.
_ACCUMULATE_BASIS_MIN_N = 2**14


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


class _RowOperator:
    """What the Krylov recurrences need of A, for a dense (..., n, n) array or an operator.

    An operator is any object with `shape` (..., n, n), ``matvec(V)`` for V (..., n, k) and a
    bound `norm_inf` >= ||A||_inf (e.g. `agent_envs.dynamics.operators.
    LinearizationOperator`); the recurrences act on rows W (..., k, n), so
    ``apply(W) = (A W^T)^T``.
    """

    def __init__(self, a: Any) -> None:
        self.n = a.shape[-1]
        self.batch = tuple(a.shape[:-2])
        self._a = a
        if is_operator(a):
            self._op = a
            self.arrays = ()
        else:
            self._op = None
            self._at = arrays.namespace(a).matrix_transpose(a)
            self.arrays = (a,)

    @property
    def norm_inf(self) -> float:
        """||A||_inf (a bound for an operator), the largest over the batch."""
        if self._op is not None:
            return float(self._op.norm_inf)
        xp = arrays.namespace(self._a)
        return float(arrays.to_numpy(xp.max(xp.sum(xp.abs(self._a), axis=-1))))

    @property
    def max_abs(self) -> Any:
        """max |A_kl| per batch entry (..., 1), or a float bound for an operator."""
        if self._op is not None:
            return self.norm_inf
        xp = arrays.namespace(self._a)
        return xp.max(xp.abs(self._a), axis=(-2, -1))[..., None]

    def apply(self, rows: Any) -> Any:
        if self._op is None:
            return rows @ self._at
        xp = arrays.namespace(rows)
        return xp.matrix_transpose(self._op.matvec(xp.matrix_transpose(rows)))


def is_operator(a: Any) -> bool:
    """Whether `a` is a matrix-free operator (has `matvec`) rather than an array."""
    return hasattr(a, "matvec") and not (arrays.is_torch(a) or isinstance(a, np.ndarray))


def _krylov_action(
    a: _RowOperator,
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
    xp = arrays.namespace(*a.arrays, v)
    n = a.n
    max_dim = min(max_dim, n)
    batch = tuple(np.broadcast_shapes(a.batch, tuple(v.shape[:-2])))
    rows = xp.matrix_transpose(xp.broadcast_to(v, (*batch, *v.shape[-2:])))  # (..., k, n)
    beta = xp.linalg.vector_norm(rows, axis=-1)  # (..., k)
    safe_beta = xp.where(beta > 0, beta, 1.0)
    basis = [rows / safe_beta[..., None]]
    stacked = basis[0][..., None, :]  # (..., k, j + 1, n)
    scale = a.max_abs  # (..., 1) or a float, for the breakdown test
    columns: list[Any] = []
    subdiag: list[Any] = []
    prev = None
    coeffs = None
    converged = False
    for j in range(max_dim):
        w = a.apply(basis[j])  # (..., k, n): A q_j for each column
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


def _lanczos_action(
    a: _RowOperator, v: Any, order: int, rtol: float, max_dim: int, check_every: int = 3
) -> Any | None:
    """Lanczos for symmetric A: phi_p(A) v ~ |v| Q_m phi_p(T_m) e_1, T_m tridiagonal.

    The three-term recurrence b_j q_{j+1} = A q_j - a_j q_j - b_{j-1} q_{j-1}, with the
    coefficient of q_{j-1} taken as the projection <A q_j - a_j q_j, q_{j-1}> (b_{j-1} up to
    rounding) and no reorthogonalization against older vectors: for functions of a matrix with
    a bounded spectrum the approximation converges in spite of the loss of orthogonality
    (Druskin, Greenbaum & Knizhnerman, 1998); against the dense eigh the result agrees to about
    1e-11 relative on the swarm's L(x) and exact Jacobian. Stopped when Saad's error estimate
    b_m |e_m^T phi_p(T_m) e_1| is below rtol |phi_p(T_m) e_1|, checked every `check_every`
    steps from m = 3.5 sqrt(|A|_inf) (about the dimension below which the Krylov approximation of
    the exponential has not converged yet), or at a happy breakdown; None when not converged
    by `max_dim` (also when m reaches n: the basis is then not exact). Differentiable on torch
    (list-built basis, no in-place writes).
    """
    xp = arrays.namespace(*a.arrays, v)
    n = a.n
    max_dim = min(max_dim, n)
    batch = tuple(np.broadcast_shapes(a.batch, tuple(v.shape[:-2])))
    q = xp.matrix_transpose(xp.broadcast_to(v, (*batch, *v.shape[-2:])))  # (..., k, n)
    beta0 = xp.linalg.vector_norm(q, axis=-1)  # (..., k)
    if bool(xp.any(beta0 == 0)):
        q = q / xp.where(beta0 > 0, beta0, 1.0)[..., None]
    else:
        q = q / beta0[..., None]
    basis = [q]
    alphas: list[Any] = []
    betas: list[Any] = []
    norm_inf = a.norm_inf
    first_check = max(2, min(max_dim, math.ceil(3.5 * math.sqrt(norm_inf))))
    tiny = 1e-12 * (norm_inf + 1e-300)
    coeffs = None
    converged = False
    w_prev = None
    for j in range(max_dim):
        w = a.apply(q)
        alpha = xp.vecdot(w, q)
        w = w - alpha[..., None] * q
        if w_prev is not None:
            # the three-term recurrence's b_{j-1} q_{j-1} term, with the coefficient computed
            # as the projection onto q_{j-1} (equal to b_{j-1} up to rounding)
            w = w - xp.vecdot(w, w_prev)[..., None] * w_prev
        b = xp.sqrt(xp.vecdot(w, w))
        alphas.append(alpha)
        m = j + 1
        b_host = arrays.to_numpy(b)
        any_breakdown = float(b_host.min()) <= tiny
        # m == n without convergence: the space is exhausted but, without full
        # reorthogonalization, the basis is not exact; the caller then uses the dense method.
        converged = any_breakdown and bool(np.all(b_host <= tiny))
        done = converged or m == max_dim
        if done or (m >= first_check and (m - first_check) % check_every == 0):
            t = arrays.tridiagonal(xp.stack(alphas, axis=-1), _stack_or_empty(xp, betas, alpha))
            coeffs = _small_phi_e1(t, order, True)  # (..., k, m)
            if not done:
                c = arrays.to_numpy(coeffs)
                est = b_host * np.abs(c[..., -1])
                if np.all(est <= rtol * np.linalg.norm(c, axis=-1) + 1e-300):
                    converged = done = True
        if done:
            break
        if any_breakdown:
            stop = arrays.asarray(b_host <= tiny, like=w) > 0.5
            w = xp.where(stop[..., None], 0.0, w / xp.where(stop, 1.0, b)[..., None])
        else:
            w = w / b[..., None]
        betas.append(b)
        w_prev, q = q, w
        basis.append(q)
    assert coeffs is not None
    if not converged:
        return None
    m = coeffs.shape[-1]
    if n >= _ACCUMULATE_BASIS_MIN_N:
        # large n (matrix-free operators): sum the basis vector by vector instead of stacking
        # a (..., k, m, n) copy of it (measured 0.4 s of a 2 s SERB step at n = 10^6)
        out = coeffs[..., 0:1] * basis[0]
        for j in range(1, m):
            out = out + coeffs[..., j : j + 1] * basis[j]
    else:
        stacked = xp.stack(basis[:m], axis=-2)  # (..., k, m, n)
        out = (coeffs[..., None, :] @ stacked)[..., 0, :]
    return xp.matrix_transpose(out * beta0[..., None])


def _stack_or_empty(xp: Any, items: list[Any], like: Any) -> Any:
    if items:
        return xp.stack(items, axis=-1)
    return xp.zeros((*like.shape, 0), dtype=like.dtype)


def _auto_method(a: Any, v: Any, symmetric: bool) -> str:
    n = a.shape[-1]
    batch = np.broadcast_shapes(tuple(a.shape[:-2]), tuple(v.shape[:-2]))
    single = int(np.prod(batch, dtype=int)) == 1
    if n <= _AUTO_EXPM_MAX:
        return "expm"
    if symmetric:
        return "expm" if single and n <= _AUTO_EXPM_SINGLE_MAX else "krylov"
    if n <= _AUTO_EXPM_SINGLE_MAX or (single and n <= _AUTO_EXPM_SINGLE_NONSYMMETRIC_MAX):
        return "expm"
    return "krylov"


def _krylov(a: Any, v: Any, order: int, symmetric: bool, rtol: float, max_dim: int) -> Any:
    """The Krylov phi-action (Lanczos if symmetric, else Arnoldi); None if not converged."""
    rows = _RowOperator(a)
    if symmetric:
        return _lanczos_action(rows, v, order, rtol, max_dim)
    return _krylov_action(rows, v, order, rtol, max_dim, symmetric)


_MAX_SUBSTEPS = 64
# an operator this small whose Krylov space did not converge is made dense instead
_OPERATOR_DENSE_FALLBACK_MAX = 256


def _substepped_operator_action(
    op: Any, v: Any, order: int, symmetric: bool, rtol: float, max_dim: int
) -> Any:
    """phi_order(A) V for an operator whose Krylov space did not converge, in s substeps.

    y = phi_p(A) v is y(1) for y' = A y + g(t), y(0) = 0, g(t) = v t^(p-1)/(p-1)! (p = 1, 2).
    For g linear in t the step y(t + h) = y + h phi_1(hA)(A y + g(t)) + h^2 phi_2(hA) g' is
    exact, and each action needs only the Krylov space of hA, of norm ||A|| / s. s doubles
    from 2 up to 64; a `RuntimeError` names `max_krylov_dim` if that is still not enough.
    """
    if order > 2:
        raise ValueError(f"a matrix-free phi-action of order {order} > 2 is not implemented")
    s = 2
    while s <= _MAX_SUBSTEPS:
        h = 1.0 / s
        hop = op.scaled(h)
        tail = None
        if order == 2:
            tail = _krylov(hop, v, 2, symmetric, rtol, max_dim)
        y = None
        ok = tail is not None or order == 1
        for j in range(s if ok else 0):
            g = v * (j * h) if order == 2 else v
            rhs = g if y is None else op.matvec(y) + g
            step = _krylov(hop, rhs, 1, symmetric, rtol, max_dim)
            if step is None:
                ok = False
                break
            step = h * step
            if tail is not None:
                step = step + h * h * tail
            y = step if y is None else y + step
        if ok:
            return y
        s *= 2
    raise RuntimeError(
        f"the matrix-free Krylov phi-action did not reach rtol={rtol} within max_krylov_dim="
        f"{max_dim}, even in {_MAX_SUBSTEPS} substeps; raise max_krylov_dim or shorten the step"
    )


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
    A may also be a matrix-free operator (an object with `matvec`, `shape`, `norm_inf`,
    `scaled`, e.g. `agent_envs.dynamics.operators.LinearizationOperator`): then the Krylov
    method is the only one ("auto" chooses it), and if its space does not converge within
    `max_krylov_dim` the action is taken in substeps (`_substepped_operator_action`).

    Args:
        a: the (already time-step scaled) matrix or operator, e.g. tau J.
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
    if is_operator(a):
        return _operator_action(a, v, order, method, symmetric, rtol, max_krylov_dim)
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
    result = _krylov(a, v, order, symmetric, rtol, max_krylov_dim)
    if result is None and symmetric and max_krylov_dim >= a.shape[-1]:
        # Lanczos ran through the whole space (n is small): the dense method is as cheap.
        return _eigh_action(a, v, order)
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


def _operator_action(
    op: Any, v: Any, order: int, method: str, symmetric: bool, rtol: float, max_dim: int
) -> Any:
    """`phi_action` for a matrix-free operator (Krylov only)."""
    if method not in ("auto", "krylov"):
        raise ValueError(
            f"method={method!r} needs a matrix; a matrix-free operator takes 'auto' or 'krylov'"
        )
    if arrays.is_torch(v):
        raise TypeError("a matrix-free operator acts on numpy arrays, got a torch tensor")
    v = np.asarray(v, dtype=float)
    if v.ndim < 2 or v.shape[-2] != op.shape[-1]:
        raise ValueError(f"shapes do not fit: A {tuple(op.shape)}, V {tuple(v.shape)}")
    result = _krylov(op, v, order, symmetric, rtol, max_dim)
    if result is None and op.shape[-1] <= _OPERATOR_DENSE_FALLBACK_MAX and hasattr(op, "dense"):
        # a small operator whose Krylov space ran out: its dense matrix is cheap
        return phi_action(op.dense(), v, order, method="auto", symmetric=symmetric)
    if result is None:
        result = _substepped_operator_action(op, v, order, symmetric, rtol, max_dim)
    return result
