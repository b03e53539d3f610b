"""phi-functions of scalars and dense matrices: the scalar phi_p, the augmented exponential and
the symmetric eigendecomposition.

    phi_0(z) = e^z,   phi_1(z) = (e^z - 1)/z,   phi_2(z) = (e^z - 1 - z)/z^2,
    phi_p(A) = int_0^1 e^{(1-s)A} s^{p-1}/(p-1)! ds      (p >= 1)

- `phi_scalar`: phi_p(z) elementwise, accurate near 0 (a Taylor series there);
- `augmented_expm`: phi_p(A) V as a block of the exponential of the augmented (n + p k) block
  matrix [[A, V, 0], [0, 0, I], [0, 0, 0]] (Sidje's Expokit trick), via `scipy.linalg.expm` /
  `torch.linalg.matrix_exp` (Pade with scaling and squaring). Dense, O((n+pk)^3); the
  reference for small n;
- `eigh_action`: A = Q diag(lambda) Q^T for symmetric A, phi_p(A) V = Q phi_p(lambda) Q^T V. On
  torch its gradient comes from the Daleckii-Krein formula with divided differences of phi_p
  (`agent_envs.arrays.symmetric_function_action`), finite at repeated eigenvalues (the frozen
  L(x) at consensus), where torch.linalg.eigh's own backward is not;
- `small_phi_e1` / `phi_e1_and_eigh`: phi_p(H_m) e_1 for the small (m, m) projections of the
  Krylov methods (`agent_envs.integrators.phi_arnoldi`, `agent_envs.integrators.phi_lanczos`).

Written once for numpy and torch (`agent_envs.arrays`). Shapes: A (..., n, n), V (..., n, k),
batched over the leading axes.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from agent_envs import arrays
from agent_envs.native.lanczos_rule import TAYLOR_TERMS

#: below this |z| the torch gradient of phi_1 comes from its series (`phi_scalar`)
_TINY_PHI1 = 1e-7


def phi_scalar(z: Any, order: int) -> Any:
    """phi_order(z) elementwise for real z (numpy or torch), accurate near z = 0.

    |z| < 0.1: the Taylor series sum_j z^j / (j + p)!, 16 terms (Horner); otherwise
    (e^z - sum_{j<p} z^j / j!) / z^p with expm1. phi_1 is expm1(z)/z, accurate to round-off for
    every z != 0. Both branches are evaluated on safe arguments and combined with `where`, so
    autograd never sees a division by zero.
    """
    if not (arrays.is_torch(z) or isinstance(z, np.ndarray)):
        z = np.asarray(z, dtype=float)
    xp = arrays.namespace(z)
    if order == 0:
        return xp.exp(z)
    nonzero = z != 0
    z_safe = xp.where(nonzero, z, 1.0)
    if order == 1:
        with np.errstate(over="ignore"):
            value = xp.where(nonzero, xp.expm1(z_safe) / z_safe, 1.0)
        if arrays.is_torch(z) and z.requires_grad:
            # the same values, with the derivative 1/2 + z/3 of the series near 0: autograd of
            # expm1(z) / z cancels catastrophically below |z| ~ 1e-7 and the constant branch
            # at z = 0 has none
            tiny = xp.abs(z) < _TINY_PHI1
            series = 1.0 + z * (0.5 + z / 6.0)
            value = xp.where(tiny, value.detach() + (series - series.detach()), value)
        return value
    small = xp.abs(z) < 0.1
    zs = xp.where(small, z, 0.0)
    acc = xp.zeros_like(zs) + 1.0 / math.factorial(TAYLOR_TERMS - 1 + order)
    for j in range(TAYLOR_TERMS - 2, -1, -1):
        acc = acc * zs + 1.0 / math.factorial(j + order)
    zl = xp.where(small, 1.0, z)
    with np.errstate(over="ignore", invalid="ignore"):
        val = xp.expm1(zl)
        power = zl
        for j in range(1, order):
            val = val - power / math.factorial(j)
            power = power * zl
        return xp.where(small, acc, val / power)


def phi_derivative(z: Any, order: int) -> Any:
    """phi_order'(z) = phi_order(z) - order phi_{order+1}(z) (from the Taylor series)."""
    return phi_scalar(z, order) - order * phi_scalar(z, order + 1)


def augmented_expm(a: Any, v: Any, order: int) -> Any:
    """phi_order(A) V as a block of exp([[A, V, 0], [0, 0, I], [0, 0, 0]]) (Sidje)."""
    xp = arrays.namespace(a, v)
    n, k = a.shape[-1], v.shape[-1]
    size = n + order * k
    batch = tuple(np.broadcast_shapes(tuple(a.shape[:-2]), tuple(v.shape[:-2])))
    if arrays.is_numpy_namespace(xp):
        aug = np.zeros((*batch, size, size), dtype=np.result_type(a, v))
        aug[..., :n, :n] = a
        aug[..., :n, n : n + k] = v
        for j in range(1, order):
            aug[..., n + (j - 1) * k : n + j * k, n + j * k : n + (j + 1) * k] = np.eye(k)
    else:
        top = [xp.broadcast_to(a, (*batch, n, n)), xp.broadcast_to(v, (*batch, n, k))]
        if order > 1:
            top.append(arrays.zeros((*batch, n, (order - 1) * k), like=a))
        lower = np.zeros((order * k, size))
        for j in range(1, order):
            lower[(j - 1) * k : j * k, n + j * k : n + (j + 1) * k] = np.eye(k)
        lower = xp.broadcast_to(arrays.asarray(lower, like=a), (*batch, order * k, size))
        aug = xp.concat([xp.concat(top, axis=-1), lower], axis=-2)
    expo = arrays.expm(aug)
    return expo[..., :n, n + (order - 1) * k :]


def eigh_action(a: Any, v: Any, order: int) -> Any:
    return arrays.symmetric_function_action(
        a, v, lambda lam: phi_scalar(lam, order), lambda lam: phi_derivative(lam, order)
    )


def first_unit(m: int, like: Any) -> Any:
    """e_1 as an (m, 1) column in the library and on the device of `like`."""
    e1 = np.zeros((m, 1))
    e1[0, 0] = 1.0
    return arrays.asarray(e1, like=like)


def small_phi_e1(hess: Any, order: int, symmetric: bool) -> Any:
    """phi_order(H) e_1 for a batch of small (m, m) matrices H; returns (..., m)."""
    xp = arrays.namespace(hess)
    m = hess.shape[-1]
    e1 = first_unit(m, hess)
    if symmetric:
        # Arnoldi on a symmetric matrix gives a symmetric tridiagonal H (up to round-off).
        return eigh_action(hess, e1, order)[..., 0]
    e1 = xp.broadcast_to(e1, (*hess.shape[:-2], m, 1))
    return augmented_expm(hess, e1, order)[..., 0]


def phi_e1_and_eigh(t: Any, order: int) -> tuple[Any, tuple[Any, Any]]:
    """phi_order(T) e_1 (..., m) for symmetric tridiagonal T (..., m, m), with the
    eigendecomposition it came from: `small_phi_e1`'s operations (those of
    `arrays.symmetric_function_action`) for a T that needs no gradient, so that a convergence
    check reuses the decomposition instead of taking a second one."""
    e1 = first_unit(t.shape[-1], t)
    result, eig = arrays.eigh_function_action(t, e1, lambda lam: phi_scalar(lam, order))
    return result[..., 0], eig
