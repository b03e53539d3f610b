"""The Lanczos phi-action of the frozen L(x), compiled with numba (optional).

This module imports numba; the package imports it only through `agent_envs.native.loader`
(paths "lanczos" and "fused"), so the package works without numba (the numpy executor
`agent_envs.integrators.phi_lanczos.lanczos_numpy` and the Array-API one `lanczos_action` stay,
the latter for torch and autograd).

`frozen_lanczos` computes phi_p(c L) V for c L = c (P - diag(s)) / N given as the kernel matrix
P (B, N, N) and its row sums s (B, N) (`agent_envs.dynamics.laplacian.FrozenLaplacian`), for V
(B, N, k). It is the Lanczos algorithm of `agent_envs.integrators.phi_lanczos` written as
loops, one batch member at a time: the same recurrence (b_j q_{j+1} = A q_j - a_j q_j -
<., q_{j-1}> q_{j-1}, no reorthogonalization), the same per-member bounds (||c L||_inf and the
width of spec(c L) on 1^perp, from s and P_kk as `agent_envs.dynamics.laplacian.krylov_bounds`
has them), the same deflation of the constant vector (with a finite width: Lanczos on
v - mean(v) 1, phi_p(0) mean(v) 1 added at the end), and the same stopping rule: its constants
and its scalar rules (`first_check`, `spectrum_top`, `next_check`) are
`agent_envs.native.lanczos_rule`'s, compiled here, the ones the numpy executor reads; the error
bound and phi_p(T_m) e_1 come from the QL iteration on T_m (`agent_envs.native.
lanczos_tridiagonal`). Why a second copy of the loop at all: numba compiles no Python objects
(the numpy executor's array-API dispatch, BLAS calls and dictionaries of stopped members), and
the loop here runs one member with its matrix in cache. Only the order of the floating-point
sums (loops instead of BLAS and numpy's pairwise sums, fused multiply-adds in the product) and
the eigensolver differ, so each phi-action agrees with the numpy one to round-off
(tests/test_compiled_lanczos.py: 1e-12).

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
numba keys that cache on each function's own file: after an edit of `agent_envs.native.kernel`,
`lanczos_rule` or `lanczos_tridiagonal` in a working copy, delete this module's `.nbi`/`.nbc`
files in `__pycache__`, or the fused step keeps the old code (an installed package's files
change together).
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import numpy as np
from numba import njit, prange

from agent_envs.native import kernel as _kernel_module
from agent_envs.native import lanczos_rule
from agent_envs.native import lanczos_tridiagonal as _tridiagonal_module
from agent_envs.native.kernel import cucker_smale_drift
from agent_envs.native.kernel import lower_products as _products
from agent_envs.native.lanczos_rule import BREAKDOWN_RTOL, TAYLOR_TERMS, TINY
from agent_envs.native.lanczos_tridiagonal import (
    apply_z,
    error_bound,
    factorials,
    phi_of_tridiagonal,
)


def _source_stamp(*modules: object) -> int:
    """A 62-bit hash of the source files of `modules`."""
    digest = hashlib.sha256()
    for module in modules:
        digest.update(Path(module.__file__).read_bytes())  # type: ignore[attr-defined]
    return int.from_bytes(digest.digest()[:8], "little") >> 2


#: the hash of the other files whose code and constants this module's compiled functions link
#: in (the rule, the tridiagonal eigenproblem, the kernel's products). numba's cache keys each
#: function on its own file only (its documented limit: edits to other files do not invalidate
#: it), so after an edit of one of them the cached machine code here would still run the old
#: rule while the numpy executor reads the new one. `compiled_rule_stamp` freezes this value
#: into the cache when the module compiles; the loader compares the two (`native.loader`'s
#: warm-up of "lanczos") and keeps the compiled Lanczos off, with a warning, where they differ.
RULE_STAMP = _source_stamp(lanczos_rule, _tridiagonal_module, _kernel_module)


@njit(cache=True)
def compiled_rule_stamp() -> int:
    """`RULE_STAMP` as it was when this module's cached machine code was compiled."""
    return RULE_STAMP


_first_check = njit(cache=True, error_model="numpy")(lanczos_rule.first_check)
_spectrum_top = njit(cache=True, error_model="numpy")(lanczos_rule.spectrum_top)
_next_check = njit(cache=True, error_model="numpy")(lanczos_rule.next_check)


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
    `frozen_lanczos`): the scratch arrays once, then each member's Lanczos (`_lanczos_member`)
    and, advancing, its update and next kernel pass (`_advance_member`)."""
    n_members, n, _ = p.shape
    k = v.shape[2]
    max_dim = min(max_dim, n)
    fact = factorials(TAYLOR_TERMS + order + 1)
    basis = np.empty((max_dim + 1, k, n))
    w = np.empty((k, n))
    alphas = np.empty((max_dim, k))
    betas = np.empty((max_dim, k))
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
    phis = np.empty(max_dim)
    ones = np.ones(n)  # (the deflation's mean, one dot per column)
    for member in range(n_members):
        if norms.size == 0:
            norm, width = _member_bounds(p[member], s[member], n, abs(scale), peak)
            low = -scale * peak if peak > 0.0 and scale > 0.0 else np.nan
        else:
            norm, width = norms[member], widths[member]
            low = lows[member] if lows.size > 0 else np.nan
        ok_member = _lanczos_member(
            p[member], s[member], scale / n, v, extra, extra_scale, member, order, rtol, max_dim,
            max_step, norm, width, low, fact, basis, w, alphas, betas, coeffs, eig_d, eig_e,
            rows, rot_c, rot_s, rot_at, phis, out, ones,
        )  # fmt: skip
        converged[member] = ok_member
        if advance:
            _advance_member(member, ok_member, x, dt, noise, weight, alpha2, out, p_next,
                            x_next, s_next, drift_next)  # fmt: skip


@njit(cache=True, error_model="numpy")
def _lanczos_member(pm, sm, factor, v, extra, extra_scale, member, order, rtol, max_dim,
                    max_step, norm, width, low, fact, basis, w, alphas, betas, coeffs, eig_d,
                    eig_e, rows, rot_c, rot_s, rot_at, phis, out, ones) -> bool:  # fmt: skip
    """One member's phi_order(c L) (V + e c L W) into out[member] (c L = factor (P - diag s),
    factor = c / N), with its bounds (norm, width, low); returns whether it converged.

    A finite width: c L 1 = 0 and spec(c L) on 1^perp lies in an interval of that width; the
    constant vector is deflated (phi_p(0) = 1/p! on the mean, Lanczos on the rest). The checks
    follow `lanczos_rule`: the error bound where the interval's top hi is known (`tight`), else
    Saad's estimate every `SAAD_CHECK_STEP` dimensions."""
    n = pm.shape[0]
    deflate = width < np.inf
    hi, tight = _spectrum_top(norm, width, low)
    next_check = _first_check(norm, width, deflate, tight, max_dim)
    prev_m = 0
    prev_ratio = 0.0
    tiny = BREAKDOWN_RTOL * (norm + TINY)
    beta0, means = _start_vectors(pm, sm, factor, v, extra, extra_scale, member, deflate,
                                  basis, w, ones)  # fmt: skip
    ok_member = False
    stop_m = max_dim
    for j in range(max_dim):
        m = j + 1
        all_small = _recurrence_step(pm, sm, factor, basis, w, j, alphas, betas, tiny)
        stops = all_small or m == max_dim
        check = (not stops) and m == next_check
        if stops or check:
            passed, ratio = _check_columns(
                alphas, betas, m, order, fact, coeffs, eig_d, eig_e, rows, rot_c, rot_s, rot_at,
                phis, check, stops, tight, hi, rtol,
            )  # fmt: skip
            if stops or passed:
                ok_member = all_small or (check and passed)
                stop_m = m
                break
            if tight:
                next_check = _next_check(m, ratio, prev_m, prev_ratio, max_step, n)
                prev_m, prev_ratio = m, ratio
            else:
                next_check = m + lanczos_rule.SAAD_CHECK_STEP
        _next_basis(basis, w, betas, j, tiny)
    _write_result(out[member], w, basis, coeffs, beta0, means, fact[order], stop_m)
    return ok_member


@njit(cache=True, error_model="numpy")
def _start_vectors(pm, sm, factor, v, extra, extra_scale, member, deflate, basis, w, ones):
    """The k starting vectors q_0 = (u - mean(u) 1) / |u - mean(u) 1| into basis[0] for
    u = V + e c L W (W = extra[member], or u = V without `extra`), the mean 0 without
    deflation; returns (|u - mean(u) 1|, mean(u)) per column. The product P W goes two columns
    at a time through one pass over P (basis[1] and w are free here)."""
    n = pm.shape[0]
    k = v.shape[2]
    with_extra = extra.shape[0] > 0
    beta0 = np.empty(k)
    means = np.empty(k)
    if with_extra:
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
    return beta0, means


@njit(cache=True, error_model="numpy")
def _recurrence_step(pm, sm, factor, basis, w, j, alphas, betas, tiny) -> bool:
    """One step of the three-term recurrence for the k columns: w = c L q_j - a_j q_j -
    <., q_{j-1}> q_{j-1} with a_j = <c L q_j, q_j> into alphas[j] and b_j = |w| into betas[j]
    (the products P q_j two columns at a time through one pass over P); returns whether every
    b_j <= tiny (a breakdown)."""
    n = pm.shape[0]
    k = w.shape[0]
    all_small = True
    _products(pm, basis[j], w, k, n)
    for c in range(k):
        q = basis[j, c]
        wc = w[c]
        alpha = _scale_dot(wc, sm, q, factor, n)
        if j > 0:
            qp = basis[j - 1, c]
            proj = _axpy_dot(wc, -alpha, q, qp, n)  # w -= alpha q; <w, q_{j-1}>
            betas[j, c] = math.sqrt(_axpy_dot(wc, -proj, qp, wc, n))
        else:
            betas[j, c] = math.sqrt(_axpy_dot(wc, -alpha, q, wc, n))
        alphas[j, c] = alpha
        if not betas[j, c] <= tiny:
            all_small = False
    return all_small


@njit(cache=True, error_model="numpy")
def _check_columns(alphas, betas, m, order, fact, coeffs, eig_d, eig_e, rows, rot_c, rot_s,
                   rot_at, phis, check, stops, tight, hi, rtol):  # fmt: skip
    """phi_p(T_m) e_1 of each column at a stop or a check (T_m from alphas[:m] and
    betas[:m - 1]; betas[m - 1] is b_m), and at a check whether every column's error bound
    b_m |f(hi)| (`tight`) or Saad's b_m |e_m^T phi_p(T_m) e_1| is <= rtol |phi_p(T_m) e_1| +
    TINY: returns (passed, ratio), ratio the largest bound / limit of a failing column. The
    coefficients of an accepted dimension are formed into coeffs (`apply_z`)."""
    k = coeffs.shape[0]
    passed = True
    ratio = 0.0
    for c in range(k):
        last, size, count = phi_of_tridiagonal(
            alphas, betas, m, c, order, fact, coeffs[c], eig_d, eig_e, rows, rot_c, rot_s,
            rot_at, phis,
        )  # fmt: skip
        if check:
            b = betas[m - 1, c]
            if tight:
                bound = b * error_bound(eig_d, rows, phis, m, order, fact, hi)
            else:
                bound = b * last
            if not bound <= rtol * size + TINY:
                passed = False
                ratio = max(ratio, bound / (rtol * size + TINY))
        if count > 0 and (stops or passed):  # (coefficients of an accepted m)
            apply_z(coeffs[c], count, rot_c, rot_s, rot_at)
    return passed, ratio


@njit(cache=True, error_model="numpy")
def _next_basis(basis, w, betas, j, tiny) -> None:
    """q_{j+1} = w / b_j into basis[j + 1] per column, 0 where b_j <= tiny."""
    k, n = w.shape
    for c in range(k):
        b = betas[j, c]
        nxt = basis[j + 1, c]
        if b <= tiny:
            for i in range(n):
                nxt[i] = 0.0
        else:
            inv = 1.0 / b  # one division, n products (within an ulp of w / b)
            for i in range(n):
                nxt[i] = w[c, i] * inv


@njit(cache=True, error_model="numpy")
def _write_result(out_m, w, basis, coeffs, beta0, means, fact_order, stop_m) -> None:
    """|v| Q_m c + mean / p! per column into out_m (N, k), Q_m c summed vector by vector into
    w (free now)."""
    k, n = w.shape
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
            out_m[i, c] = acc[i] * beta0[c] + means[c] / fact_order


@njit(cache=True, error_model="numpy")
def _advance_member(member, ok_member, x, dt, noise, weight, alpha2, out, p_next, x_next,
                    s_next, drift_next) -> None:  # fmt: skip
    """x_next = x + dt out + noise for one member (the integrator's update, the same operations
    in the same order), then, if its Lanczos converged, the kernel pass at x_next into p_next,
    s_next and drift_next (`cucker_smale_drift`)."""
    n, k = x.shape[1], x.shape[2]
    for i in range(n):
        for c in range(k):
            x_next[member, i, c] = x[member, i, c] + dt * out[member, i, c] + noise[member, i, c]
    if ok_member:
        cucker_smale_drift(
            x_next[member : member + 1],
            weight,
            alpha2,
            p_next[member : member + 1],
            s_next[member : member + 1],
            drift_next[member : member + 1],
        )
