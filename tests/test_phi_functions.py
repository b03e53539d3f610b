"""phi-function actions of every strategy against a 30-digit mpmath reference."""

import mpmath
import numpy as np
import pytest

from agent_envs.integrators.phi_functions import phi_action, phi_scalar


def _mp_phi(a: np.ndarray, v: np.ndarray, order: int) -> np.ndarray:
    """phi_order(A) v from the exponential of the augmented matrix in 30-digit arithmetic."""
    mpmath.mp.dps = 30
    n = a.shape[0]
    size = n + order
    aug = mpmath.zeros(size, size)
    for i in range(n):
        for j in range(n):
            aug[i, j] = mpmath.mpf(float(a[i, j]))
        aug[i, n] = mpmath.mpf(float(v[i]))
    for j in range(1, order):
        aug[n + j - 1, n + j] = 1
    expo = mpmath.expm(aug)
    return np.array([float(expo[i, size - 1]) for i in range(n)])


def _test_matrix(n, symmetric, scale, seed):
    rng = np.random.default_rng(seed)
    b = rng.normal(size=(n, n))
    if symmetric:
        a = -(b @ b.T) / n * scale  # negative definite, stiff for large scale
        a += 0.5 * np.eye(n)  # a few positive eigenvalues, like the exact Jacobian
    else:
        a = (b - 2 * np.eye(n) * np.sqrt(n)) * scale / n
    return a, rng.normal(size=n)


@pytest.mark.parametrize("order", [1, 2])
@pytest.mark.parametrize("symmetric", [True, False])
@pytest.mark.parametrize("scale", [0.1, 60.0])
def test_strategies_match_high_precision_reference(order, symmetric, scale):
    a, v = _test_matrix(12, symmetric, scale, seed=int(scale) + order)
    ref = _mp_phi(a, v, order)
    methods = ["expm", "krylov"] + (["eigh"] if symmetric else [])
    for method in methods:
        got = phi_action(a, v[:, None], order, method=method, symmetric=symmetric)[:, 0]
        np.testing.assert_allclose(
            got, ref, rtol=1e-9, atol=1e-11 * np.abs(ref).max(), err_msg=method
        )


def test_krylov_on_large_stiff_batched_matrix_matches_dense():
    rng = np.random.default_rng(0)
    n = 200
    b = rng.normal(size=(3, n, n))
    a = -np.einsum("bij,bkj->bik", b, b) / n * 40.0  # eigenvalues down to about -160
    v = rng.normal(size=(3, n, 2))
    dense = phi_action(a, v, 1, method="eigh", symmetric=True)
    krylov = phi_action(a, v, 1, method="krylov", symmetric=True)
    np.testing.assert_allclose(krylov, dense, rtol=1e-7, atol=1e-9)
    auto = phi_action(a, v, 1)
    np.testing.assert_allclose(auto, dense, rtol=1e-7, atol=1e-9)


def test_krylov_that_does_not_converge_warns_and_falls_back_to_dense():
    rng = np.random.default_rng(1)
    n = 120
    q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    a = (q * -np.logspace(0, 4, n)) @ q.T  # spectrum spread over [-1e4, -1]
    a = 0.5 * (a + a.T)
    v = rng.normal(size=(n, 1))
    with pytest.warns(RuntimeWarning, match="falling back"):
        got = phi_action(a, v, 1, method="krylov", symmetric=True, max_krylov_dim=10)
    np.testing.assert_allclose(
        got, phi_action(a, v, 1, method="eigh", symmetric=True), rtol=1e-10, atol=1e-14
    )


def test_phi_scalar_is_accurate_near_zero_and_far():
    z = np.array([0.0, 1e-9, 1e-3, 0.09, 0.11, -5.0, 3.0, -200.0])
    mpmath.mp.dps = 40
    for order in (1, 2, 3):
        ref = []
        for zz in z:
            zz = mpmath.mpf(float(zz))
            if zz == 0:
                ref.append(1.0 / float(mpmath.factorial(order)))
                continue
            val = mpmath.exp(zz) - sum(zz**j / mpmath.factorial(j) for j in range(order))
            ref.append(float(val / zz**order))
        np.testing.assert_allclose(phi_scalar(z, order), ref, rtol=1e-13)


def test_phi1_identity_a_phi1_equals_expm_minus_identity():
    a, v = _test_matrix(10, True, 5.0, seed=3)
    lhs = a @ phi_action(a, v[:, None], 1, method="krylov", symmetric=True)[:, 0]
    from scipy.linalg import expm

    np.testing.assert_allclose(lhs, expm(a) @ v - v, rtol=1e-9, atol=1e-12)


def test_bad_arguments():
    a = np.eye(3)
    with pytest.raises(ValueError, match="method"):
        phi_action(a, np.ones((3, 1)), method="pade")
    with pytest.raises(ValueError, match="symmetric"):
        phi_action(a, np.ones((3, 1)), method="eigh")
    with pytest.raises(ValueError, match="order"):
        phi_action(a, np.ones((3, 1)), order=0)
    with pytest.raises(ValueError, match="shapes"):
        phi_action(a, np.ones((4, 1)))


def test_krylov_broadcasts_vectors_over_a_batch_of_matrices():
    rng = np.random.default_rng(4)
    b = rng.normal(size=(3, 90, 90))
    a = -np.einsum("bij,bkj->bik", b, b) / 90 * 10.0
    v = rng.normal(size=(90, 1))  # no batch axis: shared by the three matrices
    for symmetric in (True, False):
        got = phi_action(a, v, 1, method="krylov", symmetric=symmetric)
        ref = phi_action(a, np.broadcast_to(v, (3, 90, 1)), 1, method="expm")
        np.testing.assert_allclose(got, ref, rtol=1e-8, atol=1e-10)
