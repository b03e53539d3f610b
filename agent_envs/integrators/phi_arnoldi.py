"""The Arnoldi phi-action for a general (non-symmetric) A.

phi_p(A) v ~ |v| Q_m phi_p(H_m) e_1 with Q_m an orthonormal basis of span{v, ..., A^{m-1} v}
built by classical Gram-Schmidt run twice (CGS2) and H_m = Q_m^T A Q_m upper Hessenberg;
phi_p(H_m) e_1 by the augmented exponential (`agent_envs.integrators.phi_dense`). Checked every
`check_every` dimensions, stopped when two successive checks agree to `rtol`
(|c_m - c_prev| <= rtol |c_m|), at a happy breakdown (h_{m+1,m} <= 1e-12 max|A_kl|) or when
the basis spans the space. O(m n^2) for a dense A. Written once for numpy and torch (the basis
built as a list and stacked, so autograd differentiates through it).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from agent_envs import arrays
from agent_envs.integrators.krylov_space import (
    RowOperator,
    gather_members,
    member_rows,
)
from agent_envs.integrators.phi_dense import small_phi_e1


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


def arnoldi_action(
    a: RowOperator,
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
    `phi_lanczos.lanczos_action`, each batch member stops at its own dimension (its k columns
    together), so its result does not depend on the rest of the batch.
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
        coeffs = small_phi_e1(_hessenberg(columns, subdiag, m), order, symmetric)  # (..., k, m)
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
            stopped[m] = (now, coeffs[member_rows(now, coeffs)])
        converged |= exhausted | passed
        done |= now
        if np.all(done):
            break
        if not m % check_every:  # the regular checks compare with the previous regular one
            prev = coeffs
    return gather_members(xp, stopped, stacked, beta, batch), converged
