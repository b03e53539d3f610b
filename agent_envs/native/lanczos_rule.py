"""The Lanczos phi-action's stopping rule: one set of constants and its scalar rules.

Plain Python (no numba, no numpy): the one source of the rule that both executors of the
Lanczos phi-action run, the numpy one (`agent_envs.integrators.lanczos_stopping`, vectorized
over batch members) and the compiled one (`agent_envs.native.lanczos`, member by member, which
compiles `first_check`, `spectrum_top` and `next_check` below with numba). It sits in the
bottom layer so that the compiled leaf modules may import it: they import nothing above
`agent_envs.native`.

The rule, per batch member with its own ||A||_inf, width w of an interval holding spec(A) on
1^perp (inf where unknown) and bottom `low` of that interval (nan where unknown):

- breakdown: b_m <= `BREAKDOWN_RTOL` (||A||_inf + `TINY`) for every column (exact: stop);
- where [lo, hi] = [low, low + w] within [-||A||_inf, 0] is known (`spectrum_top`), the error
  bound b_m f(hi) (`agent_envs.integrators.lanczos_stopping.error_bounds`) is checked first at
  m = `FIRST_BOUND_CHECK`, then at the dimension `next_check` extrapolates from the last two
  checks (at most `MAX_CHECK_STEP` on; half way there below m = `FULL_STEP_FROM` n);
- elsewhere Saad's estimate b_m |e_m^T phi_p(T_m) e_1|, checked every `SAAD_CHECK_STEP`
  dimensions from m_0 = min(ceil(`SAAD_FIRST_FACTOR` sqrt(||A||_inf)),
  ceil(`SAAD_FIRST_FACTOR` sqrt(w))) within [2, max_dim] (`first_check`);
- a check passes where every column's bound <= rtol |phi_p(T_m) e_1| + `TINY`.

phi_p near 0 is its Taylor series with `TAYLOR_TERMS` terms; the divided difference
phi[l, mu] becomes phi_p'((l + mu) / 2) where |l - mu| <= `CLOSE_GAP` max(1, |l|, |mu|).
"""

from __future__ import annotations

import math

#: Taylor terms of phi_p near 0 (|z| < 0.1)
TAYLOR_TERMS = 16
#: The largest step between two convergence checks (`next_check`).
MAX_CHECK_STEP = 8
#: The dimension of the first check where the error bound applies. On the swarm a check below 4
#: fails every time: near consensus phi_p(A) v needs 4 dimensions (the error falls by about
#: 10^3 per dimension from 10^-3 at m = 1; of 300 members' phi-actions captured over two
#: paper-setting episodes, 91 % passed at 4 and none at 3), and the spread first steps of an
#: episode need 12-18. A first check at 3 cost 0.6 us per member and step for nothing (a
#: product costs 1 us).
FIRST_BOUND_CHECK = 4
#: From m >= FULL_STEP_FROM n a failed check schedules the next at the dimension the last two
#: checks extrapolate to, below it half way there (`next_check`): a check at m costs about
#: 0.03 m^2 us and a product with a dense n x n matrix about 1e-4 n^2 us, equal at m = 0.058 n.
FULL_STEP_FROM = 0.05
#: Saad's first check m_0 = ceil(SAAD_FIRST_FACTOR sqrt(width)) (Hochbruck & Lubich 1997)
SAAD_FIRST_FACTOR = 3.5
#: the step between two checks by Saad's estimate
SAAD_CHECK_STEP = 2
#: a happy breakdown: b_m <= BREAKDOWN_RTOL (||A||_inf + TINY)
BREAKDOWN_RTOL = 1e-12
#: the floor added to norms and limits so that a zero never divides or compares as equal
TINY = 1e-300
#: the relative gap below which a divided difference is taken as the derivative at the midpoint
CLOSE_GAP = 1e-6
#: the cap of a predicted step before its integer conversion (a ratio that barely falls
#: predicts about inf)
PREDICTION_CAP = 1e9


def first_check(norm: float, width: float, deflate: bool, tight: bool, max_dim: int) -> int:
    """The dimension of a member's first check: `FIRST_BOUND_CHECK` where the error bound
    applies (`tight`), else Saad's m_0 = min(ceil(3.5 sqrt(||A||_inf)), ceil(3.5 sqrt(w)))
    (the width term only where the constant vector is deflated: a finite w), within
    [2, max_dim]."""
    if tight:
        return min(FIRST_BOUND_CHECK, max_dim)
    first = math.ceil(SAAD_FIRST_FACTOR * math.sqrt(norm))
    if deflate:
        first = min(first, math.ceil(SAAD_FIRST_FACTOR * math.sqrt(width)))
    return int(min(max(first, 2.0), float(max_dim)))


def spectrum_top(norm: float, width: float, low: float) -> tuple[float, bool]:
    """The top hi of the interval [lo, hi] holding the spectrum the Lanczos vectors see, and
    whether it is known: [low, low + width] within [-norm, 0] for the deflated frozen c L with
    c > 0 (low = -c p_max, the bottom of spec(c L) on 1^perp; nan if unknown), (hi, True); else
    (norm, False): then the iteration keeps Saad's estimate and its schedule. (The bound reads
    only hi: the f it maximizes is increasing.)"""
    if width < math.inf and low <= 0.0:
        hi = min(low + width, 0.0)
        if max(low, -norm) <= hi:
            return hi, True
    return norm, False


def next_check(m: int, ratio: float, prev_m: int, prev_ratio: float, max_step: int, n: int) -> int:
    """The dimension of the next check after a failed one at m, ratio = bound / limit > 1 there
    and at the previous check (prev_m, prev_ratio; prev_m 0: none). Where the bound falls,
    m + ceil(log(ratio) (m - prev_m) / log(prev_ratio / ratio)) extrapolates the dimension it
    passes; the step is half of that (rounded up) below m = `FULL_STEP_FROM` n, all of it from
    there, within [1, max_step]; 1 without two checks or a falling bound."""
    step = 1
    if prev_m > 0 and prev_ratio > ratio and prev_ratio < math.inf and ratio < math.inf:
        predicted = math.log(ratio) * (m - prev_m) / math.log(prev_ratio / ratio)
        ahead = math.ceil(min(predicted, PREDICTION_CAP))
        if m < FULL_STEP_FROM * n:
            ahead = (ahead + 1) // 2
        step = max(1, min(max_step, ahead))
    return m + step
