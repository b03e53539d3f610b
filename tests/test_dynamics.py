"""Kernel gradients and the exact Jacobian against finite differences; structure of L(x)."""

import numpy as np
import pytest

from agent_envs import SwarmModel, SwarmParams
from agent_envs.dynamics.kernels import CuckerSmaleKernel


def _params(kernel, dim, n=7):
    return SwarmParams(n_agents=n, dim=dim, kernel=kernel, epsilon=0.3, alpha=0.4)


def _fd_jacobian(model, x, h=1e-6):
    """Central differences of the drift, agent-major flattening: (Nd, Nd)."""
    n, d = x.shape
    flat = x.reshape(-1)
    jac = np.empty((n * d, n * d))
    for j in range(n * d):
        e = np.zeros(n * d)
        e[j] = h
        fp = model.drift(0.0, (flat + e).reshape(n, d))
        fm = model.drift(0.0, (flat - e).reshape(n, d))
        jac[:, j] = (fp - fm).reshape(-1) / (2 * h)
    return jac


@pytest.mark.parametrize("kernel", ["symmetric", "nonsymmetric"])
@pytest.mark.parametrize("dim", [1, 2])
def test_exact_jacobian_matches_finite_differences(kernel, dim):
    model = SwarmModel(_params(kernel, dim))
    x = np.random.default_rng(1).uniform(-1, 1, (7, dim))
    jac = model.jacobian(x)
    assert jac.shape == (7 * dim, 7 * dim)
    np.testing.assert_allclose(jac, _fd_jacobian(model, x), rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("dim", [1, 2])
def test_kernel_gradients_match_finite_differences(dim):
    kernel = CuckerSmaleKernel.nonsymmetric_kernel(0.3, 0.1, 0.5, 5)
    rng = np.random.default_rng(2)
    x = rng.uniform(-1, 1, (5, dim))
    xk, xl = x[:, None, :], x[None, :, :]
    h = 1e-6
    for i in range(dim):
        e = np.zeros(dim)
        e[i] = h
        dx = (kernel.value(xk + e, xl) - kernel.value(xk - e, xl)) / (2 * h)
        dy = (kernel.value(xk, xl + e) - kernel.value(xk, xl - e)) / (2 * h)
        np.testing.assert_allclose(kernel.grad_x(xk, xl)[..., i], dx, rtol=1e-6, atol=1e-8)
        np.testing.assert_allclose(kernel.grad_y(xk, xl)[..., i], dy, rtol=1e-6, atol=1e-8)


def test_drift_is_frozen_linearization_times_state_and_batched():
    model = SwarmModel(SwarmParams(n_agents=6, dim=2, kernel="nonsymmetric"))
    x = np.random.default_rng(3).uniform(-1, 1, (4, 3, 6, 2))
    u = np.random.default_rng(4).normal(size=(6, 2))
    lx = model.frozen_linearization(x)
    assert lx.shape == (4, 3, 6, 6)
    np.testing.assert_allclose(model.drift(0.0, x, u), lx @ x + u)
    # the batched call equals the one-by-one calls
    np.testing.assert_allclose(model.drift(0.0, x)[2, 1], model.drift(0.0, x[2, 1]))
    # explicit double sum of eq:dynamics
    n = 6
    xs = x[0, 0]
    p = model.interaction_matrix(xs)
    direct = np.array([sum(p[k, j] * (xs[j] - xs[k]) for j in range(n)) / n for k in range(n)])
    np.testing.assert_allclose(model.interaction_drift(xs), direct)


def test_frozen_linearization_is_minus_a_laplacian():
    model = SwarmModel(SwarmParams(n_agents=30, epsilon=0.05))
    x = np.random.default_rng(5).uniform(-1, 1, (30, 1))
    lx = model.frozen_linearization(x)
    np.testing.assert_allclose(lx.sum(axis=1), 0.0, atol=1e-10)  # rows sum to zero
    np.testing.assert_allclose(lx, lx.T)
    assert np.max(np.linalg.eigvalsh(lx)) < 1e-9  # negative semi-definite


def test_exact_jacobian_is_indefinite_when_agents_are_spread():
    """The finding behind the default jacobian='frozen': J has positive eigenvalues."""
    model = SwarmModel(SwarmParams(n_agents=100, epsilon=0.05, alpha=0.1))
    x = np.linspace(-1, 1, 100)[:, None]
    eig = np.linalg.eigvalsh(model.jacobian(x))
    assert eig.max() > 50.0
    assert np.max(np.linalg.eigvalsh(model.frozen_linearization(x))) < 1e-9


def test_user_kernel_is_accepted():
    class Gaussian:
        symmetric = True

        def value(self, xk, xl):
            return np.exp(-np.sum((xk - xl) ** 2, axis=-1))

        def grad_x(self, xk, xl):
            return -2 * (xk - xl) * self.value(xk, xl)[..., None]

        def grad_y(self, xk, xl):
            return -self.grad_x(xk, xl)

    model = SwarmModel(SwarmParams(n_agents=5, dim=2, kernel=Gaussian()))
    x = np.random.default_rng(6).uniform(-1, 1, (5, 2))
    np.testing.assert_allclose(model.jacobian(x), _fd_jacobian(model, x), rtol=1e-6, atol=1e-7)


def test_bad_state_shape_is_rejected():
    model = SwarmModel(SwarmParams(n_agents=5))
    for shape in [(4, 1), (6, 1), (5, 2), (5,)]:  # fewer or more agents or coordinates
        with pytest.raises(ValueError, match=r"\(\.\.\., 5, 1\)"):
            model.drift(0.0, np.zeros(shape))


def test_a_user_kernel_returning_a_read_only_array_is_not_written_into():
    """The frozen linearization must not modify (or fail on) the array a user kernel returns."""

    class ConstantKernel:
        symmetric = True

        def __init__(self, n: int) -> None:
            self.matrix = np.full((n, n), 2.0)
            self.matrix.flags.writeable = False

        def value(self, xk, xl):
            return np.broadcast_to(self.matrix, np.broadcast_shapes(xk.shape, xl.shape)[:-1])

        def grad_x(self, xk, xl):
            return np.zeros((*np.broadcast_shapes(xk.shape, xl.shape)[:-1], xk.shape[-1]))

        def grad_y(self, xk, xl):
            return self.grad_x(xk, xl)

    n = 5
    kernel = ConstantKernel(n)
    model = SwarmModel(SwarmParams(n_agents=n, kernel=kernel))
    x = np.linspace(-1.0, 1.0, n)[:, None]
    lin = model.frozen_linearization(x)
    np.testing.assert_allclose(lin, 2.0 * (np.ones((n, n)) - n * np.eye(n)) / n)
    np.testing.assert_array_equal(kernel.matrix, np.full((n, n), 2.0))


# ------------------------------------------------ the kernel's contract (mutation testing)
@pytest.mark.parametrize(
    ("alpha", "weights"),
    [
        (0.0, 1.0),
        (-0.5, 1.0),
        (0.3, 0.0),
        (0.3, -1.0),
        (0.3, [1.0, -2.0]),
        (0.3, [1.0, np.nan]),
        (0.3, np.ones((2, 2))),
    ],
)
def test_kernel_rejects_bad_alpha_and_weights(alpha, weights):
    with pytest.raises(ValueError, match=r"alpha|weights"):
        CuckerSmaleKernel(alpha, weights)


@pytest.mark.parametrize(
    ("weights", "symmetric"),
    [
        (2.0, True),
        ([2.0], True),
        ([2.0, 2.0, 2.0], True),
        ([1.0, 2.0, 3.0], False),
        ([3.0, 2.0, 1.0], False),
        ([2.0, 1.0, 1.0], False),
    ],
)
def test_kernel_is_symmetric_exactly_for_equal_weights(weights, symmetric):
    assert CuckerSmaleKernel(0.3, weights).symmetric is symmetric


@pytest.mark.parametrize(
    ("eps_min", "eps_max", "symmetric"), [(0.1, 0.5, False), (0.5, 0.1, False), (0.2, 0.2, True)]
)
def test_nonsymmetric_kernel_flag(eps_min, eps_max, symmetric):
    kernel = CuckerSmaleKernel.nonsymmetric_kernel(0.3, eps_min, eps_max, 4)
    assert kernel.symmetric is symmetric
    np.testing.assert_allclose(kernel.weights, 1.0 / np.linspace(eps_min, eps_max, 4))


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_kernel_on_single_pairs_and_a_batch_of_one(dim):
    """Shapes (1, 1, d) and (1, N, 1, d) take the same formula as (N, 1, d): the d = 1 fast
    paths must not be chosen by a leading axis of length 1."""
    x = np.random.default_rng(dim).uniform(-1, 1, (4, dim))
    kernel = CuckerSmaleKernel.nonsymmetric_kernel(0.3, 0.1, 0.5, 4)
    full = kernel.value(x[:, None, :], x[None, :, :])
    gx = kernel.grad_x(x[:, None, :], x[None, :, :])
    batch = kernel.value(x[None, :, None, :], x[None, None, :, :])
    np.testing.assert_allclose(batch[0], full, rtol=1e-14)
    np.testing.assert_allclose(kernel.grad_x(x[None, :, None, :], x[None, None, :, :])[0], gx)
    single = CuckerSmaleKernel(0.3, 2.0)
    for k in range(4):
        for q in range(4):
            diff = x[k] - x[q]
            want = 2.0 / (0.09 + float(diff @ diff))
            got = single.value(x[k][None, None, :], x[q][None, None, :])
            assert got.shape == (1, 1) and got[0, 0] == pytest.approx(want, rel=1e-13)
            g = single.grad_x(x[k][None, None, :], x[q][None, None, :])[0, 0]
            np.testing.assert_allclose(g, -2.0 * 2.0 * diff / (0.09 + diff @ diff) ** 2)


def test_kernel_follows_the_protocol_and_is_radial():
    """`InteractionKernel` is a runtime-checkable protocol (users' kernels are checked with
    isinstance); the Cucker-Smale kernel depends on |x_k - x_l| only, so with the symmetric
    weights its exact Jacobian is symmetric (which lets "eigh" serve it)."""
    from agent_envs.dynamics.kernels import InteractionKernel

    kernel = CuckerSmaleKernel.symmetric_kernel(0.3, 0.2)
    assert isinstance(kernel, InteractionKernel) and kernel.radial is True
    assert not isinstance(object(), InteractionKernel)
    model = SwarmModel(_params("symmetric", 2))
    x = np.random.default_rng(4).uniform(-1, 1, (7, 2))
    _, lin = model.drift_and_linearization(0.0, x, None, "exact")
    assert lin.symmetric is True
    np.testing.assert_allclose(lin.matrix, lin.matrix.T, atol=1e-12)


def test_matrix_free_exact_jacobian_beyond_d1_is_a_named_error():
    """The matrix-free exact Jacobian exists for d = 1 only: forced matrix-free in d = 2, the
    exact linearization is refused with the dense size it would need, (2 + 3d)(N d)^2 floats
    (N = 5000: 6.0 GiB); nothing of that size is allocated."""
    model = SwarmModel(_params("symmetric", 2, n=5000), "matrix_free")
    with pytest.raises(ValueError, match=r"only for d = 1 .* needs 6\.0 GiB"):
        model.drift_and_linearization(0.0, np.zeros((5000, 2)), None, "exact")


def test_forced_matrix_free_drift_matches_the_dense_one_with_a_control():
    params = _params("symmetric", 2, n=6)
    rng = np.random.default_rng(0)
    x, u = rng.uniform(-1, 1, (3, 6, 2)), rng.normal(size=(3, 6, 2))
    free, dense = SwarmModel(params, "matrix_free"), SwarmModel(params, "dense")
    assert free.matrix_free(x) and not dense.matrix_free(x)
    f_free, _ = free.drift_and_linearization(0.0, x, u, "frozen")
    f_dense, _ = dense.drift_and_linearization(0.0, x, u, "frozen")
    np.testing.assert_allclose(f_free, f_dense, rtol=1e-10, atol=1e-12)
    torch = pytest.importorskip("torch")
    with pytest.raises(ValueError, match="numpy states"):
        free.matrix_free(torch.as_tensor(x))


@pytest.mark.parametrize(
    ("dim", "n_agents", "n_paths", "matrix_free"),
    [
        (1, 999, 1, False),
        (1, 1000, 1, True),  # AUTO_MATRIX_FREE_MIN_AGENTS
        (1, 1400, 1, True),
        (2, 1999, 1, False),
        (2, 2000, 1, True),
        (1, 400, 500, False),  # 8 (2 + d) P N^2 bytes: 1.9e9 < 2 GiB
        (1, 400, 600, True),  # 2.3e9 > 2 GiB: over the dense memory budget
    ],
)
def test_auto_goes_matrix_free_from_the_documented_sizes(dim, n_agents, n_paths, matrix_free):
    """`linear_operator="auto"`: matrix-free for numpy states from N = 1000 (d = 1) and
    N = 2000 (d = 2), or when a step's dense matrices would exceed 2 GiB (the class doc)."""
    model = SwarmModel(SwarmParams(n_agents=n_agents, dim=dim))
    x = np.broadcast_to(np.zeros((1, n_agents, dim)), (n_paths, n_agents, dim))  # no copy
    assert model.matrix_free(x) is matrix_free


def test_matrix_free_answers_are_kept_per_shape_and_recomputed_when_the_budget_moves(
    monkeypatch,
):
    """`matrix_free` keeps its answer per (type, shape, kind, budget): one shape over and one
    under the dense budget in turn give their own answers, a repeated question is not
    recomputed, and a budget patched later (as tests do) is seen."""
    model = SwarmModel(SwarmParams(n_agents=400))
    under = np.broadcast_to(np.zeros((1, 400, 1)), (500, 400, 1))
    over = np.broadcast_to(np.zeros((1, 400, 1)), (600, 400, 1))
    calls = []
    compute = model._matrix_free
    monkeypatch.setattr(model, "_matrix_free", lambda x, kind: calls.append(1) or compute(x, kind))
    for _ in range(3):
        assert model.matrix_free(under) is False
        assert model.matrix_free(over) is True
    assert len(calls) == 2
    monkeypatch.setattr("agent_envs.dynamics.swarm.DENSE_MEMORY_BUDGET_BYTES", 1)
    assert model.matrix_free(under) is True
    assert len(calls) == 3


def test_a_model_pickled_before_the_matrix_free_memo_still_steps():
    """A model pickled by a version without the memo (its state lacks the attribute) unpickles
    into one that answers `matrix_free` and steps; a current model round-trips with its memo."""
    import pickle

    model = SwarmModel(SwarmParams(n_agents=6))
    x = np.random.default_rng(0).uniform(-1, 1, (2, 6, 1))
    expected = model.interaction_drift(x)
    old = pickle.loads(pickle.dumps(model))
    del old.__dict__["_matrix_free_answers"]  # the state an older version pickled
    revived = pickle.loads(pickle.dumps(old))
    np.testing.assert_array_equal(revived.interaction_drift(x), expected)
    again = pickle.loads(pickle.dumps(model))
    assert again._matrix_free_answers == model._matrix_free_answers


def test_matrix_free_raises_every_time_it_must():
    """An answer that raises (the matrix-free path needed but missing) is never kept: the
    second question raises too."""
    torch = pytest.importorskip("torch")
    model = SwarmModel(SwarmParams(n_agents=10), "matrix_free")
    x = torch.zeros((1, 10, 1), dtype=torch.float64)
    for _ in range(2):
        with pytest.raises(ValueError, match="numpy states"):
            model.matrix_free(x)


class _AnisotropicKernel:
    """p(x, y) = 1 / (1 + r^T A r), r = y - x, A not the identity: symmetric in (x, y) but
    not radial, so the exact Jacobian's blocks r (dp/dy)^T are not symmetric matrices."""

    symmetric = True
    a = np.array([[1.0, 0.5], [0.5, 2.0]])

    def _q(self, xk, xl):
        r = xl - xk
        return r, 1.0 + np.einsum("...i,ij,...j->...", r, self.a, r)

    def value(self, xk, xl):
        return 1.0 / self._q(xk, xl)[1]

    def grad_y(self, xk, xl):
        r, q = self._q(xk, xl)
        return -2.0 * (r @ self.a) / q[..., None] ** 2

    def grad_x(self, xk, xl):
        return -self.grad_y(xk, xl)


def test_exact_jacobian_of_a_non_radial_kernel_matches_finite_differences():
    """The blocks' orientation (row = coordinate of agent k, column = of agent l) matters
    only when they are not symmetric: checked with an anisotropic kernel in d = 2."""
    model = SwarmModel(SwarmParams(n_agents=5, dim=2, kernel=_AnisotropicKernel()))
    x = np.random.default_rng(3).uniform(-1, 1, (5, 2))
    np.testing.assert_allclose(model.jacobian(x), _fd_jacobian(model, x), rtol=1e-6, atol=1e-6)


def test_matrix_free_serb_step_in_d2_matches_the_dense_one():
    from agent_envs.integrators import make_integrator

    params = _params("symmetric", 2, n=6)
    rng = np.random.default_rng(1)
    x, u, dw = rng.uniform(-1, 1, (3, 6, 2)), rng.normal(size=(3, 6, 2)), rng.normal(size=(3, 6, 2))
    scheme = make_integrator("serb", phi_method="krylov")
    free = scheme.step(SwarmModel(params, "matrix_free"), x, u, 0.0, 0.01, 0.1 * dw)
    dense = scheme.step(SwarmModel(params, "dense"), x, u, 0.0, 0.01, 0.1 * dw)
    np.testing.assert_allclose(free, dense, rtol=1e-7, atol=1e-9)


def test_dense_memory_budget_is_exceeded_not_reached():
    """needed > 2 GiB goes matrix-free; exactly 2 GiB (d = 2, N = 2^13, one path: 8 (2 + d)
    N^2 = 2^31 bytes) stays dense, for a user kernel (the N rule covers only Cucker-Smale)."""
    params = SwarmParams(n_agents=2**13, dim=2, kernel=_AnisotropicKernel())
    model = SwarmModel(params)
    assert model.matrix_free(np.broadcast_to(np.zeros((1, 2**13, 2)), (1, 2**13, 2))) is False
    assert model.matrix_free(np.broadcast_to(np.zeros((1, 2**13, 2)), (2, 2**13, 2))) is True
