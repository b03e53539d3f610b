"""What the Krylov phi-actions share: the row view of A, its per-member bounds, and the
gathering of each batch member's result.

phi_p(A) v ~ |v| Q_m phi_p(H_m) e_1 on an orthonormal basis Q_m of span{v, Av, ..., A^{m-1} v},
H_m = Q_m^T A Q_m (`agent_envs.integrators.phi_arnoldi`, `agent_envs.integrators.phi_lanczos`).
The recurrences act on rows: W (..., k, n) for the k columns of V (..., n, k), so a product is
``apply(W) = (A W^T)^T`` (`RowOperator`), for a dense (..., n, n) array or a matrix-free
operator. Each batch member stops at its own dimension m_i: `gather_members` forms
|v| Q_{m_i} c_i per member, (..., n, k).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from agent_envs import arrays


class RowOperator:
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
        (`agent_envs.integrators.phi_lanczos`). Without that knowledge it is inf. The bounds come
        from `bounds` (the caller's, e.g. `Linearization.scaled_bounds`), else from the
        operator's `krylov_bounds()`, else ||A||_inf of the matrix (one pass over A) or the
        operator's shared `norm_inf`. `low` is the bottom of an interval of that width holding
        spec(A) on 1^perp (`lanczos_stopping.spectrum_interval`), from a third entry of the
        bounds (nan where unknown or not given).
        """
        if bounds is None and self._op is not None and hasattr(self._op, "krylov_bounds"):
            bounds = self._op.krylov_bounds()
        if bounds is not None:
            return given_bounds(bounds, batch)
        if self._op is not None:
            norms = float(self._op.norm_inf)
        else:
            xp = arrays.namespace(self._a)
            norms = arrays.to_numpy(xp.max(xp.sum(xp.abs(self._a), axis=-1), axis=-1))
        return given_bounds((norms, None), batch)

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


def given_bounds(bounds: Any, batch: tuple) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(||A||_inf, width, low) float64 arrays of shape `batch` from bounds (norms, widths or
    None[, low or None]): width None is inf; low (the bottom of the interval of that width,
    `lanczos_stopping.spectrum_interval`) is nan where not given or without a width."""
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


def gather_members(
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
        out[member_rows(members, out)] = (
            coeffs[..., None, :] @ basis[member_rows(members, basis)]
        )[..., 0, :]
    return xp.matrix_transpose(out * beta[..., None])


def member_rows(mask: np.ndarray, like: Any) -> Any:
    """A boolean mask over the leading (batch) axes, usable as an index of `like`."""
    if arrays.is_torch(like):
        import torch

        return torch.as_tensor(mask, device=like.device)
    return mask


def stack_or_empty(xp: Any, items: list[Any], like: Any) -> Any:
    """The items (each shaped like `like`) stacked on a new last axis, or an empty (..., 0)
    array of `like`'s shape and dtype when there are none."""
    if items:
        return xp.stack(items, axis=-1)
    return xp.zeros((*like.shape, 0), dtype=like.dtype)
