"""phi-function actions of every strategy against a 30-digit mpmath reference."""

import math

import mpmath
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agent_envs.integrators.lanczos_stopping import next_checks
from agent_envs.integrators.phi_functions import phi_action, phi_scalar
from agent_envs.native.lanczos_rule import FULL_STEP_FROM


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
    # (0 wrote past the compiled Lanczos's basis with add_product: numba checks no bounds)
    with pytest.raises(ValueError, match="max_krylov_dim must be >= 1"):
        phi_action(a, np.ones((3, 1)), method="krylov", max_krylov_dim=0)
    with pytest.raises(TypeError, match="max_krylov_dim must be an int"):
        phi_action(a, np.ones((3, 1)), max_krylov_dim=2.5)


def test_krylov_broadcasts_vectors_over_a_batch_of_matrices():
    rng = np.random.default_rng(4)
    b = rng.normal(size=(3, 90, 90))
    a = -np.einsum("bij,bkj->bik", b, b) / 90 * 10.0
    v = rng.normal(size=(90, 1))  # no batch axis: shared by the three matrices
    for symmetric in (True, False):
        got = phi_action(a, v, 1, method="krylov", symmetric=symmetric)
        ref = phi_action(a, np.broadcast_to(v, (3, 90, 1)), 1, method="expm")
        np.testing.assert_allclose(got, ref, rtol=1e-8, atol=1e-10)


@pytest.mark.parametrize("symmetric", [True, False])
def test_a_member_that_does_not_converge_leaves_the_others_unchanged(symmetric):
    """Only the failing batch member falls back to the dense method: the others keep exactly
    the value they have when computed alone (one stiff path or env must not change the rest
    of the batch)."""
    rng = np.random.default_rng(3)
    n = 100
    q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    mild = (q * -np.linspace(0.0, 2.0, n)) @ q.T
    stiff = (q * -np.logspace(0, 8, n)) @ q.T  # needs far more than 30 Krylov vectors
    a = np.stack([mild, stiff])
    a = 0.5 * (a + np.swapaxes(a, -1, -2))
    if not symmetric:
        a = a + 1e-3 * rng.normal(size=(n, n))
    v = rng.normal(size=(n, 1))
    kw = {"method": "krylov", "symmetric": symmetric, "max_krylov_dim": 30}
    alone = phi_action(a[0], v, 1, **kw)
    with pytest.warns(RuntimeWarning, match="1 of 2 matrices"):
        batch = phi_action(a, v, 1, **kw)
    np.testing.assert_array_equal(batch[0], alone)
    dense = "eigh" if symmetric else "expm"
    np.testing.assert_allclose(
        batch[1], phi_action(a[1], v, 1, method=dense, symmetric=symmetric), rtol=1e-9
    )


def _swarm_laplacians(n_paths: int = 6, n: int = 100):
    """tau L(x) of the paper's swarm (dense arrays and the workspace operator) for spread,
    near-consensus and mixed states."""
    from agent_envs import SwarmModel, SwarmParams

    rng = np.random.default_rng(5)
    spread = rng.uniform(-1, 1, (n_paths, n, 1))
    consensus = 0.3 + 1e-4 * rng.standard_normal((n_paths, n, 1))
    model = SwarmModel(SwarmParams(n_agents=n))
    for x in (spread, consensus, np.concatenate([spread[:3], consensus[3:]])):
        _, lin = model.drift_and_linearization(0.0, x, None, "frozen")
        yield x, 0.02 * model.frozen_linearization(x), 0.02 * lin.matrix


@pytest.mark.parametrize("order", [1, 2])
@pytest.mark.parametrize("columns", [1, 2])
def test_numpy_lanczos_equals_the_reference_lanczos_bit_for_bit(order, columns):
    """The numpy Lanczos (`lanczos_numpy`) repeats `lanczos_action` operation by operation,
    on plain matrices (no bounds) and on the workspace operator (row-sum bounds)."""
    from agent_envs.integrators.krylov_space import RowOperator
    from agent_envs.integrators.phi_lanczos import lanczos_action, lanczos_numpy

    rng = np.random.default_rng(order + columns)
    for _, dense, operator in _swarm_laplacians():
        v = rng.standard_normal((dense.shape[0], 100, columns))
        v[0] = 0.0  # a zero member: the happy breakdown at m = 1
        for a in (dense, operator):
            got, got_ok = lanczos_numpy(RowOperator(a), v, order, 1e-10, 100)
            want, want_ok = lanczos_action(RowOperator(a), v, order, 1e-10, 100)
            np.testing.assert_array_equal(got, want)
            np.testing.assert_array_equal(got_ok, want_ok)
            assert np.all(got_ok)


@pytest.mark.parametrize("order", [1, 2])
@pytest.mark.parametrize("mean", [0.0, 3.0])
def test_lanczos_with_row_sum_bounds_matches_dense_to_the_tolerance(order, mean):
    """With the row-sum bounds the constant vector is deflated (phi_p(0) = 1/p! on the mean):
    against the dense eigh, for vectors with and without a mean, phi_1 and phi_2."""
    for _, dense, operator in _swarm_laplacians():
        v = np.random.default_rng(0).standard_normal((dense.shape[0], 100, 1)) + mean
        ref = phi_action(dense, v, order, method="eigh", symmetric=True)
        got = phi_action(operator, v, order, method="krylov", symmetric=True)
        scale = np.linalg.norm(ref, axis=-2, keepdims=True)
        assert np.max(np.abs(got - ref) / scale) < 1e-8


@pytest.mark.parametrize("order", [1, 2, 3])
def test_a_constant_vector_is_deflated_exactly(order):
    """phi_p(c L) (a 1) = a / p! (L 1 = 0): with the width known, the Lanczos iteration sees
    v - mean(v) 1 = 0, breaks down at m = 1 and returns the mean's part alone, exactly, in the
    numpy and the reference Lanczos (without the deflation the Krylov value is only within
    round-off of it); without the width (no deflation) the same value to the tolerance."""
    import math

    from agent_envs.integrators.krylov_space import RowOperator
    from agent_envs.integrators.phi_lanczos import lanczos_action, lanczos_numpy

    for _, dense, operator in _swarm_laplacians():
        v = np.full((dense.shape[0], 100, 2), 2.5)
        v[:, :, 1] = -0.75
        want = v / math.factorial(order)
        bounds = operator.krylov_bounds()
        assert bounds[1] is not None and np.all(np.isfinite(bounds[1]))
        for lanczos in (lanczos_numpy, lanczos_action):
            got, ok = lanczos(RowOperator(operator), v, order, 1e-10, 100, bounds=bounds)
            assert np.all(ok)
            np.testing.assert_array_equal(got, want)  # the mean's part alone, exactly
            plain, ok = lanczos(RowOperator(dense), v, order, 1e-10, 100)
            assert np.all(ok)
            np.testing.assert_allclose(plain, want, rtol=1e-9, atol=0)


@pytest.mark.parametrize("method", ["krylov", "eigh", "expm", "auto"])
def test_add_product_acts_on_v_plus_e_a_w(method):
    """phi_action(A, V, add_product=(W, e)) = phi_action(A, V + e A W) on the workspace
    operator (the compiled pass when numba is installed), a dense matrix and a torch tensor."""
    e = 1 / 0.02
    for _, dense, operator in _swarm_laplacians(n_paths=3):
        rng = np.random.default_rng(1)
        v = rng.standard_normal((3, 100, 1))
        w = 0.1 * rng.standard_normal((3, 100, 1))
        want = phi_action(dense, v + e * (dense @ w), 1, method="eigh", symmetric=True)
        scale = np.max(np.abs(want))
        for a in (operator, dense):
            got = phi_action(a, v, 1, method=method, symmetric=True, add_product=(w, e))
            assert np.max(np.abs(got - want)) <= 1e-9 * scale
        torch = pytest.importorskip("torch")
        got = phi_action(
            torch.tensor(dense), torch.tensor(v), 1, method=method, symmetric=True,
            add_product=(torch.tensor(w), e),
        )  # fmt: skip
        assert np.max(np.abs(got.numpy() - want)) <= 1e-9 * scale


@given(
    n=st.integers(2, 60),
    d=st.integers(1, 2),
    spread=st.sampled_from([1e-5, 0.05, 0.5, 2.0]),
    dt=st.sampled_from([0.02, 0.2]),
    order=st.integers(1, 3),
    mean=st.sampled_from([0.0, 4.0]),
    seed=st.integers(0, 2**16),
)
@settings(max_examples=60, deadline=None)
def test_deflated_krylov_matches_dense_on_any_swarm(n, d, spread, dt, order, mean, seed):
    """The frozen L(x)'s Krylov phi-action (constant vector deflated, the compiled Lanczos when
    numba is installed) against the dense eigh, for any N, d, spread, step, order and mean."""
    from agent_envs import SwarmModel, SwarmParams

    rng = np.random.default_rng(seed)
    model = SwarmModel(SwarmParams(n_agents=n, dim=d, epsilon=0.05), linear_operator="dense")
    x = rng.uniform(-spread, spread, (2, n, d))
    _, lin = model.drift_and_linearization(0.0, x, None, "frozen")
    v = rng.standard_normal((2, n, d)) + mean
    got = phi_action(dt * lin.matrix, v, order, method="krylov", symmetric=True)
    dense = dt * model.frozen_linearization(x)
    want = phi_action(dense, v, order, method="eigh", symmetric=True)
    scale = np.linalg.norm(want, axis=-2, keepdims=True)
    assert np.max(np.abs(got - want) / scale) < 1e-8


@pytest.mark.parametrize("order", [1, 2])
@pytest.mark.parametrize("scale", [0.02, 0.2])
def test_lanczos_error_bound_is_above_the_error(order, scale):
    """`error_bounds` on the frozen c L(x) of spread, consensus and mixed swarms: at every
    Krylov dimension, b_m max |f| over `spectrum_interval` is at least the error of the Lanczos
    approximation against the dense eigh value (where that error is above round-off), and,
    below 1e-6, within a factor 30 of it: the max over the interval is taken where the
    spectrum may be, and a spread swarm at c = 0.2 spans [-400, 0] (12x there; 1.01x near
    consensus, where Saad's estimate overstates the error by about c p_max)."""
    from agent_envs.integrators.lanczos_stopping import error_bounds, spectrum_interval

    rng = np.random.default_rng(order)
    checked = 0
    for _, dense, operator in _swarm_laplacians():
        dense, operator = dense * (scale / 0.02), operator * (scale / 0.02)
        norms, widths, low = operator.krylov_bounds()
        lo, hi, tight = spectrum_interval(norms, widths, np.full(norms.shape, low))
        assert tight.all()
        for member in range(dense.shape[0]):
            a = dense[member]
            lam, z = np.linalg.eigh(a)
            v = rng.standard_normal(a.shape[0])
            v -= v.mean()  # the deflated vector: Lanczos on 1^perp
            exact = z @ (phi_scalar(lam, order) * (z.T @ v))
            basis, alphas, betas = [v / np.linalg.norm(v)], [], []
            for m in range(1, 30):
                w = a @ basis[-1]
                alphas.append(w @ basis[-1])
                w = w - alphas[-1] * basis[-1]
                if m > 1:
                    w = w - (w @ basis[-2]) * basis[-2]
                b = np.linalg.norm(w)
                t = np.diag(alphas) + np.diag(betas, 1) + np.diag(betas, -1)
                tl, tz = np.linalg.eigh(t)
                phis = phi_scalar(tl, order)
                approx = np.linalg.norm(v) * (np.array(basis).T @ (tz @ (phis * tz[0])))
                error = np.linalg.norm(approx - exact) / np.linalg.norm(v)
                bound = b * error_bounds(
                    tl[None, None], tz[0][None, None], tz[-1][None, None], phis[None, None],
                    order, hi[member : member + 1],
                )[0, 0]  # fmt: skip
                if error > 1e-12 * np.linalg.norm(exact) / np.linalg.norm(v):
                    assert bound >= 0.999 * error, (member, m, bound, error)
                    # f is increasing: its max over the interval is at the top (to 1e-4: near
                    # consensus f, an m-th divided difference, is a sum of first-order ones
                    # that cancel)
                    mus = np.linspace(lo[member], hi[member], 9)
                    f = np.array([
                        error_bounds(tl[None, None], tz[0][None, None], tz[-1][None, None],
                                      phis[None, None], order, np.array([mu]))[0, 0]
                        for mu in mus
                    ])  # fmt: skip
                    assert np.all(np.diff(f) >= -1e-4 * f[-1]), (member, m, f)
                    assert f[-1] >= 0.9999 * np.max(f)
                    if error < 1e-6:  # where the stopping decisions are taken
                        assert bound <= 30 * error, (member, m, bound, error)
                    checked += 1
                if b <= 1e-12:
                    break
                betas.append(b)
                basis.append(w / b)
    assert checked > 50


@pytest.mark.parametrize("method", ["krylov", "eigh", "expm", "auto"])
def test_an_empty_batch_gives_an_empty_result(method):
    """No batch member: every method returns the (0, n, k) result (the Lanczos iteration raised
    on the minimum of an empty array)."""
    torch = pytest.importorskip("torch")

    for a, v in (
        (np.zeros((0, 5, 5)), np.zeros((0, 5, 2))),
        (torch.zeros((0, 5, 5), dtype=torch.float64), torch.zeros((0, 5, 2), dtype=torch.float64)),
    ):
        got = phi_action(a, v, 1, method=method, symmetric=True)
        assert tuple(got.shape) == (0, 5, 2)


def test_check_schedule_steps_half_way_then_all_the_way():
    """A bound falling by 10x per dimension, 1e4 over its limit at m and 1e5 at the check
    before: the next check is 4 dimensions on where a check costs more than a product
    (m >= FULL_STEP_FROM n), half way (2 on) below, never more than max_step on, and 1 on
    without a previous check or where the bound did not fall."""
    n = 100
    big = math.ceil(FULL_STEP_FROM * n)
    one = np.ones(1)
    assert next_checks(big, 1e4 * one, (big - 1) * one, 1e5 * one, 8, n)[0] == big + 4
    assert next_checks(big - 1, 1e4 * one, (big - 2) * one, 1e5 * one, 8, n)[0] == big + 1
    assert next_checks(big, 1e4 * one, (big - 1) * one, 1e5 * one, 3, n)[0] == big + 3
    assert next_checks(big, 1e4 * one, 0 * one, 0 * one, 8, n)[0] == big + 1
    assert next_checks(big, 1e4 * one, (big - 1) * one, 1e3 * one, 8, n)[0] == big + 1


def test_numpy_stopping_rule_is_the_scalar_rule_member_by_member():
    """One stopping rule: the numpy executor's vectorized `spectrum_interval`, `first_checks`
    and `next_checks` give, member by member, what the plain-Python rules of
    `agent_envs.native.lanczos_rule` give (the functions the compiled executor compiles), over
    bounds with and without a known interval and a grid of check histories."""
    from agent_envs.integrators.lanczos_stopping import first_checks, spectrum_interval
    from agent_envs.native import lanczos_rule

    norms = np.array([0.5, 4.0, 40.0, 400.0, 40.0, 40.0, 1e-3])
    widths = np.array([0.2, np.inf, 30.0, 100.0, 30.0, 0.0, np.inf])
    lows = np.array([-0.3, np.nan, -35.0, np.nan, 1.0, -2.0, -1.0])
    _, hi, tight = spectrum_interval(norms, widths, lows)
    for max_dim in (3, 100):
        first = first_checks(norms, widths, tight, max_dim)
        for i in range(norms.size):
            top, known = lanczos_rule.spectrum_top(norms[i], widths[i], lows[i])
            assert (hi[i], tight[i]) == (top, known)
            deflate = bool(np.isfinite(widths[i]))
            want = lanczos_rule.first_check(norms[i], widths[i], deflate, known, max_dim)
            assert first[i] == want
    for n in (20, 100, 400):
        for m in (3, 4, 5, 9, 19, 25):
            for prev_m in (0, 1, m - 1):
                for prev_ratio in (0.0, 2.0, 1e3, np.inf):
                    ratio = np.array([1.5, 10.0, 1e3, 1e30, np.inf])
                    got = next_checks(
                        m, ratio, np.full(5, float(prev_m)), np.full(5, prev_ratio), 8, n
                    )
                    want = [lanczos_rule.next_check(m, r, prev_m, prev_ratio, 8, n) for r in ratio]
                    np.testing.assert_array_equal(got, want)
