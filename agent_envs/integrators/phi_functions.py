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
  H_m tridiagonal, stopped by an a posteriori error bound where an interval holding the
  spectrum is known (the swarm's frozen L(x)), else by Saad's estimate); otherwise Arnoldi with
  classical Gram-Schmidt run twice, stopped when two successive approximations agree to
  `rtol`. O(m n^2) for a dense A, so the method of choice for large n and for batches. If it
  has not converged at `max_krylov_dim`, a `RuntimeWarning` is issued and the dense method is
  used. On torch it is differentiated through its final basis.

All three are written once for numpy and torch (`agent_envs.arrays`).

``"auto"`` picks "expm" for n <= 48, and for larger n "krylov" except for a single matrix with
n <= 80 (n <= 128 if it is not symmetric), where "expm" is still cheaper: the crossovers
measured on numpy by benchmarks/bench_integrators.py (table 1) with one BLAS thread.
For a gradient on torch (forward and backward, N = 100 batched over 20 paths),
benchmarks/bench_gradient.py measures "krylov" cheapest, then "eigh", with "expm" far behind
(matrix_exp's backward is a second exponential of a doubled matrix); docs/benchmarks.md has
the numbers.
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np

from agent_envs import arrays, native
from agent_envs.dynamics.laplacian import FrozenLaplacian, readonly_view

PHI_METHODS = ("auto", "expm", "eigh", "krylov")
# Crossovers of "auto" (measured by benchmarks/bench_integrators.py, one BLAS thread).
_AUTO_EXPM_MAX = 48
_AUTO_EXPM_SINGLE_MAX = 80
_AUTO_EXPM_SINGLE_NONSYMMETRIC_MAX = 128
_TAYLOR_TERMS = 16
#: from this n on, Lanczos sums its basis vector by vector (no stacked copy)
_ACCUMULATE_BASIS_MIN_N = 2**14

_NO_BOUNDS = readonly_view(np.empty(0))
_NO_EXTRA = readonly_view(np.empty((0, 0, 0)))


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


def _first_unit(m: int, like: Any) -> Any:
    """e_1 as an (m, 1) column in the library and on the device of `like`."""
    e1 = np.zeros((m, 1))
    e1[0, 0] = 1.0
    return arrays.asarray(e1, like=like)


def _small_phi_e1(hess: Any, order: int, symmetric: bool) -> Any:
    """phi_order(H) e_1 for a batch of small (m, m) matrices H; returns (..., m)."""
    xp = arrays.namespace(hess)
    m = hess.shape[-1]
    e1 = _first_unit(m, hess)
    if symmetric:
        # Arnoldi on a symmetric matrix gives a symmetric tridiagonal H (up to round-off).
        return _eigh_action(hess, e1, order)[..., 0]
    e1 = xp.broadcast_to(e1, (*hess.shape[:-2], m, 1))
    return _augmented_expm(hess, e1, order)[..., 0]


def _phi_e1_and_eigh(t: Any, order: int) -> tuple[Any, tuple[Any, Any]]:
    """phi_order(T) e_1 (..., m) for symmetric tridiagonal T (..., m, m), with the
    eigendecomposition it came from: `_small_phi_e1`'s operations (those of
    `arrays.symmetric_function_action`) for a T that needs no gradient, so that a convergence
    check reuses the decomposition instead of taking a second one."""
    e1 = _first_unit(t.shape[-1], t)
    result, eig = arrays.eigh_function_action(t, e1, lambda lam: phi_scalar(lam, order))
    return result[..., 0], eig


def _grad_enabled() -> bool:
    import torch

    return torch.is_grad_enabled()


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

    def member_bounds(
        self, batch: tuple, bounds: Any = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(||A||_inf, width, low) per batch member, float64 arrays of shape `batch`.

        A finite width says that A 1 = 0 and A is symmetric (the frozen L(x)), and bounds the
        spread of spec(A) on 1^perp; the Lanczos iteration then deflates the constant vector
        (`_deflate_constant`). Without that knowledge it is inf. The bounds come
        from `bounds` (the caller's, e.g. `Linearization.scaled_bounds`), else from the
        operator's `krylov_bounds()`, else ||A||_inf of the matrix (one pass over A) or the
        operator's shared `norm_inf`. `low` is the bottom of an interval of that width holding
        spec(A) on 1^perp (`_spectrum_interval`), from a third entry of the bounds (nan where
        unknown or not given).
        """
        if bounds is None and self._op is not None and hasattr(self._op, "krylov_bounds"):
            bounds = self._op.krylov_bounds()
        if bounds is not None:
            return _given_bounds(bounds, batch)
        if self._op is not None:
            norms = float(self._op.norm_inf)
        else:
            xp = arrays.namespace(self._a)
            norms = arrays.to_numpy(xp.max(xp.sum(xp.abs(self._a), axis=-1), axis=-1))
        return _given_bounds((norms, None), batch)

    @property
    def max_abs(self) -> Any:
        """max |A_kl| per batch entry (..., 1), or a float bound for an operator."""
        if self._op is not None and hasattr(self._op, "max_abs"):
            return self._op.max_abs
        if self._op is not None:
            return float(self._op.norm_inf)  # max |A_kl| <= ||A||_inf
        xp = arrays.namespace(self._a)
        return xp.max(xp.abs(self._a), axis=(-2, -1))[..., None]

    def apply(self, rows: Any) -> Any:
        if self._op is None:
            return rows @ self._at
        if hasattr(self._op, "apply_rows"):
            return self._op.apply_rows(rows)
        xp = arrays.namespace(rows)
        return xp.matrix_transpose(self._op.matvec(xp.matrix_transpose(rows)))


def _given_bounds(bounds: Any, batch: tuple) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(||A||_inf, width, low) float64 arrays of shape `batch` from bounds (norms, widths or
    None[, low or None]): width None is inf; low (the bottom of the interval of that width,
    `_spectrum_interval`) is nan where not given or without a width."""
    norms, widths = bounds[0], bounds[1]
    low = bounds[2] if len(bounds) > 2 and bounds[2] is not None else np.nan
    if widths is None:
        widths, low = np.inf, np.nan
    return (
        np.broadcast_to(np.asarray(norms, dtype=np.float64), batch),
        np.broadcast_to(np.asarray(widths, dtype=np.float64), batch),
        np.broadcast_to(np.asarray(low, dtype=np.float64), batch),
    )


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
    """Arnoldi (CGS2) on each column of V; returns (result, converged per member).

    The columns are handled as rows internally: W (..., k, n). The basis vectors are kept in a
    list and stacked, never written in place, so autograd differentiates through the final
    basis and Hessenberg matrix; the convergence test reads detached values. As in
    `_lanczos_action`, each batch member stops at its own dimension (its k columns together),
    so its result does not depend on the rest of the batch.
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
    scale = a.max_abs  # (..., 1) or a float bound, for the breakdown test
    columns: list[Any] = []
    subdiag: list[Any] = []
    prev = None
    done = np.zeros(batch, dtype=bool)
    converged = np.zeros(batch, dtype=bool)
    # stopping dimension -> (members that stopped there, their phi_p(H_m) e_1 (count, k, m))
    stopped: dict[int, tuple[np.ndarray, Any]] = {}
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
        # per member (the k columns of a member stop together): a happy breakdown or the
        # whole space spanned ends it exactly
        broke = np.broadcast_to(arrays.to_numpy(breakdown), (*batch, breakdown.shape[-1]))
        exhausted = ~done & (np.all(broke, axis=-1) | (m == n))
        stops = exhausted | (~done & (m == max_dim))
        if m % check_every and not np.any(stops):
            continue
        coeffs = _small_phi_e1(_hessenberg(columns, subdiag, m), order, symmetric)  # (..., k, m)
        coeffs = xp.broadcast_to(coeffs, (*batch, *coeffs.shape[-2:]))
        passed = np.zeros(batch, dtype=bool)
        if prev is not None and not m % check_every:
            c, p = arrays.to_numpy(coeffs), arrays.to_numpy(prev)
            diff = np.linalg.norm(c[..., : p.shape[-1]] - p, axis=-1)
            diff = np.sqrt(diff**2 + np.sum(c[..., p.shape[-1] :] ** 2, axis=-1))
            size = np.linalg.norm(c, axis=-1)
            passed = ~done & ~stops & np.all(diff <= rtol * size + 1e-300, axis=-1)
        now = stops | passed
        if np.any(now):
            stopped[m] = (now, coeffs[_rows(now, coeffs)])
        converged |= exhausted | passed
        done |= now
        if np.all(done):
            break
        if not m % check_every:  # the regular checks compare with the previous regular one
            prev = coeffs
    return _gather_members(xp, stopped, stacked, beta, batch), converged


def _first_check(norm_inf: np.ndarray, width: np.ndarray) -> np.ndarray:
    """The Krylov dimension m_0 of the first convergence check with Saad's estimate, per member
    (before clipping): min(3.5 sqrt(|A|_inf), 3.5 sqrt(w)), w the width of an interval holding
    spec(A) on the complement of the deflated constant vector (inf where unknown)."""
    return np.minimum(np.ceil(3.5 * np.sqrt(norm_inf)), np.ceil(3.5 * np.sqrt(width)))


def _first_checks(
    norm_inf: np.ndarray, width: np.ndarray, tight: np.ndarray, max_dim: int
) -> np.ndarray:
    """Per member, the dimension of the first check: `FIRST_BOUND_CHECK` where the error bound
    applies (`tight`), else Saad's m_0 (`_first_check`), within [2, max_dim]."""
    first = np.clip(_first_check(norm_inf, width), 2, max_dim)
    return np.where(tight, min(FIRST_BOUND_CHECK, max_dim), first).astype(np.int64)


#: The largest step between two convergence checks of the Lanczos phi-action (`_next_check`).
MAX_CHECK_STEP = 8
#: The dimension of the first check where the error bound applies (`_error_bounds`). On the
#: swarm a check below 4 fails every time: near consensus phi_p(A) v needs 4 dimensions (the
#: error falls by about 10^3 per dimension from 10^-3 at m = 1; of 300 members' phi-actions
#: captured over two paper-setting episodes, 91 % passed at 4 and none at 3), and the spread
#: first steps of an episode need 12-18. A first check at 3 cost 0.6 us per member and step
#: for nothing (a product costs 1 us).
FIRST_BOUND_CHECK = 4
#: From m >= FULL_STEP_FROM n a failed check schedules the next at the dimension the last two
#: checks extrapolate to, below it half way there (`_next_check`): a check at m costs about
#: 0.03 m^2 us and a product with a dense n x n matrix about 1e-4 n^2 us, equal at m = 0.058 n.
FULL_STEP_FROM = 0.05


def _spectrum_interval(
    norm_inf: np.ndarray, width: np.ndarray, low: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """[lo, hi] per member, an interval holding the spectrum that the Lanczos vectors see:
    [low, low + w] within [-|A|_inf, 0] where the constant vector is deflated (finite width w)
    and the bottom `low` <= 0 of spec(A) on 1^perp is known (the frozen c L with c > 0:
    low = -c p_max, its width w = 2 c max_k (p_max - s_k / N), and c L is negative
    semidefinite), with tight = True; else [-|A|_inf, |A|_inf] (|A|_2 <= |A|_inf for a
    symmetric A) and tight = False: there phi_p may grow like e^{|A|_inf} on the interval and
    the bound would be useless, so the iteration keeps Saad's estimate for those members.
    `low` is nan where unknown. Returns (lo, hi, tight)."""
    with np.errstate(invalid="ignore"):
        lo = np.maximum(low, -norm_inf)
        hi = np.minimum(low + width, 0.0)
        tight = np.isfinite(width) & (low <= 0.0) & (lo <= hi)
    return np.where(tight, lo, -norm_inf), np.where(tight, hi, norm_inf), tight


def _error_bounds(lam: Any, first: Any, last: Any, phis: Any, order: int, hi: Any) -> Any:
    """|f(hi)|, f(mu) = sum_j g_j phi[lambda_j, mu], per member and column: the Lanczos error
    bound at dimension m over b_m |v|.

    With A Q_m = Q_m T_m + b_m q_{m+1} e_m^T and T_m = Z diag(lambda) Z^T, the error of
    |v| Q_m phi_p(T_m) e_1 is |v| b_m f(A) q_{m+1} (A symmetric, exact arithmetic), with
    g_j = Z_1j Z_mj and the divided difference phi[l, mu] = (phi_p(l) - phi_p(mu)) / (l - mu):
    the error e(t) of t^p phi_p(t A) v solves e' = A e + r(t) with the residual
    r(t) = |v| b_m t^p e_m^T phi_p(t T_m) e_1 q_{m+1}, so e(1) = int_0^1 e^{(1-t) A} r(t) dt,
    and int_0^1 e^{(1-t) mu} t^p phi_p(t l) dt = exp[mu, l, 0, ..., 0] (p zeros) = phi[l, mu].
    Hence |error| <= |v| b_m max over spec(A) of |f|, spec(A) in [lo, hi]
    (`_spectrum_interval`). And f(mu) = (b_1 ... b_{m-1}) phi_p[lambda_1, ..., lambda_m, mu]
    (sum_j g_j h(lambda_j) is that multiple of the divided difference of any h on the Ritz
    values), positive and increasing in mu since every derivative of phi_p is positive
    (phi_p(z) = int_0^1 e^{(1-s) z} s^{p-1} / (p-1)! ds): the max is f(hi). Where
    |l - hi| <= 1e-6 max(1, |l|, |hi|) the divided difference is phi_p'((l + hi) / 2) =
    phi_p - p phi_{p+1} there. Unlike Saad's estimate b_m |e_m^T phi_p(T_m) e_1| (the residual
    at t = 1), it is not inflated by the stiffness: on the swarm near consensus (spec(A) on
    1^perp about -c p_max) the error is the residual divided by about c p_max.

    lam, first, last (Z's first and last rows), phis = phi_p(lam): (count, k, m) numpy arrays;
    hi (count,). Returns (count, k). The sum runs over j in order, as the compiled
    `native.lanczos._error_bound` does.
    """
    m = lam.shape[-1]
    hi = np.asarray(hi, dtype=np.float64)[:, None]  # (count, 1)
    phi_hi = phi_scalar(hi, order)
    acc = None
    for j in range(m):
        lam_j = lam[..., j]  # (count, k)
        gap = lam_j - hi
        scale = np.maximum(np.maximum(np.abs(lam_j), np.abs(hi)), 1.0)
        close = np.abs(gap) <= 1e-6 * scale
        term = (phis[..., j] - phi_hi) / np.where(close, 1.0, gap)
        if close.any():
            mid = 0.5 * (lam_j + hi)
            slope = phi_scalar(mid, order) - order * phi_scalar(mid, order + 1)
            term = np.where(close, slope, term)
        term = (first[..., j] * last[..., j]) * term
        acc = term if acc is None else acc + term
    return np.abs(acc)


def _next_check(
    m: int,
    ratio: np.ndarray,
    prev_m: np.ndarray,
    prev_ratio: np.ndarray,
    max_step: int,
    n: int,
) -> np.ndarray:
    """The dimension of the next check after a failed one at m, per member: ratio = bound /
    (rtol |phi_p(T_m) e_1|) > 1 there and at the previous check (prev_m, prev_ratio; prev_m 0:
    none). Where the bound falls geometrically or faster (as it does once the iteration
    converges), m + Delta, Delta = ceil(log(ratio) / rate) with the rate log(prev_ratio / ratio)
    / (m - prev_m) of the last two checks, is at or beyond the dimension it passes (where it
    falls slower, the prediction only costs another check, never an early stop). The next
    check is at most `max_step` dimensions on (1 without two checks or a falling bound), and:

    - half way there (at least 1 on) while m < `FULL_STEP_FROM` n: there a check (the QL
      iteration on T_m, O(m^2)) costs less than a product with the dense n x n A (O(n^2)), so
      a check too early costs less than dimensions beyond the one that passes;
    - at m + Delta itself from m >= `FULL_STEP_FROM` n, where a check costs more than a
      product: at n = 100 a check at m = 18 took 9.5 us and a product 1.0 us
      (benchmarks/bench_throughput.py part 2b), and an episode's first steps (m = 12-18)
      took five or six checks half way against three or four now.

    n is the size of A (the matrices the members' checks run on are at most max_dim)."""
    m_arr = np.full(ratio.shape, float(m))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        known = (prev_m > 0) & (prev_ratio > ratio) & (prev_ratio < np.inf) & (ratio < np.inf)
        # (capped at 1e9 as the compiled rule caps it before its integer conversion)
        predicted = np.ceil(
            np.minimum(
                np.log(ratio) * (m_arr - prev_m) / np.log(np.where(known, prev_ratio / ratio, 2.0)),
                1e9,
            )
        )
        predicted = np.where(known, predicted, 1.0)
    ahead = predicted if m >= FULL_STEP_FROM * n else (predicted + 1) // 2
    step = np.where(known, np.clip(ahead, 1, max_step), 1)
    return (m + step).astype(np.int64)


def _check_bounds(
    b: np.ndarray,
    eig: tuple[Any, Any],
    coeffs: Any,
    order: int,
    tight: np.ndarray,
    hi: np.ndarray,
) -> np.ndarray:
    """The error bounds (count, k) of the checked members (all arrays over them): b_m max |f|
    (`_error_bounds`, f at the top `hi` of the spectrum's interval) where `tight`, Saad's
    b_m |e_m^T phi_p(T_m) e_1| elsewhere. eig =
    (eigenvalues, eigenvectors) of their T_m, coeffs = phi_p(T_m) e_1 (numpy). The bound is
    computed on the host, in numpy, from the eigenvalues and Z's first and last rows (a loop of
    small array operations: on a GPU each would be a kernel launch)."""
    bound = b * np.abs(coeffs[..., -1])
    if tight.any():
        lam, vectors = eig
        m = lam.shape[-1]
        lam, first, last = (
            arrays.to_numpy(lam), arrays.to_numpy(vectors[..., 0, :]),
            arrays.to_numpy(vectors[..., m - 1, :]),
        )  # fmt: skip
        if not tight.all():
            lam, first, last = lam[tight], first[tight], last[tight]
        exact = _error_bounds(lam, first, last, phi_scalar(lam, order), order, hi[tight])
        bound[tight] = b[tight] * exact
    return bound


def _limits(coeffs: np.ndarray, rtol: float) -> np.ndarray:
    """rtol |phi_p(T_m) e_1| + 1e-300 per checked member and column (count, k): what each
    column's error bound must not exceed."""
    return rtol * _norms(coeffs) + 1e-300


def _schedule(
    m: int,
    n: int,
    bound: np.ndarray,
    limit: np.ndarray,
    failed: np.ndarray,
    tight: np.ndarray,
    needed: np.ndarray,
    max_step: int,
    next_check: np.ndarray,
    prev_m: np.ndarray,
    prev_ratio: np.ndarray,
) -> None:
    """For the members that `failed` their check at m (a mask of the batch; bound and limit
    (`_limits`) are over the `needed` members): their next check (`_next_check`) and their
    (m, ratio) for the one after, in place. ratio = the largest bound / limit of a failing
    column, as the compiled iteration takes it. Members without the bound (`tight`
    False: Saad's estimate) check every second dimension."""
    legacy = failed & ~tight
    next_check[legacy] = m + 2
    failed = failed & tight
    if not failed.any():
        return
    ratios = np.max(np.where(bound <= limit, 0.0, bound / limit), axis=-1)
    ratio = ratios[failed[needed]]
    next_check[failed] = _next_check(m, ratio, prev_m[failed], prev_ratio[failed], max_step, n)
    prev_m[failed] = m
    prev_ratio[failed] = ratio


def _deflate_constant(xp: Any, q: Any, width: np.ndarray) -> tuple[Any, Any]:
    """Rows q (..., k, n) without their means where a member's width is finite, and the means
    (..., k); (q, None) where no member has a width.

    A finite width says A 1 = 0 (the frozen L(x): its rows sum to 0) and A symmetric, so
    phi_p(A) v = phi_p(0) mean(v) 1 + phi_p(A) (v - mean(v) 1) with the second term in 1^perp,
    where the spectrum is one interval of that width: the Lanczos iteration runs on
    v - mean(v) 1 and needs no dimension for the eigenvalue 0 (`_add_constant` adds the first
    term back)."""
    finite = np.isfinite(width)
    if not finite.any():
        return q, None
    mean = xp.mean(q, axis=-1)  # (..., k)
    if not finite.all():
        mean = mean * arrays.asarray(finite.astype(np.float64), like=mean)[..., None]
    return q - mean[..., None], mean


def _add_constant(result: Any, mean: Any, order: int) -> Any:
    """result (..., n, k) + phi_p(0) mean 1^T (phi_p(0) = 1 / p!) for the deflated constant
    vector."""
    return result if mean is None else result + mean[..., None, :] / math.factorial(order)


def _lanczos_action(
    a: _RowOperator,
    v: Any,
    order: int,
    rtol: float,
    max_dim: int,
    max_step: int = MAX_CHECK_STEP,
    bounds: Any = None,
) -> Any | None:
    """Lanczos for symmetric A: phi_p(A) v ~ |v| Q_m phi_p(T_m) e_1, T_m tridiagonal.

    The three-term recurrence b_j q_{j+1} = A q_j - a_j q_j - b_{j-1} q_{j-1}, with the
    coefficient of q_{j-1} taken as the projection <A q_j - a_j q_j, q_{j-1}> (b_{j-1} up to
    rounding) and no reorthogonalization against older vectors: for functions of a matrix with
    a bounded spectrum the approximation converges in spite of the loss of orthogonality
    (Druskin, Greenbaum & Knizhnerman, 1998); tests/test_phi_functions.py checks it against the
    dense eigh on the swarm's L(x) and exact Jacobian. Stopped at a happy breakdown, or when
    an error bound is below rtol |phi_p(T_m) e_1|:

    - where an interval [lo, hi] holding the spectrum is known (the frozen c L(x), c > 0:
      `_spectrum_interval`), the bound b_m max_[lo, hi] |f| = b_m f(hi) of `_error_bounds`,
      which the error reaches within a few per cent where it matters
      (benchmarks/bench_throughput.py part 2b: 4.83 dimensions per member and step on the
      paper setting, where the smallest that meet rtol are 4.78 and Saad's estimate took
      6.13). Checked at m = `FIRST_BOUND_CHECK`, then
      at the dimension `_next_check` extrapolates from the last two checks;
    - elsewhere Saad's estimate b_m |e_m^T phi_p(T_m) e_1|, checked every second step from
      m_0 = min(3.5 sqrt(|A|_inf), 3.5 sqrt(w)) (about the dimension below which the Krylov
      approximation of the exponential has not converged yet: 3.5 sqrt of the width of an
      interval holding the spectrum, by Hochbruck & Lubich 1997). It is the residual at t = 1,
      which overstates the error of a stiff A by about its smallest |eigenvalue| (40 on the
      swarm near consensus).

    w is known for the frozen L(x) (A 1 = 0, A symmetric; `_RowOperator.member_bounds`): it
    bounds the spectrum on 1^perp, and the iteration runs on v - mean(v) 1, the mean's part
    phi_p(0) mean(v) 1 added at the end (`_deflate_constant`): the eigenvalue 0 then costs no
    Krylov dimension (one per step near consensus, where L is about -p_max on 1^perp). `max_step`
    caps the step between two checks. A member that reaches `max_dim`
    first (also when m reaches n: the basis is then not exact) counts as not converged.
    Returns (result, converged per batch member). Differentiable on torch
    (list-built basis, no in-place writes to the basis).

    Batch members (the leading axes; the k columns of one member stop together) are decided
    one by one: each has its own |A|_inf, first check, breakdown tolerance and stopping
    dimension m_i, and its result is Q_{m_i} phi_p(T_{m_i}) e_1 computed on its own. So a
    member's result does not depend on what else is in the batch (the native vector env relies
    on this to reproduce the single env exactly); the recurrence runs until the last member
    stops.
    """
    xp = arrays.namespace(*a.arrays, v)
    n = a.n
    max_dim = min(max_dim, n)
    batch = tuple(np.broadcast_shapes(a.batch, tuple(v.shape[:-2])))
    if math.prod(batch) == 0:  # no member: nothing to iterate (the dense methods agree)
        return xp.zeros((*batch, *v.shape[-2:]), dtype=v.dtype), np.ones(batch, dtype=bool)
    q = xp.matrix_transpose(xp.broadcast_to(v, (*batch, *v.shape[-2:])))  # (..., k, n)
    # per member: |A|_inf, the first check and the breakdown tolerance
    norm_inf, width, low = a.member_bounds(batch, bounds)
    q, mean = _deflate_constant(xp, q, width)
    beta0 = xp.linalg.vector_norm(q, axis=-1)  # (..., k)
    if bool(xp.any(beta0 == 0)):
        q = q / xp.where(beta0 > 0, beta0, 1.0)[..., None]
    else:
        q = q / beta0[..., None]
    basis = [q]
    alphas: list[Any] = []
    betas: list[Any] = []
    _, hi, tight = _spectrum_interval(norm_inf, width, low)
    next_check = _first_checks(norm_inf, width, tight, max_dim)
    prev_m = np.zeros(batch)
    prev_ratio = np.zeros(batch)
    tiny = 1e-12 * (norm_inf + 1e-300)
    done = np.zeros(batch, dtype=bool)
    converged = np.zeros(batch, dtype=bool)
    # stopping dimension -> (members that stopped there, their phi_p(T_m) e_1 (count, k, m))
    stopped: dict[int, tuple[np.ndarray, Any]] = {}
    w_prev = None
    for j in range(max_dim):
        w = a.apply(q)
        alpha = xp.vecdot(w, q)
        w = w - alpha[..., None] * q
        if w_prev is not None:
            # the three-term recurrence's b_{j-1} q_{j-1} term, with the coefficient computed
            # as the projection onto q_{j-1} (equal to b_{j-1} up to rounding)
            w = w - xp.vecdot(w, w_prev)[..., None] * w_prev
        b = xp.linalg.vector_norm(w, axis=-1)  # its gradient is 0 at 0 (sqrt is not)
        alphas.append(alpha)
        m = j + 1
        b_host = np.broadcast_to(arrays.to_numpy(b), (*batch, b.shape[-1]))
        small = b_host <= tiny[..., None]
        # m == n without convergence: the space is exhausted but, without full
        # reorthogonalization, the basis is not exact; the caller then uses the dense method.
        breakdown = ~done & np.all(small, axis=-1)
        stops = breakdown | (~done & (m == max_dim))
        check = ~done & ~stops & (next_check == m)
        needed = stops | check
        if np.any(needed):
            t = arrays.tridiagonal(xp.stack(alphas, axis=-1), _stack_or_empty(xp, betas, alpha))
            t = xp.broadcast_to(t, (*batch, *t.shape[-3:]))
            t = t[_rows(needed, t)]
            if arrays.is_torch(t) and t.requires_grad and _grad_enabled():
                coeffs = _small_phi_e1(t, order, True)  # (count, k, m), differentiable
                eig = None
            else:
                coeffs, eig = _phi_e1_and_eigh(t, order)
            passed = np.zeros(batch, dtype=bool)
            if np.any(check):
                c = arrays.to_numpy(coeffs)
                if eig is None and np.any(tight[needed]):
                    # the bound reads a decomposition of its own (no autograd through a check)
                    eig = arrays.eigh(t.detach())
                bound = _check_bounds(b_host[needed], eig, c, order, tight[needed], hi[needed])
                limit = _limits(c, rtol)
                passed[needed] = np.all(bound <= limit, axis=-1) & check[needed]
                _schedule(m, n, bound, limit, check & ~passed, tight, needed, max_step,
                          next_check, prev_m, prev_ratio)  # fmt: skip
            now = stops | passed
            if np.any(now):
                stopped[m] = (now, coeffs[_rows(now[needed], coeffs)])
            converged |= breakdown | passed
            done |= now
        if np.all(done):
            break
        if np.any(small):
            stop = arrays.asarray(small, like=w) > 0.5
            w = xp.where(stop[..., None], 0.0, w / xp.where(stop, 1.0, b)[..., None])
        else:
            w = w / b[..., None]
        betas.append(b)
        w_prev, q = q, w
        basis.append(q)
    if n >= _ACCUMULATE_BASIS_MIN_N and len(stopped) == 1:
        # large n (matrix-free operators), every member stopped at one m: sum the basis vector
        # by vector instead of stacking a (..., k, m, n) copy of it (measured 0.4 s of a 2 s
        # SERB step at n = 10^6)
        ((m, (_, coeffs)),) = stopped.items()
        coeffs = xp.reshape(coeffs, (*batch, *coeffs.shape[-2:]))
        out = coeffs[..., 0:1] * basis[0]
        for j in range(1, m):
            out = out + coeffs[..., j : j + 1] * basis[j]
        return _add_constant(xp.matrix_transpose(out * beta0[..., None]), mean, order), converged
    stacked = xp.stack(basis[: max(stopped)], axis=-2)
    result = _gather_members(xp, stopped, stacked, beta0, batch)
    return _add_constant(result, mean, order), converged


def _norms(w: np.ndarray) -> np.ndarray:
    """||w|| along the last axis: numpy's vector_norm arithmetic (sqrt of the pairwise sum of
    w * w) without its argument handling."""
    return np.sqrt(np.add.reduce(w * w, axis=-1))


def _lanczos_numpy(
    a: _RowOperator,
    v: np.ndarray,
    order: int,
    rtol: float,
    max_dim: int,
    max_step: int = MAX_CHECK_STEP,
    bounds: Any = None,
) -> tuple[np.ndarray, np.ndarray]:
    """`_lanczos_action` for numpy arrays with the per-step overhead taken out.

    The same recurrence, per-member bounds, checks, stopping dimensions and arithmetic (each
    floating-point operation the same, in the same order: tests/test_phi_functions.py checks the
    results are equal bit for bit), written with in-place numpy operations: no array-namespace
    dispatch, no broadcast copies, one host-side test per step. `_lanczos_action` stays the
    reference and the torch (differentiable) path. Returns (result, converged per member).
    """
    xp = arrays.namespace(v)  # numpy's standard namespace (numpy 1.x: array-api-compat)
    n = a.n
    max_dim = min(max_dim, n)
    batch = tuple(np.broadcast_shapes(a.batch, tuple(v.shape[:-2])))
    if math.prod(batch) == 0:  # as `_lanczos_action`
        return np.zeros((*batch, *v.shape[-2:])), np.ones(batch, dtype=bool)
    q = np.swapaxes(np.broadcast_to(v, (*batch, *v.shape[-2:])), -1, -2)  # (..., k, n)
    norm_inf, width, low = a.member_bounds(batch, bounds)
    q, mean = _deflate_constant(xp, q, width)
    beta0 = _norms(q)  # (..., k)
    if (beta0 == 0).any():
        q = q / np.where(beta0 > 0, beta0, 1.0)[..., None]
    else:
        q = q / beta0[..., None]
    basis = [q]
    alphas: list[np.ndarray] = []
    betas: list[np.ndarray] = []
    _, hi, tight = _spectrum_interval(norm_inf, width, low)
    next_check = _first_checks(norm_inf, width, tight, max_dim)
    earliest = int(next_check.min())
    prev_m = np.zeros(batch)
    prev_ratio = np.zeros(batch)
    tiny = (1e-12 * (norm_inf + 1e-300))[..., None]
    done = np.zeros(batch, dtype=bool)
    converged = np.zeros(batch, dtype=bool)
    stopped: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    e1 = None
    w_prev = None
    for j in range(max_dim):
        w = a.apply(q)
        alpha = xp.vecdot(w, q)
        w -= alpha[..., None] * q
        if w_prev is not None:
            w -= xp.vecdot(w, w_prev)[..., None] * w_prev
        b = _norms(w)
        alphas.append(alpha)
        m = j + 1
        small = b <= tiny
        any_small = bool(small.any())
        if any_small or m == max_dim or m >= earliest:
            breakdown = ~done & small.all(axis=-1)
            stops = breakdown | (~done & (m == max_dim))
            check = ~done & ~stops & (next_check == m)
            needed = stops | check
            if needed.any():
                t = arrays.tridiagonal(np.stack(alphas, axis=-1), _stack_or_empty(np, betas, alpha))
                t = t[needed]  # (count, k, m, m)
                if e1 is None or e1.shape[0] != m:
                    e1 = np.zeros((m, 1))
                    e1[0, 0] = 1.0
                lam, vectors = np.linalg.eigh(t)
                coef = np.swapaxes(vectors, -1, -2) @ e1
                coeffs = (vectors @ (phi_scalar(lam, order)[..., None] * coef))[..., 0]
                passed = np.zeros(batch, dtype=bool)
                if check.any():
                    bound = _check_bounds(b[needed], (lam, vectors), coeffs, order,
                                          tight[needed], hi[needed])  # fmt: skip
                    limit = _limits(coeffs, rtol)
                    passed[needed] = np.all(bound <= limit, axis=-1) & check[needed]
                    _schedule(m, n, bound, limit, check & ~passed, tight, needed, max_step,
                              next_check, prev_m, prev_ratio)  # fmt: skip
                now = stops | passed
                if now.any():
                    stopped[m] = (now, coeffs[now[needed]])
                converged |= breakdown | passed
                done |= now
            if done.all():
                break
        if any_small:
            w = np.where(small[..., None], 0.0, w / np.where(small, 1.0, b)[..., None])
        else:
            w /= b[..., None]
        betas.append(b)
        w_prev, q = q, w
        basis.append(q)
    if n >= _ACCUMULATE_BASIS_MIN_N and len(stopped) == 1:
        # as in `_lanczos_action`: sum the basis vector by vector (no stacked copy)
        ((m, (_, coeffs)),) = stopped.items()
        coeffs = np.reshape(coeffs, (*batch, *coeffs.shape[-2:]))
        out = coeffs[..., 0:1] * basis[0]
        for j in range(1, m):
            out = out + coeffs[..., j : j + 1] * basis[j]
        return _add_constant(np.swapaxes(out * beta0[..., None], -1, -2), mean, order), converged
    stacked = np.stack(basis[: max(stopped)], axis=-2)
    result = _gather_members(np, stopped, stacked, beta0, batch)
    return _add_constant(result, mean, order), converged


def _gather_members(
    xp: Any, stopped: dict[int, tuple[np.ndarray, Any]], stacked: Any, beta: Any, batch: tuple
) -> Any:
    """|v| Q_{m_i} c_i for every batch member i, each computed with its own stopping dimension.

    `stopped` maps a Krylov dimension m to (the members that stopped there, their coefficients
    (count, k, m)); `stacked` (..., k, >= max m, n) is the basis, `beta` (..., k) the norms of
    the starting vectors. Returns (..., n, k).
    """
    if len(stopped) == 1:  # every member stopped at the same m: no gathering needed
        ((m, (_, coeffs)),) = stopped.items()
        coeffs = xp.reshape(coeffs, (*batch, *coeffs.shape[-2:]))
        out = (coeffs[..., None, :] @ stacked[..., :m, :])[..., 0, :]
        return xp.matrix_transpose(out * beta[..., None])
    k, n = stacked.shape[-3], stacked.shape[-1]
    out = xp.zeros((*batch, k, n), dtype=stacked.dtype)
    if arrays.is_torch(out):
        out = out.to(stacked.device)
    for m, (members, coeffs) in stopped.items():
        basis = xp.broadcast_to(stacked[..., :m, :], (*batch, k, m, n))
        out[_rows(members, out)] = (coeffs[..., None, :] @ basis[_rows(members, basis)])[..., 0, :]
    return xp.matrix_transpose(out * beta[..., None])


def _rows(mask: np.ndarray, like: Any) -> Any:
    """A boolean mask over the leading (batch) axes, usable as an index of `like`."""
    if arrays.is_torch(like):
        import torch

        return torch.as_tensor(mask, device=like.device)
    return mask


def _stack_or_empty(xp: Any, items: list[Any], like: Any) -> Any:
    if items:
        return xp.stack(items, axis=-1)
    return xp.zeros((*like.shape, 0), dtype=like.dtype)


def auto_phi_method(size: int, n_matrices: int, symmetric: bool) -> str:
    """The strategy ``method="auto"`` uses for `n_matrices` matrices of shape (size, size).

    Public so that a caller that batches several independent problems together (the native
    vector env stacks its envs on a leading axis) can fix the strategy each problem would get
    on its own, and so compute each one exactly as an unbatched call would.
    """
    single = n_matrices == 1
    if size <= _AUTO_EXPM_MAX:
        return "expm"
    if symmetric:
        return "expm" if single and size <= _AUTO_EXPM_SINGLE_MAX else "krylov"
    if size <= _AUTO_EXPM_SINGLE_MAX or (single and size <= _AUTO_EXPM_SINGLE_NONSYMMETRIC_MAX):
        return "expm"
    return "krylov"


def _auto_method(a: Any, v: Any, symmetric: bool) -> str:
    a_batch, v_batch = tuple(a.shape[:-2]), tuple(v.shape[:-2])
    # (np.broadcast_shapes and np.prod of a tuple: 10 us per SERB env step)
    batch = a_batch if a_batch == v_batch else np.broadcast_shapes(a_batch, v_batch)
    return auto_phi_method(a.shape[-1], math.prod(batch), symmetric)


def load_compiled() -> bool:
    """Whether the compiled Lanczos (`agent_envs.native.lanczos`, needs numba) serves the numpy
    frozen L(x): ``native.available("lanczos")``, loaded on the first call (the exponential
    integrators' constructors ask, so that the load falls there and not in a step). Without
    numba, or with the environment variable ``AGENT_ENVS_NUMBA=0``, False: the numpy Lanczos
    runs."""
    return native.available("lanczos")


def use_compiled(enabled: bool) -> bool:
    """Switch the compiled Lanczos and the compiled kernel pass on (when numba is installed) or
    off for this process (``native.use`` of "kernel" and "lanczos"); returns whether the
    Lanczos was in use before. For comparisons in one process (benchmarks, tests)."""
    native.use("kernel", enabled)
    return native.use("lanczos", enabled)


def load_compiled_threads(threads: int) -> bool:
    """Whether the compiled Lanczos is available and the compiled kernel pass and the fused
    exponential Rosenbrock-Euler step (`frozen_advance`) can run on `threads` threads
    (``native.load_compiled_threads``, which loads their threaded drivers)."""
    return native.available("lanczos") and native.load_compiled_threads(threads)


def _compiled_frozen_lanczos(
    a: FrozenLaplacian,
    v: np.ndarray,
    order: int,
    rtol: float,
    max_dim: int,
    bounds: Any,
    add_product: tuple[np.ndarray, float] | None = None,
) -> tuple[np.ndarray, np.ndarray] | None:
    """`_lanczos_numpy` on c L(x) by the compiled kernel: (result, converged per member), or
    None where it does not apply (V, or W of `add_product`, batched beyond P). With
    `add_product` = (W, e) it acts on V + e (c L) W, the product taken in the compiled pass."""
    matrix, row_sums = a.parts()
    n, k = a.n, v.shape[-1]
    batch = tuple(matrix.shape[:-2])
    full = (*batch, n, k)
    shapes = [tuple(v.shape)]
    if add_product is not None:
        if tuple(add_product[0].shape[-2:]) != (n, k):
            return None
        shapes.append(tuple(add_product[0].shape))
    # (np.broadcast_shapes only where a shape differs: the integrators' V and W are P's)
    if any(shape != full for shape in shapes) and np.broadcast_shapes(full, *shapes) != full:
        return None
    members = math.prod(batch)
    extra, extra_scale = _NO_EXTRA, 0.0
    if add_product is not None:
        extra, extra_scale = _as_members(add_product[0], full), float(add_product[1])
    if bounds is None:
        norms = widths = lows = _NO_BOUNDS
    else:  # as `_RowOperator.member_bounds` reads them
        norms, widths, lows = (
            readonly_view(np.ascontiguousarray(part).reshape(members))
            for part in _given_bounds(bounds, batch)
        )
    peak = a.peak if a.peak is not None and a.symmetric else -1.0
    out = np.empty((members, n, k))
    converged = np.empty(members, dtype=bool)
    native.loaded("lanczos").frozen_lanczos(
        readonly_view(matrix.reshape(members, n, n)),
        readonly_view(_contiguous(row_sums).reshape(members, n)), a.scale, _as_members(v, full),
        order, rtol, max_dim, MAX_CHECK_STEP, norms, widths, lows, peak, out, converged, extra,
        extra_scale,
    )  # fmt: skip
    return out.reshape(full), converged.reshape(batch)


def _as_members(arr: np.ndarray, full: tuple[int, ...]) -> np.ndarray:
    """arr broadcast to `full` = (*batch, n, k) as a read-only float64 C-contiguous
    (members, n, k) array for the compiled calls: arr itself when it already is one (a single
    env's read-only state), a read-only view of it reshaped when it is C-contiguous float64 of
    that shape (the integrators' other arrays), a copy otherwise."""
    if type(arr) is np.ndarray and arr.shape == full and arr.dtype == np.float64:
        if len(full) == 3 and not arr.flags.writeable and arr.flags.c_contiguous:
            return arr
    else:
        arr = np.broadcast_to(np.asarray(arr, dtype=np.float64), full)
    return readonly_view(_contiguous(arr).reshape(-1, *full[-2:]))


def frozen_advance_applies(a: Any, rhs: Any, x: Any, noise: Any, method: str) -> bool:
    """Whether `frozen_advance` serves this exponential Rosenbrock-Euler step: A the symmetric
    kernel's frozen L(x) over a current workspace, the compiled Lanczos loaded, rhs, x and
    noise float64 numpy arrays of one shape batched exactly like P, and the phi-action's
    method "krylov" (or "auto" choosing it, as `phi_action` would). (Plain comparisons in the
    order of their cost: the check runs every env step.)"""
    if (
        type(x) is not np.ndarray
        or type(rhs) is not np.ndarray
        or type(noise) is not np.ndarray
        or method not in ("auto", "krylov")
        or not isinstance(a, FrozenLaplacian)
        or not a.symmetric
        or a.peak is None
        or x.dtype != np.float64
        or rhs.dtype != np.float64
        or noise.dtype != np.float64
    ):
        return False
    shape = x.shape
    if (
        rhs.shape != shape
        or noise.shape != shape
        or shape[:-1] != a.shape[:-1]
        or not a.current
        or not native.available("lanczos")
    ):
        return False
    return method == "krylov" or auto_phi_method(a.n, math.prod(shape[:-2]), True) == "krylov"


def frozen_advance(
    a: FrozenLaplacian,
    rhs: np.ndarray,
    x: np.ndarray,
    dt: float,
    noise: np.ndarray,
    extra_scale: float | None,
    p_next: np.ndarray,
    weight: float,
    alpha2: float,
    threads: int = 1,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """x + dt phi_1(dt A) (rhs + e dt A noise) + noise, and the kernel pass at that state, by
    the compiled `frozen_advance` (where `frozen_advance_applies`): (x_next, s_next, drift_next)
    with P(x_next) written into `p_next` (the workspace buffer A's P views), or None if some
    member's Lanczos did not converge within 100 dimensions (its P is P(x) still, the others'
    P(x_next): the caller discards the workspace and takes the general path).

    `threads` > 1 (`native.load_compiled_threads` must have answered True for it): the members in
    that many spans on numba's threads (`frozen_advance_threads`), the same bits.

    e = `extra_scale` (1 / dt for SERB's sigma A dW with sigma != 0; None: no product, ERB).
    The phi-action is `phi_action`'s on dt A with rtol = 1e-10 and its default
    max_krylov_dim; x_next is the integrators' x + dt phi + noise, the same operations in the
    same order, so the result equals the general path's bit for bit.
    """
    _, row_sums = a.parts()  # (parts() refuses an operator whose P was overwritten)
    *batch, n, d = full = tuple(x.shape)
    members = math.prod(batch)
    noise_members = _as_members(noise, full)
    extra = _NO_EXTRA if extra_scale is None else noise_members
    out = np.empty((members, n, d))
    x_next = np.empty((members, n, d))
    s_next = np.empty((members, n))
    drift_next = np.empty((members, n, d))
    args = (
        p_next.reshape(members, n, n),
        readonly_view(_contiguous(row_sums).reshape(members, n)),
        a.scale * float(dt), _as_members(rhs, full), 1e-10, 100, MAX_CHECK_STEP, a.peak, out,
        extra, 0.0 if extra_scale is None else float(extra_scale), _as_members(x, full),
        float(dt), noise_members, float(weight), float(alpha2), x_next, s_next, drift_next,
    )  # fmt: skip
    lanczos = native.loaded("lanczos")
    failed = native.call_on_threads(
        lanczos.frozen_advance, lanczos.frozen_advance_threads, args, members, threads
    )
    if failed:
        return None
    return x_next.reshape(x.shape), s_next, drift_next


def _contiguous(a: np.ndarray) -> np.ndarray:
    """a itself when C-contiguous (np.ascontiguousarray's call costs more than this check)."""
    return a if a.flags.c_contiguous else np.ascontiguousarray(a)


def _krylov(
    a: Any,
    v: Any,
    order: int,
    symmetric: bool,
    rtol: float,
    max_dim: int,
    bounds: Any = None,
    add_product: Any = None,
) -> Any:
    """The Krylov phi-action (Lanczos if symmetric, else Arnoldi) on a matrix or an operator:
    (result, converged per batch member), of V + e A W for `add_product` = (W, e)."""
    if (
        symmetric
        and isinstance(a, FrozenLaplacian)
        and isinstance(v, np.ndarray)
        and native.available("lanczos")
    ):
        found = _compiled_frozen_lanczos(a, v, order, rtol, max_dim, bounds, add_product)
        if found is not None:
            return found
    if add_product is not None:
        v = _with_product(a, v, add_product)
    rows = _RowOperator(a)
    if symmetric and not (arrays.is_torch(v) or arrays.is_torch(a)):
        return _lanczos_numpy(rows, v, order, rtol, max_dim, bounds=bounds)
    if symmetric:
        return _lanczos_action(rows, v, order, rtol, max_dim, bounds=bounds)
    return _krylov_action(rows, v, order, rtol, max_dim, symmetric)


def _with_product(a: Any, v: Any, add_product: tuple[Any, float]) -> Any:
    """V + e A W for `add_product` = (W, e)."""
    w, e = add_product
    return v + e * (a @ w)


def _krylov_or_none(
    a: Any, v: Any, order: int, symmetric: bool, rtol: float, max_dim: int
) -> Any | None:
    """`_krylov`'s result when every member converged, else None."""
    result, converged = _krylov(a, v, order, symmetric, rtol, max_dim)
    return result if np.all(converged) else None


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
            tail = _krylov_or_none(hop, v, 2, symmetric, rtol, max_dim)
        y = None
        ok = tail is not None or order == 1
        for j in range(s if ok else 0):
            g = v * (j * h) if order == 2 else v
            rhs = g if y is None else op.matvec(y) + g
            step = _krylov_or_none(hop, rhs, 1, symmetric, rtol, max_dim)
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
    bounds: Any = None,
    add_product: tuple[Any, float] | None = None,
) -> Any:
    """phi_order(A) V for A (..., n, n) and V (..., n, k); returns (..., n, k).

    numpy or torch arrays (see `agent_envs.arrays`); on torch every strategy is differentiable.
    A may also be a matrix-free operator (an object with `matvec`, `shape`, `norm_inf`,
    `scaled`, e.g. `agent_envs.dynamics.operators.LinearizationOperator`): then the Krylov
    method is the only one ("auto" chooses it), and if its space does not converge within
    `max_krylov_dim` the action is taken in substeps (`_substepped_operator_action`). A
    dense-backed operator (one with `dense()` and `apply_rows`, e.g.
    `agent_envs.dynamics.laplacian.FrozenLaplacian`) is treated as the matrix it stands for:
    "auto" picks as for that matrix, "expm"/"eigh" and the fallback use `dense()`.

    Args:
        a: the (already time-step scaled) matrix, e.g. tau J.
        v: the block of vectors.
        order: p >= 1.
        method: "auto", "expm", "eigh" (requires `symmetric=True`) or "krylov".
        symmetric: whether A is symmetric (enables "eigh").
        rtol: relative tolerance of the Krylov approximation.
        max_krylov_dim: largest Krylov dimension tried.
        bounds: (||A||_inf, width or None[, low or None]) per batch member, numpy arrays (low
            a float or an array), when the caller knows them (`Linearization.scaled_bounds`);
            the Lanczos iteration reads them instead of a pass over A (see `_lanczos_action`).
            A width may only be given for a symmetric A with A 1 = 0 (the frozen L(x)): it
            bounds spec(A) on 1^perp, and Lanczos deflates the constant vector. low, with a
            width, promises that spec(A) on 1^perp lies in [low, low + width] with low <= 0
            and A negative semidefinite (the frozen c L(x), c > 0: low = -c p_max): the
            iteration then stops by its error bound (`_error_bounds`), else by Saad's
            estimate. Without `bounds` a `FrozenLaplacian` gives all three itself.
        add_product: (W, e) with W shaped like V: phi_order(A) (V + e A W) instead, e.g.
            SERB's F + sigma J dW with A = tau J and e = 1 / tau. On the compiled frozen L(x)
            the product A W is taken in the same pass over each member's matrix as its
            Lanczos iteration; elsewhere it is taken first.
    """
    if order < 1:
        raise ValueError(f"order must be >= 1, got {order}")
    if isinstance(max_krylov_dim, bool) or not isinstance(max_krylov_dim, (int, np.integer)):
        raise TypeError(f"max_krylov_dim must be an int >= 1, got {max_krylov_dim!r}")
    if max_krylov_dim < 1:
        raise ValueError(f"max_krylov_dim must be >= 1, got {max_krylov_dim}")
    if method not in PHI_METHODS:
        raise ValueError(f"method must be one of {PHI_METHODS}, got {method!r}")
    dense_backed = is_operator(a) and hasattr(a, "dense") and hasattr(a, "apply_rows")
    if is_operator(a) and not dense_backed:
        if add_product is not None:
            v = _with_product(a, v, add_product)
        return _operator_action(a, v, order, method, symmetric, rtol, max_krylov_dim)
    if dense_backed:
        if arrays.is_torch(v):
            raise TypeError("a dense-backed operator acts on numpy arrays, got a torch tensor")
        v = np.asarray(v, dtype=float)
    elif not (arrays.is_torch(a) or arrays.is_torch(v)):
        a = np.asarray(a, dtype=float)
        v = np.asarray(v, dtype=float)
    if a.shape[-1] != a.shape[-2] or v.shape[-2] != a.shape[-1]:
        raise ValueError(f"shapes do not fit: A {tuple(a.shape)}, V {tuple(v.shape)}")
    if method == "auto":
        method = _auto_method(a, v, symmetric)
    if add_product is not None and method != "krylov":
        v, add_product = _with_product(a, v, add_product), None
    if dense_backed and method != "krylov":
        a = a.dense()
    if method == "eigh":
        if not symmetric:
            raise ValueError("method='eigh' needs a symmetric matrix (symmetric=True)")
        return _eigh_action(a, v, order)
    if method == "expm":
        return _augmented_expm(a, v, order)
    result, converged = _krylov(a, v, order, symmetric, rtol, max_krylov_dim, bounds, add_product)
    if converged.all():
        return result
    if add_product is not None:
        v = _with_product(a, v, add_product)
    if dense_backed:
        a = a.dense()
    # Only the members that did not converge get the dense method: the others keep their
    # Krylov values, so a batch member's result never depends on the other members.
    if not (symmetric and max_krylov_dim >= a.shape[-1]):
        # (when Lanczos ran through the whole space, n is small and the dense method as cheap)
        warnings.warn(
            f"Krylov phi-action did not reach rtol={rtol} within max_krylov_dim="
            f"{max_krylov_dim} (matrix size {a.shape[-1]}) for {int(np.sum(~converged))} of "
            f"{converged.size} matrices; falling back to dense "
            f"'{'eigh' if symmetric else 'expm'}' for those",
            RuntimeWarning,
            stacklevel=2,
        )
    dense = _eigh_action(a, v, order) if symmetric else _augmented_expm(a, v, order)
    if converged.ndim == 0 or not np.any(converged):
        return dense
    xp = arrays.namespace(result)
    keep = arrays.asarray(converged, like=result) > 0.5
    return xp.where(keep[..., None, None], result, dense)


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
    result = _krylov_or_none(op, v, order, symmetric, rtol, max_dim)
    if result is None and op.shape[-1] <= _OPERATOR_DENSE_FALLBACK_MAX and hasattr(op, "dense"):
        # a small operator whose Krylov space ran out: its dense matrix is cheap
        return phi_action(op.dense(), v, order, method="auto", symmetric=symmetric)
    if result is None:
        result = _substepped_operator_action(op, v, order, symmetric, rtol, max_dim)
    return result
