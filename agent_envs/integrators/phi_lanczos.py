"""The Lanczos phi-action for symmetric A: one algorithm, its numpy and Array-API executors.

phi_p(A) v ~ |v| Q_m phi_p(T_m) e_1, T_m = Q_m^T A Q_m tridiagonal, by the three-term
recurrence b_j q_{j+1} = A q_j - a_j q_j - b_{j-1} q_{j-1}, with the coefficient of q_{j-1}
taken as the projection <A q_j - a_j q_j, q_{j-1}> (b_{j-1} up to rounding) and no
reorthogonalization against older vectors: for functions of a matrix with a bounded spectrum
the approximation converges in spite of the loss of orthogonality (Druskin, Greenbaum &
Knizhnerman, 1998); tests/test_phi_functions.py checks it against the dense eigh on the swarm's
L(x) and exact Jacobian. Stopped at a happy breakdown, or when an error bound is below
rtol |phi_p(T_m) e_1| (the rule of `agent_envs.native.lanczos_rule`, vectorized over members
in `agent_envs.integrators.lanczos_stopping`):

- where an interval [lo, hi] holding the spectrum is known (the frozen c L(x), c > 0:
  `spectrum_interval`), the bound b_m max_[lo, hi] |f| = b_m f(hi) of `error_bounds`, which the
  error reaches within a few per cent where it matters (part 2b of the former
  benchmarks/bench_throughput.py, docs/performance-notes.md: 4.83 dimensions per member and step
  on the paper setting, where the smallest that meet rtol are 4.78 and Saad's estimate took 6.13).
  Checked at m = `FIRST_BOUND_CHECK`, then at the
  dimension `next_checks` extrapolates from the last two checks;
- elsewhere Saad's estimate b_m |e_m^T phi_p(T_m) e_1|, checked every second step from
  m_0 = min(3.5 sqrt(|A|_inf), 3.5 sqrt(w)) (about the dimension below which the Krylov
  approximation of the exponential has not converged yet: 3.5 sqrt of the width of an interval
  holding the spectrum, by Hochbruck & Lubich 1997). It is the residual at t = 1, which
  overstates the error of a stiff A by about its smallest |eigenvalue| (40 on the swarm near
  consensus).

w is known for the frozen L(x) (A 1 = 0, A symmetric; `RowOperator.member_bounds`): it bounds
the spectrum on 1^perp, and the iteration runs on v - mean(v) 1, the mean's part
phi_p(0) mean(v) 1 added at the end (`_deflate_constant`): the eigenvalue 0 then costs no
Krylov dimension (one per step near consensus, where L is about -p_max on 1^perp). A member
that reaches `max_dim` first (also when m reaches n: the basis is then not exact) counts as not
converged.

Batch members (the leading axes; the k columns of one member stop together) are decided one by
one (`_Members`): each has its own |A|_inf, first check, breakdown tolerance and stopping
dimension m_i, and its result is Q_{m_i} phi_p(T_{m_i}) e_1 computed on its own. So a member's
result does not depend on what else is in the batch (the native vector env relies on this to
reproduce the single env exactly); the recurrence runs until the last member stops.

Three executors run this algorithm, sharing the start (`_start`), the per-member decisions
(`_Members.decide`: breakdown, checks, schedule), the assembly of the result (`_assemble`)
and every constant:

- `lanczos_action` (Array API: numpy and torch): out-of-place operations and a basis built as
  a list, so that autograd differentiates through the result on torch;
- `lanczos_numpy`: the same arithmetic (each floating-point operation the same, in the same
  order: tests/test_phi_functions.py checks the results are equal bit for bit) with in-place
  numpy updates of w, no namespace dispatch and the per-member decisions skipped before the
  earliest check. In-place updates would break autograd, hence the two recurrence loops;
- `agent_envs.native.lanczos` (numba) for the frozen L(x) on numpy: loops, one member at a
  time, equal to these to round-off (numba compiles no Python objects; see its docstring).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from agent_envs import arrays
from agent_envs.integrators.krylov_space import (
    RowOperator,
    gather_members,
    member_rows,
    stack_or_empty,
)
from agent_envs.integrators.lanczos_stopping import (
    check_bounds,
    first_checks,
    limits,
    schedule,
    spectrum_interval,
    vector_norms,
)
from agent_envs.integrators.phi_dense import phi_e1_and_eigh, phi_scalar, small_phi_e1
from agent_envs.native.lanczos_rule import BREAKDOWN_RTOL, MAX_CHECK_STEP, TINY

#: from this n on, Lanczos sums its basis vector by vector (no stacked copy)
ACCUMULATE_BASIS_MIN_N = 2**14


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


def _grad_enabled() -> bool:
    import torch

    return torch.is_grad_enabled()


class _Members:
    """The per-member state of one Lanczos run over a batch: bounds, check schedule, which
    members are done or converged, and the coefficients phi_p(T_m) e_1 of those that stopped.

    `stopped` maps a stopping dimension m to (the members that stopped there, their
    phi_p(T_m) e_1 (count, k, m)), as `gather_members` reads it. Arrays are over the batch."""

    def __init__(self, batch: tuple, bounds: tuple[np.ndarray, np.ndarray, np.ndarray],
                 order: int, rtol: float, max_dim: int, max_step: int, n: int) -> None:  # fmt: skip
        norm_inf, width, low = bounds
        self.batch, self.order, self.rtol = batch, order, rtol
        self.max_dim, self.max_step, self.n = max_dim, max_step, n
        _, self.hi, self.tight = spectrum_interval(norm_inf, width, low)
        self.next_check = first_checks(norm_inf, width, self.tight, max_dim)
        self.prev_m = np.zeros(batch)
        self.prev_ratio = np.zeros(batch)
        self.tiny = (BREAKDOWN_RTOL * (norm_inf + TINY))[..., None]  # (..., 1)
        self.done = np.zeros(batch, dtype=bool)
        self.converged = np.zeros(batch, dtype=bool)
        self.stopped: dict[int, tuple[np.ndarray, Any]] = {}

    def decide(
        self,
        m: int,
        b: np.ndarray,
        tridiagonal: Callable[[], Any],
        coefficients: Callable[[Any], tuple[Any, Any]],
    ) -> bool:
        """After the step to dimension m with b = b_m (..., k) on the host: which members stop
        (a breakdown: every column's b_m <= tiny; or m = max_dim) or pass their check, and the
        next check of those that fail. `tridiagonal()` gives T_m (..., k, m, m) and
        `coefficients(T)` (phi_p(T) e_1, its (eigenvalues, eigenvectors) or None) for the
        members that need it. Returns whether every member is done."""
        breakdown = ~self.done & np.all(b <= self.tiny, axis=-1)
        stops = breakdown | (~self.done & (m == self.max_dim))
        check = ~self.done & ~stops & (self.next_check == m)
        needed = stops | check
        if np.any(needed):
            t = tridiagonal()
            t = t[member_rows(needed, t)]
            coeffs, eig = coefficients(t)
            passed = np.zeros(self.batch, dtype=bool)
            if np.any(check):
                c = arrays.to_numpy(coeffs)
                if eig is None and np.any(self.tight[needed]):
                    # the bound reads a decomposition of its own (no autograd through a check)
                    eig = arrays.eigh(t.detach())
                bound = check_bounds(b[needed], eig, c, self.order, self.tight[needed],
                                     self.hi[needed])  # fmt: skip
                limit = limits(c, self.rtol)
                passed[needed] = np.all(bound <= limit, axis=-1) & check[needed]
                schedule(m, self.n, bound, limit, check & ~passed, self.tight, needed,
                         self.max_step, self.next_check, self.prev_m, self.prev_ratio)  # fmt: skip
            now = stops | passed
            if np.any(now):
                self.stopped[m] = (now, coeffs[member_rows(now[needed], coeffs)])
            self.converged |= breakdown | passed
            self.done |= now
        return bool(np.all(self.done))


def _start(
    xp: Any,
    a: RowOperator,
    v: Any,
    norms: Callable[[Any], Any],
    run: tuple[int, float, int, int, Any],
) -> tuple[Any, Any, Any, _Members] | None:
    """The first basis rows q_0 (..., k, n) (v's columns, deflated, normalized), |v - mean 1|
    (..., k), the means (or None) and the members' state, or None for an empty batch.
    run = (order, rtol, max_dim, max_step, bounds); `norms` is the executor's vector norm."""
    order, rtol, max_dim, max_step, bounds = run
    batch = tuple(np.broadcast_shapes(a.batch, tuple(v.shape[:-2])))
    if math.prod(batch) == 0:  # no member: nothing to iterate (the dense methods agree)
        return None
    q = xp.matrix_transpose(xp.broadcast_to(v, (*batch, *v.shape[-2:])))  # (..., k, n)
    member_bounds = a.member_bounds(batch, bounds)
    q, mean = _deflate_constant(xp, q, member_bounds[1])
    beta0 = norms(q)  # (..., k)
    if bool(xp.any(beta0 == 0)):
        q = q / xp.where(beta0 > 0, beta0, 1.0)[..., None]
    else:
        q = q / beta0[..., None]
    members = _Members(batch, member_bounds, order, rtol, min(max_dim, a.n), max_step, a.n)
    return q, beta0, mean, members


def _assemble(
    xp: Any, members: _Members, basis: list[Any], beta0: Any, mean: Any
) -> tuple[Any, np.ndarray]:
    """(|v| Q_{m_i} phi_p(T_{m_i}) e_1 + phi_p(0) mean 1 per member (..., n, k), converged)."""
    stopped, batch, order = members.stopped, members.batch, members.order
    if members.n >= ACCUMULATE_BASIS_MIN_N and len(stopped) == 1:
        # large n (matrix-free operators), every member stopped at one m: sum the basis vector
        # by vector instead of stacking a (..., k, m, n) copy of it (measured 0.4 s of a 2 s
        # SERB step at n = 10^6)
        ((m, (_, coeffs)),) = stopped.items()
        coeffs = xp.reshape(coeffs, (*batch, *coeffs.shape[-2:]))
        out = coeffs[..., 0:1] * basis[0]
        for j in range(1, m):
            out = out + coeffs[..., j : j + 1] * basis[j]
        result = xp.matrix_transpose(out * beta0[..., None])
        return _add_constant(result, mean, order), members.converged
    stacked = xp.stack(basis[: max(stopped)], axis=-2)
    result = gather_members(xp, stopped, stacked, beta0, batch)
    return _add_constant(result, mean, order), members.converged


def lanczos_action(
    a: RowOperator,
    v: Any,
    order: int,
    rtol: float,
    max_dim: int,
    max_step: int = MAX_CHECK_STEP,
    bounds: Any = None,
) -> tuple[Any, np.ndarray]:
    """phi_order(A) V (..., n, k) for symmetric A by Lanczos (module docstring), on numpy or
    torch: returns (result, converged per batch member). Differentiable on torch (list-built
    basis, no in-place writes to the basis). `max_step` caps the step between two checks;
    `bounds` as `RowOperator.member_bounds` reads them."""
    xp = arrays.namespace(*a.arrays, v)

    def norms(rows: Any) -> Any:
        return xp.linalg.vector_norm(rows, axis=-1)

    started = _start(xp, a, v, norms, (order, rtol, max_dim, max_step, bounds))
    if started is None:
        batch = tuple(np.broadcast_shapes(a.batch, tuple(v.shape[:-2])))
        return xp.zeros((*batch, *v.shape[-2:]), dtype=v.dtype), np.ones(batch, dtype=bool)
    q, beta0, mean, members = started
    batch = members.batch
    basis, alphas, betas = [q], [], []

    def coefficients(t: Any) -> tuple[Any, Any]:
        if arrays.is_torch(t) and t.requires_grad and _grad_enabled():
            return small_phi_e1(t, order, True), None  # (count, k, m), differentiable
        return phi_e1_and_eigh(t, order)

    w_prev = None
    for j in range(members.max_dim):
        w = a.apply(q)
        alpha = xp.vecdot(w, q)
        w = w - alpha[..., None] * q
        if w_prev is not None:
            # the three-term recurrence's b_{j-1} q_{j-1} term, with the coefficient computed
            # as the projection onto q_{j-1} (equal to b_{j-1} up to rounding)
            w = w - xp.vecdot(w, w_prev)[..., None] * w_prev
        b = xp.linalg.vector_norm(w, axis=-1)  # its gradient is 0 at 0 (sqrt is not)
        alphas.append(alpha)
        b_host = np.broadcast_to(arrays.to_numpy(b), (*batch, b.shape[-1]))

        def tridiagonal(alpha: Any = alpha) -> Any:
            t = arrays.tridiagonal(xp.stack(alphas, axis=-1), stack_or_empty(xp, betas, alpha))
            return xp.broadcast_to(t, (*batch, *t.shape[-3:]))

        # m == n without convergence: the space is exhausted but, without full
        # reorthogonalization, the basis is not exact; the caller then uses the dense method.
        if members.decide(j + 1, b_host, tridiagonal, coefficients):
            break
        small = b_host <= members.tiny
        if np.any(small):
            stop = arrays.asarray(small, like=w) > 0.5
            w = xp.where(stop[..., None], 0.0, w / xp.where(stop, 1.0, b)[..., None])
        else:
            w = w / b[..., None]
        betas.append(b)
        w_prev, q = q, w
        basis.append(q)
    return _assemble(xp, members, basis, beta0, mean)


def _numpy_coefficients(order: int) -> Callable[[np.ndarray], tuple[np.ndarray, Any]]:
    """phi_order(T) e_1 (count, k, m) and (eigenvalues, eigenvectors) of T (count, k, m, m) by
    numpy's eigh: `phi_e1_and_eigh`'s arithmetic without its dispatch, e_1 made once per m."""
    e1s: dict[int, np.ndarray] = {}

    def coefficients(t: np.ndarray) -> tuple[np.ndarray, Any]:
        m = t.shape[-1]
        if m not in e1s:
            e1s[m] = np.zeros((m, 1))
            e1s[m][0, 0] = 1.0
        lam, vectors = np.linalg.eigh(t)
        coef = np.swapaxes(vectors, -1, -2) @ e1s[m]
        return (vectors @ (phi_scalar(lam, order)[..., None] * coef))[..., 0], (lam, vectors)

    return coefficients


def lanczos_numpy(
    a: RowOperator,
    v: np.ndarray,
    order: int,
    rtol: float,
    max_dim: int,
    max_step: int = MAX_CHECK_STEP,
    bounds: Any = None,
) -> tuple[np.ndarray, np.ndarray]:
    """`lanczos_action` for numpy arrays with the per-step overhead taken out: the same
    recurrence, decisions and arithmetic, bit for bit, with in-place updates of w, no namespace
    dispatch in the recurrence and no per-member decision before the earliest first check.
    Returns (result, converged per member)."""
    xp = arrays.namespace(v)  # numpy's standard namespace (numpy 1.x: array-api-compat)
    started = _start(xp, a, v, vector_norms, (order, rtol, max_dim, max_step, bounds))
    if started is None:
        batch = tuple(np.broadcast_shapes(a.batch, tuple(v.shape[:-2])))
        return np.zeros((*batch, *v.shape[-2:])), np.ones(batch, dtype=bool)
    q, beta0, mean, members = started
    basis: list[np.ndarray] = [q]
    alphas: list[np.ndarray] = []
    betas: list[np.ndarray] = []
    earliest = int(members.next_check.min())
    coefficients = _numpy_coefficients(order)
    w_prev = None
    for j in range(members.max_dim):
        w = a.apply(q)
        alpha = xp.vecdot(w, q)
        w -= alpha[..., None] * q
        if w_prev is not None:
            w -= xp.vecdot(w, w_prev)[..., None] * w_prev
        b = vector_norms(w)
        alphas.append(alpha)
        m = j + 1
        small = b <= members.tiny
        any_small = bool(small.any())
        if any_small or m == members.max_dim or m >= earliest:

            def tridiagonal(alpha: np.ndarray = alpha) -> np.ndarray:
                return arrays.tridiagonal(np.stack(alphas, axis=-1),
                                          stack_or_empty(np, betas, alpha))  # fmt: skip

            if members.decide(m, b, tridiagonal, coefficients):
                break
        if any_small:
            w = np.where(small[..., None], 0.0, w / np.where(small, 1.0, b)[..., None])
        else:
            w /= b[..., None]
        betas.append(b)
        w_prev, q = q, w
        basis.append(q)
    return _assemble(np, members, basis, beta0, mean)
