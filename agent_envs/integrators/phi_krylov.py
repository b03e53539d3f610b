"""The Krylov phi-action: which executor computes phi_p(A) V by Krylov for a matrix or an
operator, returning (result, converged per batch member).

- symmetric A, the frozen L(x) on numpy with the compiled Lanczos loaded: the compiled
  executor (`agent_envs.integrators.phi_fused.compiled_frozen_lanczos`);
- other symmetric A: the Lanczos algorithm (`agent_envs.integrators.phi_lanczos`), its numpy
  executor on numpy, its Array-API executor on torch (differentiable);
- a general A: Arnoldi (`agent_envs.integrators.phi_arnoldi`).

With `add_product` = (W, e) the action is on V + e A W (SERB's F + sigma J dW), the product
taken inside the compiled pass where that serves, else first (`with_product`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from agent_envs import arrays, native
from agent_envs.dynamics.laplacian import FrozenLaplacian
from agent_envs.integrators.krylov_space import RowOperator
from agent_envs.integrators.phi_arnoldi import arnoldi_action
from agent_envs.integrators.phi_fused import compiled_frozen_lanczos
from agent_envs.integrators.phi_lanczos import lanczos_action, lanczos_numpy


def krylov_phi(
    a: Any,
    v: Any,
    order: int,
    symmetric: bool,
    rtol: float,
    max_dim: int,
    bounds: Any = None,
    add_product: Any = None,
) -> Any:
    """The Krylov phi-action (Lanczos if symmetric, else Arnoldi) on a matrix or an operator:
    (result, converged per batch member), of V + e A W for `add_product` = (W, e)."""
    if (
        symmetric
        and isinstance(a, FrozenLaplacian)
        and isinstance(v, np.ndarray)
        and native.available("lanczos")
    ):
        found = compiled_frozen_lanczos(a, v, order, rtol, max_dim, bounds, add_product)
        if found is not None:
            return found
    if add_product is not None:
        v = with_product(a, v, add_product)
    rows = RowOperator(a)
    if symmetric and not (arrays.is_torch(v) or arrays.is_torch(a)):
        return lanczos_numpy(rows, v, order, rtol, max_dim, bounds=bounds)
    if symmetric:
        return lanczos_action(rows, v, order, rtol, max_dim, bounds=bounds)
    return arnoldi_action(rows, v, order, rtol, max_dim, symmetric)


def with_product(a: Any, v: Any, add_product: tuple[Any, float]) -> Any:
    """V + e A W for `add_product` = (W, e)."""
    w, e = add_product
    return v + e * (a @ w)


def krylov_or_none(
    a: Any, v: Any, order: int, symmetric: bool, rtol: float, max_dim: int
) -> Any | None:
    """`krylov_phi`'s result when every member converged, else None."""
    result, converged = krylov_phi(a, v, order, symmetric, rtol, max_dim)
    return result if np.all(converged) else None
