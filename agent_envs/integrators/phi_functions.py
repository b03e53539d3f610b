"""Actions of the phi-functions of a matrix on a block of vectors: the entry points and the
choice of strategy.

    phi_0(z) = e^z,   phi_1(z) = (e^z - 1)/z,   phi_2(z) = (e^z - 1 - z)/z^2,
    phi_p(A) = int_0^1 e^{(1-s)A} s^{p-1}/(p-1)! ds      (p >= 1)

`phi_action(A, V, order)` returns phi_order(A) V for A of shape (..., n, n) and V of shape
(..., n, k), batched over leading axes. Three strategies, one implementation each, in modules
by job:

- ``"expm"``: the exponential of the augmented (n + p k) block matrix (Sidje's Expokit trick;
  `agent_envs.integrators.phi_dense.augmented_expm`). Dense, O((n+pk)^3); the reference for
  small n.
- ``"eigh"``: A = Q diag(lambda) Q^T for symmetric A, phi_p(A) V = Q phi_p(lambda) Q^T V
  (`agent_envs.integrators.phi_dense.eigh_action`), with a gradient finite at repeated
  eigenvalues on torch.
- ``"krylov"``: phi_p(A) v ~ |v| Q_m phi_p(H_m) e_1 on an orthonormal basis Q_m of
  span{v, Av, ..., A^{m-1} v}, H_m = Q_m^T A Q_m (`agent_envs.integrators.phi_krylov`).
  Symmetric A: Lanczos (`agent_envs.integrators.phi_lanczos`: three-term recurrence, H_m
  tridiagonal, stopped by an a posteriori error bound where an interval holding the spectrum
  is known (the swarm's frozen L(x)), else by Saad's estimate; compiled for the frozen L(x) by
  `agent_envs.integrators.phi_fused`); otherwise Arnoldi with classical Gram-Schmidt run twice
  (`agent_envs.integrators.phi_arnoldi`), stopped when two successive approximations agree to
  `rtol`. O(m n^2) for a dense A, so the method of choice for large n and for batches. If it
  has not converged at `max_krylov_dim`, a `RuntimeWarning` is issued and the dense method is
  used for the members that did not converge. On torch it is differentiated through its
  final basis. A matrix-free operator takes the Krylov method only, in substeps where its
  space does not converge (`agent_envs.integrators.phi_matrix_free`).

All three are written once for numpy and torch (`agent_envs.arrays`).

``"auto"`` picks "expm" for n <= 48; above that "krylov" for symmetric matrices except a single
one with n <= 80, and for non-symmetric ones "expm" up to n = 80 (up to 128 for a single
matrix), where it is still cheaper than Arnoldi, else "krylov": the crossovers
measured on numpy by benchmarks/bench_integrators.py (table 1) with one BLAS thread.
For a gradient on torch (forward and backward, N = 100 batched over 20 paths),
benchmarks/bench_gradient.py measures "krylov" cheapest, then "eigh", with "expm" far behind
(matrix_exp's backward is a second exponential of a doubled matrix); docs/benchmarks.md has
the numbers.

The entry points the integrators and envs call are here: `phi_action`, `auto_phi_method`,
`PHI_METHODS`, `phi_scalar`, the compiled switches `load_compiled` / `use_compiled` /
`load_compiled_threads` and the fused step `frozen_advance_applies` / `frozen_advance`.
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np

from agent_envs import arrays, native
from agent_envs.dynamics.laplacian import FrozenLaplacian
from agent_envs.integrators.krylov_space import is_operator
from agent_envs.integrators.phi_dense import augmented_expm, eigh_action, phi_scalar
from agent_envs.integrators.phi_fused import (
    frozen_advance,
    load_compiled,
    load_compiled_threads,
    use_compiled,
)
from agent_envs.integrators.phi_krylov import krylov_or_none, krylov_phi, with_product
from agent_envs.integrators.phi_matrix_free import substepped_operator_action

PHI_METHODS = ("auto", "expm", "eigh", "krylov")
# Crossovers of "auto" (measured by benchmarks/bench_integrators.py, one BLAS thread).
_AUTO_EXPM_MAX = 48
_AUTO_EXPM_SINGLE_MAX = 80
_AUTO_EXPM_SINGLE_NONSYMMETRIC_MAX = 128
# an operator this small whose Krylov space did not converge is made dense instead
_OPERATOR_DENSE_FALLBACK_MAX = 256

__all__ = [
    "PHI_METHODS",
    "auto_phi_method",
    "frozen_advance",
    "frozen_advance_applies",
    "load_compiled",
    "load_compiled_threads",
    "phi_action",
    "phi_scalar",
    "use_compiled",
]


def auto_phi_method(size: int, n_matrices: int, symmetric: bool) -> str:
    """The strategy ``method="auto"`` uses for `n_matrices` matrices of shape (size, size).

    Public so that a caller that batches several independent problems together (the native
    vector env stacks its envs on a leading axis) can fix the strategy each problem would get
    on its own, and so compute each one exactly as an unbatched call would.
    """
    single = n_matrices == 1
    if size <= _AUTO_EXPM_MAX:
        return "expm"
    if symmetric:
        return "expm" if single and size <= _AUTO_EXPM_SINGLE_MAX else "krylov"
    if size <= _AUTO_EXPM_SINGLE_MAX or (single and size <= _AUTO_EXPM_SINGLE_NONSYMMETRIC_MAX):
        return "expm"
    return "krylov"


def _auto_method(a: Any, v: Any, symmetric: bool) -> str:
    a_batch, v_batch = tuple(a.shape[:-2]), tuple(v.shape[:-2])
    # (np.broadcast_shapes and np.prod of a tuple: 10 us per SERB env step)
    batch = a_batch if a_batch == v_batch else np.broadcast_shapes(a_batch, v_batch)
    return auto_phi_method(a.shape[-1], math.prod(batch), symmetric)


def phi_action(
    a: Any,
    v: Any,
    order: int = 1,
    *,
    method: str = "auto",
    symmetric: bool = False,
    rtol: float = 1e-10,
    max_krylov_dim: int = 100,
    bounds: Any = None,
    add_product: tuple[Any, float] | None = None,
) -> Any:
    """phi_order(A) V for A (..., n, n) and V (..., n, k); returns (..., n, k).

    numpy or torch arrays (see `agent_envs.arrays`); on torch every strategy is differentiable.
    A may also be a matrix-free operator (an object with `matvec`, `shape`, `norm_inf`,
    `scaled`, e.g. `agent_envs.dynamics.operators.LinearizationOperator`): then the Krylov
    method is the only one ("auto" chooses it), and if its space does not converge within
    `max_krylov_dim` the action is taken in substeps (`substepped_operator_action`). A
    dense-backed operator (one with `dense()` and `apply_rows`, e.g.
    `agent_envs.dynamics.laplacian.FrozenLaplacian`) is treated as the matrix it stands for:
    "auto" picks as for that matrix, "expm"/"eigh" and the fallback use `dense()`.

    Args:
        a: the (already time-step scaled) matrix, e.g. tau J.
        v: the block of vectors.
        order: p >= 1.
        method: "auto", "expm", "eigh" (requires `symmetric=True`) or "krylov".
        symmetric: whether A is symmetric (enables "eigh").
        rtol: relative tolerance of the Krylov approximation.
        max_krylov_dim: largest Krylov dimension tried.
        bounds: (||A||_inf, width or None[, low or None]) per batch member, numpy arrays (low
            a float or an array), when the caller knows them (`Linearization.scaled_bounds`);
            the Lanczos iteration reads them instead of a pass over A (see `phi_lanczos`).
            A width may only be given for a symmetric A with A 1 = 0 (the frozen L(x)): it
            bounds spec(A) on 1^perp, and Lanczos deflates the constant vector. low, with a
            width, promises that spec(A) on 1^perp lies in [low, low + width] with low <= 0
            and A negative semidefinite (the frozen c L(x), c > 0: low = -c p_max): the
            iteration then stops by its error bound (`lanczos_stopping.error_bounds`), else by
            Saad's estimate. Without `bounds` a `FrozenLaplacian` gives all three itself.
        add_product: (W, e) with W shaped like V: phi_order(A) (V + e A W) instead, e.g.
            SERB's F + sigma J dW with A = tau J and e = 1 / tau. On the compiled frozen L(x)
            the product A W is taken in the same pass over each member's matrix as its
            Lanczos iteration; elsewhere it is taken first.
    """
    _check_arguments(order, method, max_krylov_dim)
    dense_backed = is_operator(a) and hasattr(a, "dense") and hasattr(a, "apply_rows")
    if is_operator(a) and not dense_backed:
        if add_product is not None:
            v = with_product(a, v, add_product)
        return _operator_action(a, v, order, method, symmetric, rtol, max_krylov_dim)
    if dense_backed:
        if arrays.is_torch(v):
            raise TypeError("a dense-backed operator acts on numpy arrays, got a torch tensor")
        v = np.asarray(v, dtype=float)
    elif not (arrays.is_torch(a) or arrays.is_torch(v)):
        a = np.asarray(a, dtype=float)
        v = np.asarray(v, dtype=float)
    elif arrays.is_torch(a) != arrays.is_torch(v):  # (no method mixes the two libraries)
        raise TypeError(
            "a and v must both be numpy arrays or both torch tensors, got "
            f"{type(a).__name__} and {type(v).__name__}"
        )
    if a.shape[-1] != a.shape[-2] or v.shape[-2] != a.shape[-1]:
        raise ValueError(f"shapes do not fit: A {tuple(a.shape)}, V {tuple(v.shape)}")
    if method == "auto":
        method = _auto_method(a, v, symmetric)
    if add_product is not None and method != "krylov":
        v, add_product = with_product(a, v, add_product), None
    if dense_backed and method != "krylov":
        a = a.dense()
    if method == "eigh":
        if not symmetric:
            raise ValueError("method='eigh' needs a symmetric matrix (symmetric=True)")
        return eigh_action(a, v, order)
    if method == "expm":
        return augmented_expm(a, v, order)
    result, converged = krylov_phi(
        a, v, order, symmetric, rtol, max_krylov_dim, bounds, add_product
    )
    if converged.all():
        return result
    if add_product is not None:
        v = with_product(a, v, add_product)
    if dense_backed:
        a = a.dense()
    return _dense_where_not_converged(a, v, order, symmetric, rtol, max_krylov_dim, result,
                                      converged)  # fmt: skip


def _check_arguments(order: int, method: str, max_krylov_dim: Any) -> None:
    """`phi_action`'s checks of its scalar arguments: order >= 1, an int max_krylov_dim >= 1, a
    method of `PHI_METHODS`."""
    if order < 1:
        raise ValueError(f"order must be >= 1, got {order}")
    if isinstance(max_krylov_dim, bool) or not isinstance(max_krylov_dim, (int, np.integer)):
        raise TypeError(f"max_krylov_dim must be an int >= 1, got {max_krylov_dim!r}")
    if max_krylov_dim < 1:
        raise ValueError(f"max_krylov_dim must be >= 1, got {max_krylov_dim}")
    if method not in PHI_METHODS:
        raise ValueError(f"method must be one of {PHI_METHODS}, got {method!r}")


def _dense_where_not_converged(
    a: Any,
    v: Any,
    order: int,
    symmetric: bool,
    rtol: float,
    max_krylov_dim: int,
    result: Any,
    converged: np.ndarray,
) -> Any:
    """The Krylov result where a member converged, the dense method's ("eigh" if symmetric,
    else "expm") elsewhere, with a `RuntimeWarning` unless Lanczos ran through the whole space.
    Only the members that did not converge get the dense method: the others keep their Krylov
    values, so a batch member's result never depends on the other members."""
    if not (symmetric and max_krylov_dim >= a.shape[-1]):
        # (when Lanczos ran through the whole space, n is small and the dense method as cheap)
        warnings.warn(
            f"Krylov phi-action did not reach rtol={rtol} within max_krylov_dim="
            f"{max_krylov_dim} (matrix size {a.shape[-1]}) for {int(np.sum(~converged))} of "
            f"{converged.size} matrices; falling back to dense "
            f"'{'eigh' if symmetric else 'expm'}' for those",
            RuntimeWarning,
            stacklevel=3,
        )
    dense = eigh_action(a, v, order) if symmetric else augmented_expm(a, v, order)
    if converged.ndim == 0 or not np.any(converged):
        return dense
    xp = arrays.namespace(result)
    keep = arrays.asarray(converged, like=result) > 0.5
    return xp.where(keep[..., None, None], result, dense)


def _operator_action(
    op: Any, v: Any, order: int, method: str, symmetric: bool, rtol: float, max_dim: int
) -> Any:
    """`phi_action` for a matrix-free operator (Krylov only)."""
    if method not in ("auto", "krylov"):
        raise ValueError(
            f"method={method!r} needs a matrix; a matrix-free operator takes 'auto' or 'krylov'"
        )
    if arrays.is_torch(v):
        raise TypeError("a matrix-free operator acts on numpy arrays, got a torch tensor")
    v = np.asarray(v, dtype=float)
    if v.ndim < 2 or v.shape[-2] != op.shape[-1]:
        raise ValueError(f"shapes do not fit: A {tuple(op.shape)}, V {tuple(v.shape)}")
    result = krylov_or_none(op, v, order, symmetric, rtol, max_dim)
    if result is None and op.shape[-1] <= _OPERATOR_DENSE_FALLBACK_MAX and hasattr(op, "dense"):
        # a small operator whose Krylov space ran out: its dense matrix is cheap
        return phi_action(op.dense(), v, order, method="auto", symmetric=symmetric)
    if result is None:
        result = substepped_operator_action(op, v, order, symmetric, rtol, max_dim)
    return result


def frozen_advance_applies(a: Any, rhs: Any, x: Any, noise: Any, method: str) -> bool:
    """Whether `frozen_advance` serves this exponential Rosenbrock-Euler step: A the symmetric
    kernel's frozen L(x) over a current workspace, the compiled Lanczos loaded, rhs, x and
    noise float64 numpy arrays of one shape batched exactly like P, and the phi-action's
    method "krylov" (or "auto" choosing it, as `phi_action` would). (Plain comparisons in the
    order of their cost: the check runs every env step.)"""
    if (
        type(x) is not np.ndarray
        or type(rhs) is not np.ndarray
        or type(noise) is not np.ndarray
        or method not in ("auto", "krylov")
        or not isinstance(a, FrozenLaplacian)
        or not a.symmetric
        or a.peak is None
        or x.dtype != np.float64
        or rhs.dtype != np.float64
        or noise.dtype != np.float64
    ):
        return False
    shape = x.shape
    if (
        rhs.shape != shape
        or noise.shape != shape
        or shape[:-1] != a.shape[:-1]
        or not a.current
        or not native.available("lanczos")
    ):
        return False
    return method == "krylov" or auto_phi_method(a.n, math.prod(shape[:-2]), True) == "krylov"
