"""The Lanczos stopping rule vectorized over batch members: the error bound and the check
schedule of the numpy and Array-API executors (`agent_envs.integrators.phi_lanczos`).

The rule and its constants are `agent_envs.native.lanczos_rule`'s (its docstring states it);
the compiled executor (`agent_envs.native.lanczos`) runs its scalar functions member by member.
Here the same formulas run on numpy arrays over the members that check at a dimension m:

- `spectrum_interval`: [lo, hi] holding spec(A) on 1^perp per member, and whether it is known;
- `first_checks`: the first check, `FIRST_BOUND_CHECK` or Saad's m_0;
- `check_bounds`: b_m |f(hi)| (`error_bounds`) or Saad's b_m |e_m^T phi_p(T_m) e_1|, against
  `limits` = rtol |phi_p(T_m) e_1| + TINY;
- `schedule` / `next_checks`: the next check of the members that failed.

Why a second copy of the scalar rule: numba compiles scalar loops and the compiled executor
decides one member at a time, while here one numpy operation decides every member at once (a
Python loop over members would cost more than the check); both read the same constants, and
tests/test_compiled_lanczos.py checks that the two schedules agree on a grid of inputs.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from agent_envs import arrays
from agent_envs.integrators.phi_dense import phi_scalar
from agent_envs.native.lanczos_rule import (
    CLOSE_GAP,
    FIRST_BOUND_CHECK,
    FULL_STEP_FROM,
    PREDICTION_CAP,
    SAAD_CHECK_STEP,
    SAAD_FIRST_FACTOR,
    TINY,
)


def _saad_first_checks(norm_inf: np.ndarray, width: np.ndarray) -> np.ndarray:
    """The Krylov dimension m_0 of the first convergence check with Saad's estimate, per member
    (before clipping): min(3.5 sqrt(|A|_inf), 3.5 sqrt(w)), w the width of an interval holding
    spec(A) on the complement of the deflated constant vector (inf where unknown)."""
    return np.minimum(
        np.ceil(SAAD_FIRST_FACTOR * np.sqrt(norm_inf)), np.ceil(SAAD_FIRST_FACTOR * np.sqrt(width))
    )


def first_checks(
    norm_inf: np.ndarray, width: np.ndarray, tight: np.ndarray, max_dim: int
) -> np.ndarray:
    """Per member, the dimension of the first check: `FIRST_BOUND_CHECK` where the error bound
    applies (`tight`), else Saad's m_0 (`_saad_first_checks`), within [2, max_dim]."""
    first = np.clip(_saad_first_checks(norm_inf, width), 2, max_dim)
    return np.where(tight, min(FIRST_BOUND_CHECK, max_dim), first).astype(np.int64)


def spectrum_interval(
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


def error_bounds(lam: Any, first: Any, last: Any, phis: Any, order: int, hi: Any) -> Any:
    """|f(hi)|, f(mu) = sum_j g_j phi[lambda_j, mu], per member and column: the Lanczos error
    bound at dimension m over b_m |v|.

    With A Q_m = Q_m T_m + b_m q_{m+1} e_m^T and T_m = Z diag(lambda) Z^T, the error of
    |v| Q_m phi_p(T_m) e_1 is |v| b_m f(A) q_{m+1} (A symmetric, exact arithmetic), with
    g_j = Z_1j Z_mj and the divided difference phi[l, mu] = (phi_p(l) - phi_p(mu)) / (l - mu):
    the error e(t) of t^p phi_p(t A) v solves e' = A e + r(t) with the residual
    r(t) = |v| b_m t^p e_m^T phi_p(t T_m) e_1 q_{m+1}, so e(1) = int_0^1 e^{(1-t) A} r(t) dt,
    and int_0^1 e^{(1-t) mu} t^p phi_p(t l) dt = exp[mu, l, 0, ..., 0] (p zeros) = phi[l, mu].
    Hence |error| <= |v| b_m max over spec(A) of |f|, spec(A) in [lo, hi]
    (`spectrum_interval`). And f(mu) = (b_1 ... b_{m-1}) phi_p[lambda_1, ..., lambda_m, mu]
    (sum_j g_j h(lambda_j) is that multiple of the divided difference of any h on the Ritz
    values), positive and increasing in mu since every derivative of phi_p is positive
    (phi_p(z) = int_0^1 e^{(1-s) z} s^{p-1} / (p-1)! ds): the max is f(hi). Where
    |l - hi| <= 1e-6 max(1, |l|, |hi|) the divided difference is phi_p'((l + hi) / 2) =
    phi_p - p phi_{p+1} there. Unlike Saad's estimate b_m |e_m^T phi_p(T_m) e_1| (the residual
    at t = 1), it is not inflated by the stiffness: on the swarm near consensus (spec(A) on
    1^perp about -c p_max) the error is the residual divided by about c p_max.

    lam, first, last (Z's first and last rows), phis = phi_p(lam): (count, k, m) numpy arrays;
    hi (count,). Returns (count, k). The sum runs over j in order, as the compiled
    `native.lanczos_tridiagonal.error_bound` does.
    """
    m = lam.shape[-1]
    hi = np.asarray(hi, dtype=np.float64)[:, None]  # (count, 1)
    phi_hi = phi_scalar(hi, order)
    acc = None
    for j in range(m):
        lam_j = lam[..., j]  # (count, k)
        gap = lam_j - hi
        scale = np.maximum(np.maximum(np.abs(lam_j), np.abs(hi)), 1.0)
        close = np.abs(gap) <= CLOSE_GAP * scale
        term = (phis[..., j] - phi_hi) / np.where(close, 1.0, gap)
        if close.any():
            mid = 0.5 * (lam_j + hi)
            slope = phi_scalar(mid, order) - order * phi_scalar(mid, order + 1)
            term = np.where(close, slope, term)
        term = (first[..., j] * last[..., j]) * term
        acc = term if acc is None else acc + term
    return np.abs(acc)


def next_checks(
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
      (part 2b of the former benchmarks/bench_throughput.py, docs/performance-notes.md), and an
      episode's first steps (m = 12-18) took five or six checks half way against three or four
      now.

    n is the size of A (the matrices the members' checks run on are at most max_dim)."""
    m_arr = np.full(ratio.shape, float(m))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        known = (prev_m > 0) & (prev_ratio > ratio) & (prev_ratio < np.inf) & (ratio < np.inf)
        # (capped at 1e9 as the compiled rule caps it before its integer conversion)
        predicted = np.ceil(
            np.minimum(
                np.log(ratio) * (m_arr - prev_m) / np.log(np.where(known, prev_ratio / ratio, 2.0)),
                PREDICTION_CAP,
            )
        )
        predicted = np.where(known, predicted, 1.0)
    ahead = predicted if m >= FULL_STEP_FROM * n else (predicted + 1) // 2
    step = np.where(known, np.clip(ahead, 1, max_step), 1)
    return (m + step).astype(np.int64)


def check_bounds(
    b: np.ndarray,
    eig: tuple[Any, Any],
    coeffs: Any,
    order: int,
    tight: np.ndarray,
    hi: np.ndarray,
) -> np.ndarray:
    """The error bounds (count, k) of the checked members (all arrays over them): b_m max |f|
    (`error_bounds`, f at the top `hi` of the spectrum's interval) where `tight`, Saad's
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
        exact = error_bounds(lam, first, last, phi_scalar(lam, order), order, hi[tight])
        bound[tight] = b[tight] * exact
    return bound


def vector_norms(w: np.ndarray) -> np.ndarray:
    """||w|| along the last axis: numpy's vector_norm arithmetic (sqrt of the pairwise sum of
    w * w) without its argument handling."""
    return np.sqrt(np.add.reduce(w * w, axis=-1))


def limits(coeffs: np.ndarray, rtol: float) -> np.ndarray:
    """rtol |phi_p(T_m) e_1| + 1e-300 per checked member and column (count, k): what each
    column's error bound must not exceed."""
    return rtol * vector_norms(coeffs) + TINY


def schedule(
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
    (`limits`) are over the `needed` members): their next check (`next_checks`) and their
    (m, ratio) for the one after, in place. ratio = the largest bound / limit of a failing
    column, as the compiled iteration takes it. Members without the bound (`tight`
    False: Saad's estimate) check every second dimension."""
    legacy = failed & ~tight
    next_check[legacy] = m + SAAD_CHECK_STEP
    failed = failed & tight
    if not failed.any():
        return
    ratios = np.max(np.where(bound <= limit, 0.0, bound / limit), axis=-1)
    ratio = ratios[failed[needed]]
    next_check[failed] = next_checks(m, ratio, prev_m[failed], prev_ratio[failed], max_step, n)
    prev_m[failed] = m
    prev_ratio[failed] = ratio
