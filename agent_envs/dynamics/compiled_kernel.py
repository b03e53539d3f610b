"""The Cucker-Smale kernel matrix, its row sums and the drift in one compiled pass (numba).

This module imports numba; `agent_envs.dynamics.laplacian` imports it only through
`load_compiled_kernel()` there, so the package works without numba (the numpy passes of
`fill_cucker_smale` and one product P [x | 1] stay, and stay the reference).

`cucker_smale_drift` computes, for states x (B, N, d) and the symmetric kernel with a scalar
weight w (`SwarmParams.kernel="symmetric"`),

    P[b, k, l] = w / (alpha^2 + |x_k - x_l|^2),   s = P 1,   F = (P x - s * x) / N = L(x) x,

one batch member at a time: the upper triangle of P row by row (N (N + 1) / 2 divisions
instead of N^2: P is symmetric), mirrored below the diagonal, then s and P x as sums of P's rows
(w += P[l, :] and w += x_l P[l, :], four rows per pass over w in the rows' order, which the
compiler vectorizes without reassociating a sum; P symmetric, so these are the row sums).
Each entry of P is the same arithmetic as `fill_cucker_smale` (x_l - x_k, squared, summed over
the coordinates, + alpha^2, w / .), up to the compiler fusing a multiply and an add into one
rounding; s and P x are sums in another order than numpy's product, so the results agree with
the numpy path to round-off (tests/test_compiled_kernel.py: 1e-15 for P, 1e-13 for the drift,
relative). A member's result does not depend on the rest of the batch (the native vector env
relies on it). No `fastmath`, no threads.

Measured by `benchmarks/bench_throughput.py` (part 2, N = 100, 20 paths, d = 1): 8.9 us per
member against 12.6 us for numpy's four in-place passes and the product on one machine; on a
slower one 12-15 us, of which the N (N + 1) / 2 divisions take 7.4 us, the mirror 2.1 us and
the sums 2.2 us (2.9 us one row per pass).

`cache=True`: the machine code is written next to this file (or to numba's user-wide cache
directory when that is read-only) the first time and loaded from there in every later process.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _upper_row(
    xt: np.ndarray, k: int, weight: float, alpha2: float, row: np.ndarray, n: int, d: int
) -> None:
    """row[j] = w / (alpha^2 + |x_k - x_l|^2) for j >= k; xt (d, N) the coordinates."""
    if d == 1:
        xk = xt[0, k]
        for j in range(k, n):
            diff = xt[0, j] - xk
            row[j] = weight / (diff * diff + alpha2)
        return
    xk = xt[0, k]
    for j in range(k, n):
        diff = xt[0, j] - xk
        row[j] = diff * diff
    for c in range(1, d):
        xk = xt[c, k]
        for j in range(k, n):
            diff = xt[c, j] - xk
            row[j] += diff * diff
    for j in range(k, n):
        row[j] = weight / (row[j] + alpha2)


@njit(cache=True)
def cucker_smale_drift(
    x: np.ndarray,
    weight: float,
    alpha2: float,
    p: np.ndarray,
    s: np.ndarray,
    drift: np.ndarray,
) -> None:
    """P into `p` (B, N, N), s = P 1 into `s` (B, N) and L(x) x into `drift` (B, N, d), for x
    (B, N, d) float64 (see the module docstring)."""
    members, n, d = x.shape
    xt = np.empty((d, n))
    acc = np.empty((d, n))
    for b in range(members):
        pb = p[b]
        sb = s[b]
        for j in range(n):
            for c in range(d):
                xt[c, j] = x[b, j, c]
        for k in range(n):
            _upper_row(xt, k, weight, alpha2, pb[k], n, d)
        for k in range(1, n):
            for j in range(k):
                pb[k, j] = pb[j, k]
        for i in range(n):
            sb[i] = 0.0
        for c in range(d):
            for i in range(n):
                acc[c, i] = 0.0
        # four rows per pass over s and each acc[c]: the same sums in the same order as row by
        # row (s_i = ((P_0i + P_1i) + P_2i) + ...), with a quarter of the passes
        top = n - n % 4
        for j in range(0, top, 4):
            r0 = pb[j]
            r1 = pb[j + 1]
            r2 = pb[j + 2]
            r3 = pb[j + 3]
            for i in range(n):
                sb[i] = sb[i] + r0[i] + r1[i] + r2[i] + r3[i]
            for c in range(d):
                x0 = xt[c, j]
                x1 = xt[c, j + 1]
                x2 = xt[c, j + 2]
                x3 = xt[c, j + 3]
                ac = acc[c]
                for i in range(n):
                    ac[i] = ac[i] + x0 * r0[i] + x1 * r1[i] + x2 * r2[i] + x3 * r3[i]
        for j in range(top, n):
            row = pb[j]
            for i in range(n):
                sb[i] += row[i]
            for c in range(d):
                xl = xt[c, j]
                ac = acc[c]
                for i in range(n):
                    ac[i] += xl * row[i]
        for i in range(n):
            for c in range(d):
                drift[b, i, c] = (acc[c, i] - sb[i] * xt[c, i]) / n
