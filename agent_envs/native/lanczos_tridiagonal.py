"""phi_p(T_m) e_1 and the Lanczos error bound from the QL iteration on T_m, compiled with numba.

The small eigenproblem of the compiled Lanczos (`agent_envs.native.lanczos`): for the symmetric
tridiagonal T_m = Z diag(lambda) Z^T of the recurrence, phi_p(T_m) e_1 = Z phi_p(Lambda) Z^T e_1
and the error bound |f(hi)|, f(mu) = sum_j Z_1j Z_mj phi_p[lambda_j, mu], of the stopping rule
(`agent_envs.native.lanczos_rule`). The eigensolver is the implicit QL iteration for
tridiagonal matrices (EISPACK's tql2; numpy's `eigh` calls LAPACK's syevd: both backward
stable), allocation-free, and it does not form Z: it records its plane rotations and carries
only Z's first and last rows, all that the error bound reads (O(m^2) per check instead of
O(m^3): a check at m = 25, as the first steps of an episode from a spread start need, cost
40 us with the full Z and 20 us without; `math.sqrt` of the sum of squares replaces
`math.hypot` in the rotations, whose entries are bounded by ||c L||); Z phi(Lambda) Z^T e_1 is
formed from the rotations once, at the accepted dimension (`apply_z`).

`phi` is `agent_envs.integrators.phi_dense.phi_scalar` for one float and `error_bound` is
`agent_envs.integrators.lanczos_stopping.error_bounds` for one member and column, the same
arithmetic in the same order: numba compiles scalar loops, the numpy executor runs the same
formulas vectorized over members, so the formulas are written twice and share every constant
(`lanczos_rule`). `error_model="numpy"`: divisions follow IEEE 754 (see `native.lanczos`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from agent_envs.native.lanczos_rule import CLOSE_GAP, TAYLOR_TERMS


@njit(cache=True, error_model="numpy")
def factorials(count: int) -> np.ndarray:
    """j! as floats for j < count (exact up to 22!)."""
    out = np.empty(count)
    value = 1.0
    for j in range(count):
        if j > 0:
            value *= j
        out[j] = value
    return out


@njit(cache=True, error_model="numpy")
def phi(z: float, order: int, fact: np.ndarray) -> float:
    """phi_order(z) for order >= 1, as `agent_envs.integrators.phi_dense.phi_scalar` computes it."""
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


@njit(cache=True, error_model="numpy")
def tridiagonal_ql(d, e, rows, m, rot_c, rot_s, rot_at) -> int:
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
    `apply_z` forms Z y for the one vector the phi-action needs."""
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
def apply_z(y, count, rot_c, rot_s, rot_at) -> None:
    """y <- Z y = G_1 (G_2 (... (G_K y))) in place, for the K rotations `tridiagonal_ql`
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
def phi_of_tridiagonal(alphas, betas, m, col, order, fact, out, d, e, rows, rot_c, rot_s,
                        rot_at, phis):  # fmt: skip
    """What the error bound of column `col` at dimension m reads (`error_bound`: the
    eigenvalues of T_m, rows 1 and m of its eigenvector matrix Z, phi_order of the eigenvalues;
    Saad's estimate: |e_m^T phi(T_m) e_1|), |phi(T_m) e_1|, and what `apply_z` needs to form
    phi_order(T_m) e_1 = Z phi(Lambda) Z^T e_1 (T_m from alphas[:m, col] and betas[:m - 1,
    col]): returns (last, size, K).

    All come from the eigenvalues and rows 1 and m of Z alone (|Z y| = |y| for the orthogonal
    Z), so a check that fails forms no coefficients. out[:m] receives
    y = phi(Lambda) Z^T e_1 and K >= 0 the rotations of Z (`tridiagonal_ql`), or, where the
    QL iteration gave up (more rotations than the buffers hold, from m above about 40, or more
    than 30 m iterations, not seen in practice), the coefficients themselves from LAPACK's
    eigh and K = -1 (a non-finite T: NaN throughout, so that no check passes). d, e (>= m),
    rows (2, >= m) and the rotation buffers are scratch; on
    return d[:m] holds the eigenvalues, rows[:, :m] Z's first and last rows and phis[:m]
    phi_order of the eigenvalues (what `error_bound` reads)."""
    for i in range(m):
        d[i] = alphas[i, col]
    for i in range(m - 1):
        e[i] = betas[i, col]
    count = tridiagonal_ql(d, e, rows, m, rot_c, rot_s, rot_at)
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
            phis[j] = phi(lam[j], order, fact)
        for i in range(m):
            acc = 0.0
            for j in range(m):
                acc += vectors[i, j] * (phis[j] * vectors[0, j])
            out[i] = acc
            size += acc * acc
        last = out[m - 1]
    else:
        for j in range(m):
            phis[j] = phi(d[j], order, fact)
            y = phis[j] * rows[0, j]
            out[j] = y
            last += rows[1, j] * y
            size += y * y
    return abs(last), math.sqrt(size), count


@njit(cache=True, error_model="numpy")
def error_bound(d, rows, phis, m, order, fact, hi) -> float:
    """|f(hi)|, f(mu) = sum_j g_j phi[lambda_j, mu], g_j = Z_1j Z_mj: the Lanczos error at
    dimension m is at most b_m |v| max over spec(A) of |f|, and f is positive and increasing,
    so its max over [lo, hi] is f(hi) (`agent_envs.integrators.lanczos_stopping.error_bounds`,
    the same arithmetic).
    phi[l, mu] = (phi(l) - phi(mu)) / (l - mu), phi'((l + mu) / 2) = phi_p - p phi_{p+1} there
    where |l - mu| <= 1e-6 max(1, |l|, |mu|)."""
    phi_mu = phi(hi, order, fact)
    acc = 0.0
    for j in range(m):
        lam = d[j]
        gap = lam - hi
        scale = max(max(abs(lam), abs(hi)), 1.0)
        if abs(gap) <= CLOSE_GAP * scale:
            mid = 0.5 * (lam + hi)
            dd = phi(mid, order, fact) - order * phi(mid, order + 1, fact)
        else:
            dd = (phis[j] - phi_mu) / gap
        acc += (rows[0, j] * rows[1, j]) * dd
    return abs(acc)
