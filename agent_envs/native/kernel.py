"""The Cucker-Smale kernel matrix, its row sums and the drift in one compiled pass (numba).

This module imports numba; the package imports it only through `agent_envs.native.loader`
(path "kernel", `available("kernel")`), so the package works without numba (the numpy passes
of `agent_envs.dynamics.laplacian.fill_cucker_smale` and one product P [x | 1] stay, and stay
the reference).

`cucker_smale_drift` computes, for states x (B, N, d) and the symmetric kernel with a scalar
weight w (`SwarmParams.kernel="symmetric"`),

    P[b, k, l] = w / (alpha^2 + |x_k - x_l|^2),   s = P 1,   F = (P x - s * x) / N = L(x) x,

one batch member at a time: the lower triangle of P row by row (N (N + 1) / 2 divisions
instead of N^2: P is symmetric). For d = 1 each row takes its shares of s and P x in the
divisions' own loop (`_row_with_sums_1d`), while the row is in registers: entry P_kj (j < k)
adds to s_j and (P x)_j (the part above the diagonal, by symmetry: axpys over j) and to s_k
and (P x)_k (the row's own sums); its four multiply-adds take the slots the divider leaves
free. 5.2-5.9 against 6.6-6.7 us per member (N = 100, 20 members, alternating in one process)
for the rows followed by two passes of `lower_product` over the triangle, which d > 1 keeps
(`_lower_row`, then s by `lower_product` and the d columns of P x two at a time by
`lower_products`: fusing its d + 1 sums into the rows measured 1.8x slower at d = 2). The
divisions alone are 4.1-4.3 us per member at N = 100 (part 2b of the former
benchmarks/bench_throughput.py, docs/performance-notes.md): the divider's throughput, about two
cycles a division.

The upper triangle is left unwritten: the compiled Lanczos reads only the lower one, and an
Euler-Maruyama step reads P not at all; `agent_envs.dynamics.laplacian.FrozenLaplacian` fills
it (`mirror_lower`) the first time a consumer of the whole P (a numpy product, `dense()`) asks
for it. Each entry of P is the same arithmetic as `fill_cucker_smale` (x_l - x_k, squared,
summed over the coordinates in order, + alpha^2, w / .), so P equals the numpy pass bit for
bit, on both sides of the diagonal ((x_l - x_k)^2 = (x_k - x_l)^2 exactly); s and P x are
sums in another order than numpy's product, so they agree with the numpy path to round-off
(tests/test_compiled_kernel.py: P bit for bit, s 1e-14, the drift 1e-13, relative). A
member's result does not depend on the rest of the batch (the native vector env relies on
it). `fastmath={"reassoc"}` in `_row_with_sums_1d` and `lower_product`, whose reductions over
a row vectorize no other way (the order is then the machine code's, the same in every call);
an entry of P there is (x_j - x_k)^2 + alpha^2 and one division, operations reassociation does
not touch, so P keeps its bits; `_lower_row`, which sums d > 1 squares, runs without it (a
reassociated alpha^2 + |x_k - x_l|^2 would change them). One thread, except in
`cucker_smale_drift_threads` (the envs' `num_threads`): contiguous spans of members on numba's
threads, each span one call of `cucker_smale_drift`, so the bits are the one-thread call's.

`error_model="numpy"`: a division follows IEEE 754 (x / 0 is inf or nan) instead of numba's
default Python model, which tests every divisor for zero to raise ZeroDivisionError, a branch
in the loop that kept the row's divisions scalar. Without it they vectorize: the pass took 9.9
us per member with the test and 6.6 us without (N = 100, d = 1, a microbenchmark of the pass
of that time), with the same bits (each division is the same IEEE operation, one lane at a
time or four at once). The divisors are alpha^2 + |x_k - x_l|^2 >= alpha^2 > 0 and N.

History, measured by microbenchmarks at N = 100, d = 1: 13.7-13.9 us per member for the upper
triangle, its mirror below the diagonal and s and P x as sums of P's whole rows; 9.2-9.4 us for
the lower triangle and two passes of `lower_product`; 6.6 us with its divisions vectorized;
5.2-5.9 us with the sums in the rows' loop (above).

`cache=True`: the machine code is written next to this file (or to numba's user-wide cache
directory when that is read-only) the first time and loaded from there in every later process.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True, fastmath={"contract", "reassoc"})
def lower_product(p: np.ndarray, q: np.ndarray, w: np.ndarray, n: int) -> None:
    """w = P q for a symmetric P (n, n) of which only the lower triangle (and the diagonal) is
    read: four rows j..j+3 per pass, each entry P[j + r, i] (i < j) read once and used twice, in
    w_i += q_{j+r} P[j+r, i] (four rows of axpys: the part above the diagonal, by symmetry) and
    in the dot w_{j+r} += sum_i P[j+r, i] q_i (the part below it); the 4 x 4 blocks on the
    diagonal read their lower halves for both; the last n % 4 rows one at a time.

    Half of the 80 KB matrix (N = 100) is read: 0.9-1.0 us against 1.2-1.3 us for rows of
    axpys over all of P. The dots are reductions, which the compiler vectorizes only when it
    may reassociate their sums (`reassoc`, in this function only; without it 2-6 us). The order
    of the sums is then the vectorizer's, fixed by the machine code (and so per machine): the
    same inputs give the same w bit for bit in every call (the native vector env and its
    single twins agree bit for bit), and w agrees with numpy's product to round-off
    (tests/test_compiled_lanczos.py). Each caller compiles its own copy (the Lanczos of
    `agent_envs.native.lanczos` for a read-only and for a writable P): their
    equality bit for bit rests on the vectorizer treating them alike, which it does here and
    which the tests of the fused step against the general path check. `contract` fuses each
    multiply-add (one rounding instead of two)."""
    for i in range(n):
        w[i] = 0.0
    top = n - n % 4
    for j in range(0, top, 4):
        q0 = q[j]
        q1 = q[j + 1]
        q2 = q[j + 2]
        q3 = q[j + 3]
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        a3 = 0.0
        for i in range(j):
            p0 = p[j, i]
            p1 = p[j + 1, i]
            p2 = p[j + 2, i]
            p3 = p[j + 3, i]
            w[i] += q0 * p0 + q1 * p1 + q2 * p2 + q3 * p3
            qi = q[i]
            a0 += p0 * qi
            a1 += p1 * qi
            a2 += p2 * qi
            a3 += p3 * qi
        for r in range(4):  # the block on the diagonal, from its lower half
            acc = 0.0
            for c in range(4):
                if c <= r:
                    acc += p[j + r, j + c] * q[j + c]
                else:
                    acc += p[j + c, j + r] * q[j + c]
            w[j + r] += acc
        w[j] += a0
        w[j + 1] += a1
        w[j + 2] += a2
        w[j + 3] += a3
    for j in range(top, n):  # the last n % 4 rows, one at a time
        qj = q[j]
        acc = 0.0
        for i in range(j):
            pv = p[j, i]
            w[i] += qj * pv
            acc += pv * q[i]
        w[j] += acc + p[j, j] * qj


@njit(cache=True, fastmath={"contract", "reassoc"})
def lower_product_pair(
    p: np.ndarray, q: np.ndarray, r: np.ndarray, w: np.ndarray, v: np.ndarray, n: int
) -> None:
    """w = P q and v = P r in one pass over P's lower triangle: `lower_product`'s loops with
    each entry read once for both vectors (four uses instead of two).

    The loops are FMA-bound rather than bound by reading P, so two vectors in one pass cost
    less than two passes, not half: 1.17-1.21x faster than two `lower_product` calls at
    N = 100 and 300 (medians of per-round ratios over 60 interleaved rounds of 1,000 pairs,
    one process), 1.06x at N = 30. Each vector's sums follow the same scheme as
    `lower_product` (its row dots reassociated by the vectorizer), not necessarily in the same
    order: w agrees with `lower_product`'s to round-off, and with itself bit for bit in every
    call."""
    for i in range(n):
        w[i] = 0.0
        v[i] = 0.0
    top = n - n % 4
    for j in range(0, top, 4):
        q0 = q[j]
        q1 = q[j + 1]
        q2 = q[j + 2]
        q3 = q[j + 3]
        r0 = r[j]
        r1 = r[j + 1]
        r2 = r[j + 2]
        r3 = r[j + 3]
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        a3 = 0.0
        b0 = 0.0
        b1 = 0.0
        b2 = 0.0
        b3 = 0.0
        for i in range(j):
            p0 = p[j, i]
            p1 = p[j + 1, i]
            p2 = p[j + 2, i]
            p3 = p[j + 3, i]
            w[i] += q0 * p0 + q1 * p1 + q2 * p2 + q3 * p3
            v[i] += r0 * p0 + r1 * p1 + r2 * p2 + r3 * p3
            qi = q[i]
            ri = r[i]
            a0 += p0 * qi
            a1 += p1 * qi
            a2 += p2 * qi
            a3 += p3 * qi
            b0 += p0 * ri
            b1 += p1 * ri
            b2 += p2 * ri
            b3 += p3 * ri
        for row in range(4):  # the block on the diagonal, from its lower half
            acc = 0.0
            acc_r = 0.0
            for c in range(4):
                pv = p[j + row, j + c] if c <= row else p[j + c, j + row]
                acc += pv * q[j + c]
                acc_r += pv * r[j + c]
            w[j + row] += acc
            v[j + row] += acc_r
        w[j] += a0
        w[j + 1] += a1
        w[j + 2] += a2
        w[j + 3] += a3
        v[j] += b0
        v[j + 1] += b1
        v[j + 2] += b2
        v[j + 3] += b3
    for j in range(top, n):  # the last n % 4 rows, one at a time
        qj = q[j]
        rj = r[j]
        acc = 0.0
        acc_r = 0.0
        for i in range(j):
            pv = p[j, i]
            w[i] += qj * pv
            v[i] += rj * pv
            acc += pv * q[i]
            acc_r += pv * r[i]
        w[j] += acc + p[j, j] * qj
        v[j] += acc_r + p[j, j] * rj


@njit(cache=True)
def lower_products(p: np.ndarray, q: np.ndarray, w: np.ndarray, k: int, n: int) -> None:
    """w[c] = P q[c] for the k vectors q (k, n) (w (k, n)): two at a time by
    `lower_product_pair`, an odd last one by `lower_product`."""
    c = 0
    while c + 1 < k:
        lower_product_pair(p, q[c], q[c + 1], w[c], w[c + 1], n)
        c += 2
    if c < k:
        lower_product(p, q[c], w[c], n)


@njit(cache=True, error_model="numpy")
def _lower_row(
    xt: np.ndarray, k: int, weight: float, alpha2: float, row: np.ndarray, n: int, d: int
) -> None:
    """row[j] = w / (alpha^2 + |x_l - x_k|^2) for j <= k; xt (d, N) the coordinates."""
    if d == 1:
        xk = xt[0, k]
        for j in range(k + 1):
            diff = xt[0, j] - xk
            row[j] = weight / (diff * diff + alpha2)
        return
    xk = xt[0, k]
    for j in range(k + 1):
        diff = xt[0, j] - xk
        row[j] = diff * diff
    for c in range(1, d):
        xk = xt[c, k]
        for j in range(k + 1):
            diff = xt[c, j] - xk
            row[j] += diff * diff
    for j in range(k + 1):
        row[j] = weight / (row[j] + alpha2)


@njit(cache=True, fastmath={"reassoc"}, error_model="numpy")
def _row_with_sums_1d(
    x: np.ndarray,
    k: int,
    weight: float,
    alpha2: float,
    row: np.ndarray,
    s: np.ndarray,
    px: np.ndarray,
) -> None:
    """d = 1: row k of P's lower triangle, P_kj = w / ((x_j - x_k)^2 + alpha^2) (j <= k), with
    its shares of s = P 1 and P x in the same loop: s_j += P_kj, (P x)_j += P_kj x_k for j < k
    (the part above the diagonal, by symmetry) and s_k, (P x)_k += the row's own sums. The
    multiply-adds run beside the divisions, which bound the loop. x, s and px are 1-d arrays
    of their own (views of one 2-d scratch array ran this loop 1.5x slower)."""
    xk = x[k]
    acc_s = 0.0
    acc_x = 0.0
    for j in range(k):
        diff = x[j] - xk
        v = weight / (diff * diff + alpha2)
        row[j] = v
        acc_s += v
        acc_x += v * x[j]
        s[j] += v
        px[j] += v * xk
    diff = xk - xk
    v = weight / (diff * diff + alpha2)
    row[k] = v
    s[k] += acc_s + v
    px[k] += acc_x + v * xk


@njit(cache=True, error_model="numpy")
def cucker_smale_drift(
    x: np.ndarray,
    weight: float,
    alpha2: float,
    p: np.ndarray,
    s: np.ndarray,
    drift: np.ndarray,
) -> None:
    """The lower triangle of P (with its diagonal) into `p` (B, N, N), s = P 1 into `s` (B, N)
    and L(x) x into `drift` (B, N, d), for x (B, N, d) float64 (see the module docstring). The
    upper triangle of `p` is not written: `mirror_lower` fills it."""
    members, n, d = x.shape
    if d == 1:
        xs = np.empty(n)
        px = np.empty(n)
        for b in range(members):
            pb = p[b]
            sb = s[b]
            for j in range(n):
                xs[j] = x[b, j, 0]
                sb[j] = 0.0
                px[j] = 0.0
            for k in range(n):
                _row_with_sums_1d(xs, k, weight, alpha2, pb[k], sb, px)
            for i in range(n):
                drift[b, i, 0] = (px[i] - sb[i] * xs[i]) / n
        return
    xt = np.empty((d, n))
    acc = np.empty((d, n))
    ones = np.ones(n)
    for b in range(members):
        pb = p[b]
        sb = s[b]
        for j in range(n):
            for c in range(d):
                xt[c, j] = x[b, j, c]
        for k in range(n):
            _lower_row(xt, k, weight, alpha2, pb[k], n, d)
        lower_product(pb, ones, sb, n)
        lower_products(pb, xt, acc, d, n)
        for i in range(n):
            for c in range(d):
                drift[b, i, c] = (acc[c, i] - sb[i] * xt[c, i]) / n


@njit(cache=True, error_model="numpy", parallel=True)
def cucker_smale_drift_threads(
    x: np.ndarray,
    weight: float,
    alpha2: float,
    p: np.ndarray,
    s: np.ndarray,
    drift: np.ndarray,
    chunks: int,
) -> None:
    """`cucker_smale_drift` of the members in `chunks` contiguous spans, the spans on numba's
    threads (`prange`; the caller sets how many, `agent_envs.native.loader.
    compiled_threads`). Each span is one call of `cucker_smale_drift` on its slices, whose
    members are computed alone (a member's P, s and drift do not depend on the rest of the
    batch), so the result equals one call over the whole batch bit for bit
    (tests/test_compiled_threads.py)."""
    members = x.shape[0]
    for c in prange(chunks):
        lo = (members * c) // chunks
        hi = (members * (c + 1)) // chunks
        cucker_smale_drift(x[lo:hi], weight, alpha2, p[lo:hi], s[lo:hi], drift[lo:hi])


@njit(cache=True)
def mirror_lower(p: np.ndarray) -> None:
    """P's upper triangle from its lower one, in place, for p (B, N, N)."""
    members, n, _ = p.shape
    for b in range(members):
        pb = p[b]
        for k in range(1, n):
            for j in range(k):
                pb[j, k] = pb[k, j]
