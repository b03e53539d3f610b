"""The Lanczos phi-action of the frozen L(x), compiled with numba (optional).

This module imports numba; the package imports it only through `agent_envs.native.loader`
(paths "lanczos" and "fused"), so the package works without numba (the numpy path
`agent_envs.integrators.phi_functions._lanczos_numpy` and the Array-API reference
`_lanczos_action` stay, the latter for torch and autograd).

`frozen_lanczos` computes phi_p(c L) V for c L = c (P - diag(s)) / N given as the kernel matrix
P (B, N, N) and its row sums s (B, N) (`agent_envs.dynamics.laplacian.FrozenLaplacian`), for V
(B, N, k). It is `_lanczos_action` written as loops, one batch member at a time: the same
recurrence (b_j q_{j+1} = A q_j - a_j q_j - <., q_{j-1}> q_{j-1}, no reorthogonalization), the
same per-member bounds (||c L||_inf and the width of spec(c L) on 1^perp, from s and P_kk as
`agent_envs.dynamics.laplacian.krylov_bounds` has them), the same deflation of the constant
vector (with a finite width: Lanczos on v - mean(v) 1, phi_p(0) mean(v) 1 added at the end),
the same breakdown tolerance, error bound (`_error_bound`, or Saad's estimate where no interval
holding the spectrum is known), checks and stopping dimension, and phi_p(T_m) e_1 from the
eigendecomposition of T_m. Only the order of the
floating-point sums (loops instead of BLAS and numpy's pairwise sums, fused multiply-adds in
the product) and the eigensolver differ, so each phi-action agrees with the reference to
round-off (tests/test_compiled_lanczos.py: 1e-12). The eigensolver is the implicit QL
iteration for tridiagonal matrices (EISPACK's tql2; numpy's `eigh` calls LAPACK's syevd: both
backward stable), allocation-free, and it does not form the eigenvector matrix Z: it records
its plane rotations and carries only Z's first and last rows, all that the error bound reads
(O(m^2) per check instead of O(m^3): a check at m = 25, as the first steps of an episode from a
spread start need, cost 40 us with the full Z and 20 us without; `math.sqrt` of the sum of
squares replaces `math.hypot` in the rotations, whose entries are bounded by ||c L||);
Z phi(Lambda) Z^T e_1 is formed from the rotations once, at the accepted dimension.

One member at a time keeps its 80 KB kernel matrix (N = 100) in cache for all its Lanczos
products, and the product reads only P's lower triangle (`_products`:
`agent_envs.native.kernel.lower_products`, which the kernel pass uses too for d > 1;
P symmetric, each entry used for its row and its column; the kernel pass writes only that
triangle). With k > 1 columns (d > 1) the k Lanczos iterations run in lockstep, so their
products at each dimension go two at a time through one pass over P (`lower_product_pair`,
1.17-1.21x faster than two passes at N = 100-300); each of the recurrence's
scalings and projections is an element-wise loop over w followed by a dot (`_scale_dot`,
`_axpy_dot`, `_dot`). A member's result does not depend on the rest of the batch (the native
vector env relies on it). `fastmath` is on in two functions only, the product and `_dot`: it
allows the contraction of a multiply and an add into one fused operation there, and the
reassociation of their sums (dots vectorize no other way: `_dot` as four scalar chains took
0.41 us per recurrence iteration at N = 100, vectorized 0.21 us; the order is the machine
code's, the same in every call). One thread by default, as the BLAS pools of the hot path;
`frozen_advance_threads` runs the fused step's member loop on contiguous spans of members on
numba's threads (`prange`, `parallel=True` in that driver only), for the envs' `num_threads`:
each member is computed alone, by the same loop, so the bits are the one-thread call's.
`error_model="numpy"` everywhere: a division follows IEEE 754
instead of testing its divisor for zero to raise ZeroDivisionError (numba's error model covers
`/`, `//` and `%`; `math.sqrt` and `math.log` test nothing either way). On finite data every
divisor here is guarded or positive, so the bits are the same without the branches: 2-3 %
less time per member in a microbenchmark, and the kernel pass this module calls vectorizes its
divisions only so (`agent_envs.native.kernel`). Non-finite data never reaches these
calls from a step: the envs and `simulate` stop a path once its state or drift is not finite.

`cache=True`: the machine code is written next to this file (or to numba's user-wide cache
directory when that is read-only) the first time and loaded from there in every later process.
numba keys that cache on this file alone: after an edit of
`agent_envs.native.kernel` in a working copy, delete this module's `.nbi`/`.nbc` files
in `__pycache__`, or the fused step keeps the old kernel pass (an installed package's files
change together).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from agent_envs.native.kernel import cucker_smale_drift
from agent_envs.native.kernel import lower_products as _products

#: Taylor terms of phi_p near 0 (as `phi_functions._TAYLOR_TERMS`)
TAYLOR_TERMS = 16
#: the first check's dimension where the error bound applies (`phi_functions.FIRST_BOUND_CHECK`)
FIRST_BOUND_CHECK = 4
#: the full predicted step from m >= FULL_STEP_FROM n (`phi_functions.FULL_STEP_FROM`)
FULL_STEP_FROM = 0.05


@njit(cache=True, error_model="numpy")
def _factorials(count: int) -> np.ndarray:
    """j! as floats for j < count (exact up to 22!)."""
    out = np.empty(count)
    value = 1.0
    for j in range(count):
        if j > 0:
            value *= j
        out[j] = value
    return out


@njit(cache=True, error_model="numpy")
def _phi(z: float, order: int, fact: np.ndarray) -> float:
    """phi_order(z) for order >= 1, as `phi_functions.phi_scalar` computes it."""
    if order == 1:
        if z == 0.0:
            return 1.0
        return math.expm1(z) / z
    if abs(z) < 0.1:
        acc = 1.0 / fact[TAYLOR_TERMS - 1 + order]
        for j in range(TAYLOR_TERMS - 2, -1, -1):
            acc = acc * z + 1.0 / fact[j + order]
        return acc
    val = math.expm1(z)
    power = z
    for j in range(1, order):
        val = val - power / fact[j]
        power = power * z
    return val / power


@njit(cache=True, fastmath={"contract", "reassoc"})
def _dot(a: np.ndarray, b: np.ndarray, n: int) -> float:
    """sum_i a_i b_i over i < n. `reassoc` lets the compiler split the sum into vector lanes
    and interleaved partial sums (the loop is bound by the adder's latency in one chain, and
    a scalar loop of four chains measured 2.5 cycles per entry); the order of the sums is then
    the vectorizer's, fixed by the machine code, the same in every call (as the products'
    dots). Only the sum is reassociated: the arrays are read, nothing else is computed here."""
    acc = 0.0
    for i in range(n):
        acc += a[i] * b[i]
    return acc


@njit(cache=True, error_model="numpy")
def _axpy_dot(w: np.ndarray, coef: float, x: np.ndarray, y: np.ndarray, n: int) -> float:
    """w += coef x, then <w, y> over i < n (y may be w itself: then |w|^2 of the updated w).
    Two loops, not one: the update (IEEE products and sums, element by element) vectorizes on
    its own, and `_dot` reads the updated w."""
    for i in range(n):
        w[i] += coef * x[i]
    return _dot(w, y, n)


@njit(cache=True, error_model="numpy")
def _scale_dot(w: np.ndarray, s: np.ndarray, q: np.ndarray, factor: float, n: int) -> float:
    """w = (w - s * q) * factor, then <w, q> (two loops, as `_axpy_dot`)."""
    for i in range(n):
        w[i] = (w[i] - s[i] * q[i]) * factor
    return _dot(w, q, n)


@njit(cache=True, error_model="numpy")
def _member_bounds(p: np.ndarray, s: np.ndarray, n: int, scale_abs: float, peak: float):
    """(||c L||_inf, width of spec(c L) on 1^perp) of one member, as `krylov_bounds`
    (peak < 0: no peak, width inf): from max_i |s_i - P_ii| and min_i s_i, in one pass
    (max_i (peak - s_i / n) is peak - (min_i s_i) / n with the same roundings: both steps are
    monotone)."""
    largest = 0.0
    smallest = np.inf
    for i in range(n):
        d = abs(s[i] - p[i, i])
        if d > largest:
            largest = d
        if s[i] < smallest:
            smallest = s[i]
    norm = scale_abs * ((2.0 / n) * largest)
    if peak < 0.0:
        return norm, np.inf
    spread = peak - smallest / n
    return norm, scale_abs * (2.0 * max(spread, 0.0))


@njit(cache=True, error_model="numpy")
def _tridiagonal_ql(d, e, rows, m, rot_c, rot_s, rot_at) -> int:
    """Eigenvalues of the symmetric tridiagonal T (diagonal d[:m], off-diagonal e[:m - 1]; e[m - 1]
    is scratch) into d[:m], by the implicit QL iteration with Wilkinson shifts (EISPACK's tql2,
    as in Numerical Recipes' `tqli`; backward stable like LAPACK's syevd). Returns the number K
    of plane rotations G_1, ..., G_K it applied, or -1 (an eigenvalue needed more than 30 m
    iterations, or more rotations than the buffers hold: the caller then uses
    `np.linalg.eigh`).

    The eigenvectors are Z = G_1 G_2 ... G_K (columns), where G_r rotates the coordinates
    (i, i + 1), i = rot_at[r], by (c, s) = (rot_c[r], rot_s[r]):
    (G y)_i = c y_i + s y_{i+1}, (G y)_{i+1} = c y_{i+1} - s y_i. tql2 multiplies them into a
    full Z, O(m^3); here the rotations are recorded and applied to the two rows of Z that
    the error bound (and Saad's estimate) read, rows[0] = e_1^T Z and rows[1] = e_m^T Z, O(m^2);
    `_apply_z` forms Z y for the one vector the phi-action needs."""
    for j in range(m):
        rows[0, j] = 0.0
        rows[1, j] = 0.0
    rows[0, 0] = 1.0
    rows[1, m - 1] = 1.0
    capacity = rot_c.shape[0]
    count = 0
    e[m - 1] = 0.0
    for low in range(m):
        iterations = 0
        while True:
            high = low
            while high < m - 1:
                dd = abs(d[high]) + abs(d[high + 1])
                if abs(e[high]) + dd == dd:
                    break
                high += 1
            if high == low:
                break
            iterations += 1
            if iterations > 30 * m or count + (high - low) > capacity:
                return -1
            g = (d[low + 1] - d[low]) / (2.0 * e[low])
            r = math.sqrt(g * g + 1.0)  # |g| > 1e154: r = inf, the shift term below -> 0, its limit
            g = d[high] - d[low] + e[low] / (g + math.copysign(r, g))
            s = 1.0
            c = 1.0
            p = 0.0
            i = high - 1
            underflow = False
            while i >= low:
                f = s * e[i]
                b = c * e[i]
                r = math.sqrt(f * f + g * g)  # entries of c L(x) are bounded by its norm
                e[i + 1] = r
                if r == 0.0:
                    d[i + 1] -= p
                    e[high] = 0.0
                    underflow = True
                    break
                s = f / r
                c = g / r
                g = d[i + 1] - p
                r = (d[i] - g) * s + 2.0 * c * b
                p = s * r
                d[i + 1] = g + p
                g = c * r - b
                for row in range(2):
                    f = rows[row, i + 1]
                    rows[row, i + 1] = s * rows[row, i] + c * f
                    rows[row, i] = c * rows[row, i] - s * f
                rot_c[count] = c
                rot_s[count] = s
                rot_at[count] = i
                count += 1
                i -= 1
            if underflow:
                continue
            d[low] -= p
            e[low] = g
            e[high] = 0.0
    return count


@njit(cache=True, error_model="numpy")
def _apply_z(y, count, rot_c, rot_s, rot_at) -> None:
    """y <- Z y = G_1 (G_2 (... (G_K y))) in place, for the K rotations `_tridiagonal_ql`
    recorded: O(K) = O(m^2) instead of the O(m^3) of forming Z."""
    for r in range(count - 1, -1, -1):
        i = rot_at[r]
        c = rot_c[r]
        s = rot_s[r]
        a = y[i]
        b = y[i + 1]
        y[i] = c * a + s * b
        y[i + 1] = c * b - s * a


@njit(cache=True, error_model="numpy")
def _phi_of_tridiagonal(alphas, betas, m, col, order, fact, out, d, e, rows, rot_c, rot_s,
                        rot_at, phis):  # fmt: skip
    """What the error bound of column `col` at dimension m reads (`_error_bound`: the
    eigenvalues of T_m, rows 1 and m of its eigenvector matrix Z, phi_order of the eigenvalues;
    Saad's estimate: |e_m^T phi(T_m) e_1|), |phi(T_m) e_1|, and what `_apply_z` needs to form
    phi_order(T_m) e_1 = Z phi(Lambda) Z^T e_1 (T_m from alphas[:m, col] and betas[:m - 1,
    col]): returns (last, size, K).

    All come from the eigenvalues and rows 1 and m of Z alone (|Z y| = |y| for the orthogonal
    Z), so a check that fails forms no coefficients. out[:m] receives
    y = phi(Lambda) Z^T e_1 and K >= 0 the rotations of Z (`_tridiagonal_ql`), or, where the
    QL iteration gave up (more rotations than the buffers hold, from m above about 40, or more
    than 30 m iterations, not seen in practice), the coefficients themselves from LAPACK's
    eigh and K = -1 (a non-finite T: NaN throughout, so that no check passes). d, e (>= m),
    rows (2, >= m) and the rotation buffers are scratch; on
    return d[:m] holds the eigenvalues, rows[:, :m] Z's first and last rows and phis[:m]
    phi_order of the eigenvalues (what `_error_bound` reads)."""
    for i in range(m):
        d[i] = alphas[i, col]
    for i in range(m - 1):
        e[i] = betas[i, col]
    count = _tridiagonal_ql(d, e, rows, m, rot_c, rot_s, rot_at)
    last = 0.0
    size = 0.0
    if count < 0:
        finite = True
        for i in range(m):
            finite = finite and math.isfinite(alphas[i, col])
        for i in range(m - 1):
            finite = finite and math.isfinite(betas[i, col])
        if not finite:
            # (LAPACK refuses a non-finite T: the check fails instead of raising, so that the
            # member reads as not converged in the one-thread and the threaded loop alike)
            for j in range(m):
                d[j] = np.nan
                rows[0, j] = np.nan
                rows[1, j] = np.nan
                phis[j] = np.nan
                out[j] = np.nan
            return np.nan, np.nan, count
        t = np.zeros((m, m))
        for i in range(m):
            t[i, i] = alphas[i, col]
        for i in range(m - 1):
            t[i, i + 1] = betas[i, col]
            t[i + 1, i] = betas[i, col]
        lam, vectors = np.linalg.eigh(t)
        for j in range(m):
            d[j] = lam[j]
            rows[0, j] = vectors[0, j]
            rows[1, j] = vectors[m - 1, j]
            phis[j] = _phi(lam[j], order, fact)
        for i in range(m):
            acc = 0.0
            for j in range(m):
                acc += vectors[i, j] * (phis[j] * vectors[0, j])
            out[i] = acc
            size += acc * acc
        last = out[m - 1]
    else:
        for j in range(m):
            phis[j] = _phi(d[j], order, fact)
            y = phis[j] * rows[0, j]
            out[j] = y
            last += rows[1, j] * y
            size += y * y
    return abs(last), math.sqrt(size), count


@njit(cache=True, error_model="numpy")
def _error_bound(d, rows, phis, m, order, fact, hi) -> float:
    """|f(hi)|, f(mu) = sum_j g_j phi[lambda_j, mu], g_j = Z_1j Z_mj: the Lanczos error at
    dimension m is at most b_m |v| max over spec(A) of |f|, and f is positive and increasing,
    so its max over [lo, hi] is f(hi) (`phi_functions._error_bounds`, the same arithmetic).
    phi[l, mu] = (phi(l) - phi(mu)) / (l - mu), phi'((l + mu) / 2) = phi_p - p phi_{p+1} there
    where |l - mu| <= 1e-6 max(1, |l|, |mu|)."""
    phi_mu = _phi(hi, order, fact)
    acc = 0.0
    for j in range(m):
        lam = d[j]
        gap = lam - hi
        scale = max(max(abs(lam), abs(hi)), 1.0)
        if abs(gap) <= 1e-6 * scale:
            mid = 0.5 * (lam + hi)
            dd = _phi(mid, order, fact) - order * _phi(mid, order + 1, fact)
        else:
            dd = (phis[j] - phi_mu) / gap
        acc += (rows[0, j] * rows[1, j]) * dd
    return abs(acc)


@njit(cache=True, error_model="numpy")
def _spectrum_top(norm, width, low):
    """The top hi of the interval [lo, hi] holding the spectrum the Lanczos vectors see, and
    whether it is known (`phi_functions._spectrum_interval`; the bound reads only hi, f being
    increasing): [low, low + width] within [-norm, 0] for the deflated frozen c L with c > 0
    (low = -c p_max, the bottom of spec(c L) on 1^perp; nan if unknown), (hi, True); else
    (norm, False): then the iteration keeps Saad's estimate and its schedule."""
    if width < np.inf and low <= 0.0:
        hi = min(low + width, 0.0)
        if max(low, -norm) <= hi:
            return hi, True
    return norm, False


@njit(cache=True, error_model="numpy")
def _next_check(m, ratio, prev_m, prev_ratio, max_step, n) -> int:
    """The dimension of the next check after a failed one at m (`phi_functions._next_check`,
    the same arithmetic): half way to the extrapolated dimension below m = FULL_STEP_FROM n,
    all the way from there."""
    step = 1
    if prev_m > 0 and prev_ratio > ratio and prev_ratio < np.inf and ratio < np.inf:
        predicted = math.log(ratio) * (m - prev_m) / math.log(prev_ratio / ratio)
        # (clamped before the integer conversion: a ratio that barely falls predicts ~inf)
        ahead = math.ceil(min(predicted, 1e9))
        if m < FULL_STEP_FROM * n:
            ahead = (ahead + 1) // 2
        step = max(1, min(max_step, ahead))
    return m + step


@njit(cache=True, error_model="numpy")
def frozen_lanczos(
    p: np.ndarray,
    s: np.ndarray,
    scale: float,
    v: np.ndarray,
    order: int,
    rtol: float,
    max_dim: int,
    max_step: int,
    norms: np.ndarray,
    widths: np.ndarray,
    lows: np.ndarray,
    peak: float,
    out: np.ndarray,
    converged: np.ndarray,
    extra: np.ndarray,
    extra_scale: float,
) -> None:
    """phi_order(c L) (V + e c L W) into `out` (B, N, k) and the members' convergence into
    `converged` (B,).

    p (B, N, N) symmetric, s (B, N), v (B, N, k); c = `scale`; `norms`, `widths`, `lows` (B,)
    the bounds of c L per member (`lows`: the bottom of the interval of that width holding
    spec(c L) on 1^perp, nan or empty where unknown: Saad's estimate then), or `norms` empty to
    compute all three from s, P_kk, `peak` and c (`peak` < 0: none; the bottom -c p_max for
    c > 0);
    `extra` W (B, N, k) and e = `extra_scale`, or an empty W for phi_order(c L) V: the product
    c L W is taken with the member's P in cache, before its Lanczos iteration (SERB's sigma L dW).
    """
    none3 = np.empty((0, 0, 0))
    _members(
        p, s, scale, v, order, rtol, max_dim, max_step, norms, widths, lows, peak, out,
        converged, extra, extra_scale, False, none3, 0.0, none3, 0.0, 0.0, none3, none3,
        np.empty((0, 0)), none3,
    )  # fmt: skip


@njit(cache=True, error_model="numpy")
def frozen_advance(
    p: np.ndarray,
    s: np.ndarray,
    scale: float,
    v: np.ndarray,
    rtol: float,
    max_dim: int,
    max_step: int,
    peak: float,
    out: np.ndarray,
    extra: np.ndarray,
    extra_scale: float,
    x: np.ndarray,
    dt: float,
    noise: np.ndarray,
    weight: float,
    alpha2: float,
    x_next: np.ndarray,
    s_next: np.ndarray,
    drift_next: np.ndarray,
) -> int:
    """An exponential Rosenbrock-Euler step and the next kernel pass, member by member;
    returns the number of members whose Lanczos did not converge (0: all did).

    For each member: phi_1(c L) (V + e c L W) into out (as `frozen_lanczos`, order 1, the
    bounds from s and P_kk), then x_next = x + dt out + noise (the integrator's update, the same
    operations in the same order), then, if the member converged, P(x_next) into p (over
    P(x), which this member no longer needs), s_next = P(x_next) 1 and L(x_next) x_next into
    drift_next (`agent_envs.native.kernel.cucker_smale_drift`, the symmetric kernel
    w / (alpha^2 + |x_k - x_l|^2)). The next pass writes the lower triangle of P that the
    member's Lanczos products just read, while it is in cache (the upper triangle is left to
    `agent_envs.dynamics.laplacian.FrozenLaplacian`, which fills it when asked for the whole
    P). x, noise, x_next (B, N, k); s_next (B, N); drift_next (B, N, k). A member that did
    not converge keeps P(x) (the caller then takes the general path).
    """
    converged = np.empty(p.shape[0], dtype=np.bool_)
    _members(
        p, s, scale, v, 1, rtol, max_dim, max_step, np.empty(0), np.empty(0), np.empty(0), peak,
        out, converged, extra, extra_scale, True, x, dt, noise, weight, alpha2, p, x_next, s_next,
        drift_next,
    )  # fmt: skip
    failed = 0
    for member in range(p.shape[0]):
        if not converged[member]:
            failed += 1
    return failed


@njit(cache=True, error_model="numpy", parallel=True)
def frozen_advance_threads(
    p: np.ndarray,
    s: np.ndarray,
    scale: float,
    v: np.ndarray,
    rtol: float,
    max_dim: int,
    max_step: int,
    peak: float,
    out: np.ndarray,
    extra: np.ndarray,
    extra_scale: float,
    x: np.ndarray,
    dt: float,
    noise: np.ndarray,
    weight: float,
    alpha2: float,
    x_next: np.ndarray,
    s_next: np.ndarray,
    drift_next: np.ndarray,
    chunks: int,
) -> int:
    """`frozen_advance` with the members in `chunks` contiguous spans, the spans on numba's
    threads (`prange`; the caller sets how many, `agent_envs.native.loader.
    compiled_threads`). Each span runs the same member loop (`_members`) on its slices with
    scratch arrays of its own; a member's step does not depend on the other members, so the
    result equals `frozen_advance`'s bit for bit (tests/test_compiled_threads.py)."""
    members = p.shape[0]
    # (False until a span's loop sets it: numba's parallel loop may drop an error raised in a
    # span, and a member left unwritten must read as not converged, never as garbage)
    converged = np.zeros(members, dtype=np.bool_)
    with_extra = extra.shape[0] > 0
    empty = np.empty(0)
    for c in prange(chunks):
        lo = (members * c) // chunks
        hi = (members * (c + 1)) // chunks
        span_extra = extra[lo:hi] if with_extra else extra
        _members(
            p[lo:hi], s[lo:hi], scale, v[lo:hi], 1, rtol, max_dim, max_step, empty, empty, empty,
            peak, out[lo:hi], converged[lo:hi], span_extra, extra_scale, True, x[lo:hi], dt,
            noise[lo:hi], weight, alpha2, p[lo:hi], x_next[lo:hi], s_next[lo:hi],
            drift_next[lo:hi],
        )  # fmt: skip
    failed = 0
    for member in range(members):
        if not converged[member]:
            failed += 1
    return failed


@njit(cache=True, error_model="numpy")
def _members(p, s, scale, v, order, rtol, max_dim, max_step, norms, widths, lows, peak, out,
             converged, extra, extra_scale, advance, x, dt, noise, weight, alpha2, p_next, x_next,
             s_next, drift_next):  # fmt: skip
    """The body of `frozen_lanczos` (advance False) and `frozen_advance` (advance True, p_next
    the same array as p, writable: numba types every branch, and p is read-only in
    `frozen_lanczos`)."""
    n_members, n, _ = p.shape
    k = v.shape[2]
    max_dim = min(max_dim, n)
    with_extra = extra.shape[0] > 0
    fact = _factorials(TAYLOR_TERMS + order + 1)
    factor = scale / n
    basis = np.empty((max_dim + 1, k, n))
    w = np.empty((k, n))
    alphas = np.empty((max_dim, k))
    betas = np.empty((max_dim, k))
    b = np.empty(k)
    beta0 = np.empty(k)
    coeffs = np.empty((k, max_dim))
    eig_d = np.empty(max_dim)
    eig_e = np.empty(max_dim)
    rows = np.empty((2, max_dim))
    # rotations of one QL run: m^2 / 2 to 1.3 m^2 for T_m in practice; beyond the buffers (m
    # above 40; 26 at most at the paper setting) the check falls back to LAPACK's eigh
    capacity = 2 * min(max_dim, 40) ** 2 + 8
    rot_c = np.empty(capacity)
    rot_s = np.empty(capacity)
    rot_at = np.empty(capacity, dtype=np.int64)
    means = np.empty(k)
    ones = np.ones(n)
    phis = np.empty(max_dim)
    for member in range(n_members):
        pm = p[member]
        sm = s[member]
        if norms.size == 0:
            norm, width = _member_bounds(pm, sm, n, abs(scale), peak)
            low = -scale * peak if peak > 0.0 and scale > 0.0 else np.nan
        else:
            norm, width = norms[member], widths[member]
            low = lows[member] if lows.size > 0 else np.nan
        # a finite width: c L 1 = 0 and spec(c L) on 1^perp lies in an interval of that width;
        # the constant vector is deflated (phi_p(0) = 1/p! on the mean, Lanczos on the rest)
        deflate = width < np.inf
        hi, tight = _spectrum_top(norm, width, low)
        if tight:
            next_check = min(FIRST_BOUND_CHECK, max_dim)
        else:  # Saad's estimate, from m_0 = min(3.5 sqrt(|A|_inf), 3.5 sqrt(w)), every 2
            first = math.ceil(3.5 * math.sqrt(norm))
            if deflate:
                first = min(first, math.ceil(3.5 * math.sqrt(width)))
            next_check = int(min(max(first, 2.0), float(max_dim)))
        prev_m = 0
        prev_ratio = 0.0
        tiny = 1e-12 * (norm + 1e-300)
        if with_extra:
            # P W for V + e c L W = V + e c (P W - s * W) / N (basis[1] is free here), the
            # columns two at a time
            for c in range(k):
                wc_in = basis[1, c]
                for i in range(n):
                    wc_in[i] = extra[member, i, c]
            _products(pm, basis[1], w, k, n)
        for c in range(k):
            q0 = basis[0, c]
            if with_extra:
                wc_in = basis[1, c]
                for i in range(n):
                    q0[i] = v[member, i, c] + extra_scale * ((w[c, i] - sm[i] * wc_in[i]) * factor)
            else:
                for i in range(n):
                    q0[i] = v[member, i, c]
            mean = 0.0
            if deflate:
                mean = _dot(q0, ones, n) / n
            means[c] = mean
            for i in range(n):
                q0[i] = q0[i] - mean
            beta0[c] = math.sqrt(_dot(q0, q0, n))
            inv0 = 1.0 / beta0[c] if beta0[c] > 0 else 1.0
            for i in range(n):
                q0[i] = q0[i] * inv0
        ok_member = False
        stop_m = max_dim
        for j in range(max_dim):
            m = j + 1
            all_small = True
            # w = (P q - s * q) * c / N (P symmetric) and alpha = <w, q>; the products of the
            # k columns two at a time (one pass over P for both)
            _products(pm, basis[j], w, k, n)
            for c in range(k):
                q = basis[j, c]
                wc = w[c]
                alpha = _scale_dot(wc, sm, q, factor, n)
                if j > 0:
                    qp = basis[j - 1, c]
                    proj = _axpy_dot(wc, -alpha, q, qp, n)  # w -= alpha q; <w, q_{j-1}>
                    b[c] = math.sqrt(_axpy_dot(wc, -proj, qp, wc, n))
                else:
                    b[c] = math.sqrt(_axpy_dot(wc, -alpha, q, wc, n))
                alphas[j, c] = alpha
                if not b[c] <= tiny:
                    all_small = False
            stops = all_small or m == max_dim
            check = (not stops) and m == next_check
            if stops or check:
                passed = True
                ratio = 0.0
                for c in range(k):
                    last, size, count = _phi_of_tridiagonal(
                        alphas, betas, m, c, order, fact, coeffs[c], eig_d, eig_e, rows,
                        rot_c, rot_s, rot_at, phis,
                    )  # fmt: skip
                    if check:
                        if tight:
                            bound = b[c] * _error_bound(eig_d, rows, phis, m, order, fact, hi)
                        else:
                            bound = b[c] * last
                        if not bound <= rtol * size + 1e-300:
                            passed = False
                            ratio = max(ratio, bound / (rtol * size + 1e-300))
                    if count > 0 and (stops or passed):  # (coefficients of an accepted m)
                        _apply_z(coeffs[c], count, rot_c, rot_s, rot_at)
                if stops or passed:
                    ok_member = all_small or (check and passed)
                    stop_m = m
                    break
                if tight:
                    next_check = _next_check(m, ratio, prev_m, prev_ratio, max_step, n)
                    prev_m, prev_ratio = m, ratio
                else:
                    next_check = m + 2
            for c in range(k):
                betas[j, c] = b[c]
                nxt = basis[j + 1, c]
                if b[c] <= tiny:
                    for i in range(n):
                        nxt[i] = 0.0
                else:
                    inv = 1.0 / b[c]  # one division, n products (within an ulp of w / b)
                    for i in range(n):
                        nxt[i] = w[c, i] * inv
        converged[member] = ok_member
        # |v| Q_m c, summed vector by vector into w (free now), then written out
        for c in range(k):
            acc = w[c]
            for i in range(n):
                acc[i] = 0.0
            for jj in range(stop_m):
                coef = coeffs[c, jj]
                q = basis[jj, c]
                for i in range(n):
                    acc[i] += coef * q[i]
            for i in range(n):
                out[member, i, c] = acc[i] * beta0[c] + means[c] / fact[order]
        if advance:
            for i in range(n):
                for c in range(k):
                    x_next[member, i, c] = (
                        x[member, i, c] + dt * out[member, i, c] + noise[member, i, c]
                    )
            if ok_member:
                cucker_smale_drift(
                    x_next[member : member + 1],
                    weight,
                    alpha2,
                    p_next[member : member + 1],
                    s_next[member : member + 1],
                    drift_next[member : member + 1],
                )
