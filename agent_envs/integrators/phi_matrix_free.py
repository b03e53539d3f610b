"""The phi-action of a matrix-free operator whose Krylov space did not converge, in substeps.

y = phi_p(A) v is y(1) for y' = A y + g(t), y(0) = 0, g(t) = v t^(p-1)/(p-1)! (p = 1, 2). For
g linear in t the step y(t + h) = y + h phi_1(hA)(A y + g(t)) + h^2 phi_2(hA) g' is exact, and
each action needs only the Krylov space of hA, of norm ||A|| / s (`agent_envs.integrators.
phi_krylov`). The operator is any object with `matvec` (..., n, k) -> (..., n, k) and
`scaled(h)` (e.g. `agent_envs.dynamics.operators.LinearizationOperator`); V (..., n, k).
"""

from __future__ import annotations

from typing import Any

from agent_envs.integrators.phi_krylov import krylov_or_none

_MAX_SUBSTEPS = 64


def substepped_operator_action(
    op: Any, v: Any, order: int, symmetric: bool, rtol: float, max_dim: int
) -> Any:
    """phi_order(A) V for an operator whose Krylov space did not converge, in s substeps.

    y = phi_p(A) v is y(1) for y' = A y + g(t), y(0) = 0, g(t) = v t^(p-1)/(p-1)! (p = 1, 2).
    For g linear in t the step y(t + h) = y + h phi_1(hA)(A y + g(t)) + h^2 phi_2(hA) g' is
    exact, and each action needs only the Krylov space of hA, of norm ||A|| / s. s doubles
    from 2 up to 64; a `RuntimeError` names `max_krylov_dim` if that is still not enough.
    """
    if order > 2:
        raise ValueError(f"a matrix-free phi-action of order {order} > 2 is not implemented")
    s = 2
    while s <= _MAX_SUBSTEPS:
        h = 1.0 / s
        hop = op.scaled(h)
        tail = None
        if order == 2:
            tail = krylov_or_none(hop, v, 2, symmetric, rtol, max_dim)
        y = None
        ok = tail is not None or order == 1
        for j in range(s if ok else 0):
            g = v * (j * h) if order == 2 else v
            rhs = g if y is None else op.matvec(y) + g
            step = krylov_or_none(hop, rhs, 1, symmetric, rtol, max_dim)
            if step is None:
                ok = False
                break
            step = h * step
            if tail is not None:
                step = step + h * h * tail
            y = step if y is None else y + step
        if ok:
            return y
        s *= 2
    raise RuntimeError(
        f"the matrix-free Krylov phi-action did not reach rtol={rtol} within max_krylov_dim="
        f"{max_dim}, even in {_MAX_SUBSTEPS} substeps; raise max_krylov_dim or shorten the step"
    )
