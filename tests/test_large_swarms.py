"""The matrix-free path of large swarms against the dense reference.

Kernel sums (`agent_envs.dynamics.kernel_sums`), the operator L(x) (`dynamics.operators`), the
Krylov phi-action on it, one SERB/ERB step at N = 2000 for both kernels, the integrators' key
checks on the matrix-free path, and the automatic choice in `SwarmModel`, `simulate` and the
envs. Small sizes only (a few seconds in all); the timings are benchmarks/bench_large_swarms.py.
"""

import gymnasium as gym
import numpy as np
import pytest

import agent_envs  # noqa: F401  (registers the env)
from agent_envs import SwarmModel, SwarmParams, make_integrator, simulate
from agent_envs.dynamics import kernel_sums, operators
from agent_envs.dynamics.kernel_sums import ChunkedKernelSum, GridKernelSum, lagrange_weights
from agent_envs.dynamics.kernels import CuckerSmaleKernel
from agent_envs.dynamics.operators import LinearizationOperator
from agent_envs.integrators import phi_lanczos
from agent_envs.integrators.phi_functions import phi_action

N = 2000
KERNELS = ["symmetric", "nonsymmetric"]


def _params(kernel, n=N, dim=1, **kw):
    return SwarmParams(
        n_agents=n, dim=dim, epsilon=0.05, kernel=kernel, epsilon_min=0.05, epsilon_max=0.5, **kw
    )


def _state(n=N, dim=1, paths=1, seed=0):
    return np.random.default_rng(seed).uniform(-1.0, 1.0, (paths, n, dim))


def _rel(a, b):
    return np.linalg.norm(a - b) / np.linalg.norm(b)


# ------------------------------------------------------------------ kernel sums
def test_lagrange_weights_reproduce_polynomials_and_nodes():
    p = 10
    u = np.concatenate([np.linspace(4.0, 5.0, 7), np.arange(p, dtype=float)])
    w = lagrange_weights(u, p)
    nodes = np.arange(p, dtype=float)
    for degree in range(p):
        np.testing.assert_allclose(w @ nodes**degree, u**degree, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(w[-p:], np.eye(p), atol=1e-15)


@pytest.mark.parametrize("weights", ["scalar", "per_source"])
def test_grid_sum_matches_the_exact_sums_at_the_default_tolerance(weights):
    rng = np.random.default_rng(1)
    alpha = 0.1
    x = rng.uniform(-1, 1, N)
    v = rng.standard_normal((N, 3))
    w = 20.0 if weights == "scalar" else 1.0 / np.linspace(0.05, 0.5, N)
    profiles = [lambda r: 1 / (alpha**2 + r * r), lambda r: r / (alpha**2 + r * r)]
    r = x[:, None] - x[None, :]
    for fast, g in zip(GridKernelSum(x, profiles, w, alpha)(v), profiles, strict=True):
        exact = (w * g(r)) @ v
        assert _rel(fast, exact) <= kernel_sums.DEFAULT_TOLERANCE


@pytest.mark.parametrize("weights", ["scalar", "per_source"])
def test_two_dimensional_grid_sum_matches_the_exact_sum(weights):
    rng = np.random.default_rng(1)
    alpha, n = 0.1, 1500
    x = rng.uniform(-1, 1, (n, 2)) * np.array([1.0, 0.5])  # a different span per axis
    v = rng.standard_normal((n, 3))
    w = 20.0 if weights == "scalar" else 1.0 / np.linspace(0.05, 0.5, n)

    def profile(r):
        return 1 / (alpha**2 + np.sum(r * r, axis=-1))

    grid = GridKernelSum(x, [profile], w, alpha)
    assert grid.shape[0] > grid.shape[1]
    exact = (w * profile(x[:, None, :] - x[None, :, :])) @ v
    assert _rel(grid(v)[0], exact) <= kernel_sums.DEFAULT_TOLERANCE


def test_grid_resolution_table_is_ordered_and_validated():
    with pytest.raises(ValueError, match="tol"):
        kernel_sums.grid_resolution(0.0)
    coarse, fine = kernel_sums.grid_resolution(1e-6), kernel_sums.grid_resolution(1e-12)
    assert coarse[0] * coarse[1] < fine[0] * fine[1]


def test_grid_refuses_a_swarm_too_spread_for_it():
    x = np.array([0.0, 1e6])
    assert not GridKernelSum.fits(x, 1e-3)
    with pytest.raises(ValueError, match="chunked"):
        GridKernelSum(x, [lambda r: r], 1.0, 1e-3)


class _UserKernel:
    """A kernel object that is not a CuckerSmaleKernel (the generic chunked branch)."""

    symmetric = False

    def __init__(self):
        self._inner = CuckerSmaleKernel(0.1, 1.0 / np.linspace(0.05, 0.5, 300))

    def value(self, xk, xl):
        return self._inner.value(xk, xl)


@pytest.mark.parametrize("dim", [1, 2, 3])
@pytest.mark.parametrize("kind", ["cucker_smale", "user"])
def test_chunked_sum_is_the_dense_product(dim, kind):
    kernel = CuckerSmaleKernel(0.1, 1.0 / np.linspace(0.05, 0.5, 300))
    if kind == "user":
        kernel = _UserKernel()
    x = _state(300, dim)[0]
    v = np.random.default_rng(2).standard_normal((300, 2))
    dense = kernel.value(x[:, None, :], x[None, :, :])
    chunked = ChunkedKernelSum(kernel, x, block=37)  # a block that does not divide N
    sums, product = chunked.row_sums_and_product(v)
    np.testing.assert_allclose(product, dense @ v, rtol=1e-13, atol=1e-10)
    np.testing.assert_allclose(sums, dense.sum(axis=1), rtol=1e-13)
    np.testing.assert_allclose(chunked(v), dense @ v, rtol=1e-13, atol=1e-10)


# ------------------------------------------------------------------ the operator
@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize(("dim", "sums"), [(1, "grid"), (2, "grid"), (2, "chunked")])
def test_matvec_and_drift_match_the_dense_linearization(kernel, dim, sums, monkeypatch):
    n = N if dim == 1 else 800
    if sums == "grid":  # the 2-D grid serves N >= GRID_MIN_AGENTS[2]: lowered for the test
        monkeypatch.setitem(operators.GRID_MIN_AGENTS, 2, 0)
    params = _params(kernel, n, dim)
    dense, free = SwarmModel(params, "dense"), SwarmModel(params, "matrix_free")
    x = _state(n, dim, paths=2)
    v = np.random.default_rng(3).standard_normal((2, n, 3))
    matrix = dense.frozen_linearization(x)
    op = free.linearization_operator(x)
    assert all((ps.grid is not None) == (sums == "grid") for ps in op._paths)
    assert op.shape == matrix.shape and op.symmetric == (kernel == "symmetric")
    assert _rel(op @ v, matrix @ v) <= 1e-10
    assert _rel(free.interaction_drift(x), dense.interaction_drift(x)) <= 1e-10
    assert _rel((0.02 * op) @ v, 0.02 * (matrix @ v)) <= 1e-10
    assert op.norm_inf >= np.max(np.sum(np.abs(matrix), axis=-1)) * (1 - 1e-12)
    if dim == 1 or sums == "chunked":  # (N columns through the 2-D FFT would take minutes)
        dense_op = op.dense()[0]
        np.testing.assert_allclose(dense_op, matrix[0], atol=1e-10 * np.abs(matrix).max(), rtol=0)


@pytest.mark.parametrize("kernel", KERNELS)
def test_exact_jacobian_operator_matches_the_dense_jacobian(kernel):
    params = _params(kernel)
    x = _state()
    v = np.random.default_rng(3).standard_normal((1, N, 3))
    jac = SwarmModel(params, "dense").jacobian(x)
    op = SwarmModel(params, "matrix_free").linearization_operator(x, "exact")
    assert op.symmetric == (kernel == "symmetric")
    # within the operator's documented relative accuracy tol: the exact Jacobian's profile has
    # double poles, so its grid sums run one digit finer (at tol itself the error is ~2e-12)
    assert _rel(op @ v, jac @ v) <= operators.DEFAULT_TOLERANCE
    assert op.norm_inf >= np.max(np.sum(np.abs(jac), axis=-1)) * (1 - 1e-12)


def test_a_non_finite_state_gives_non_finite_sums_not_an_error():
    model = SwarmModel(_params("symmetric", 600), "matrix_free")
    x = _state(600, paths=2)
    x[1, 5, 0] = np.nan
    drift = model.interaction_drift(x)
    assert np.all(np.isfinite(drift[0])) and not np.all(np.isfinite(drift[1]))
    assert not np.all(np.isfinite(model.linearization_operator(x) @ np.ones((2, 600, 1))))


def test_a_swarm_too_wide_for_the_grid_falls_back_to_the_chunked_sum(monkeypatch):
    monkeypatch.setattr(operators, "_WARN_CHUNKED_MIN_AGENTS", 100)
    monkeypatch.setattr(kernel_sums, "MAX_GRID_POINTS", 1000)
    params = _params("nonsymmetric", 300)
    x = _state(300) * 10.0  # spans ~20 = 6400 grid points of alpha / 32
    with pytest.warns(RuntimeWarning, match="chunked") as caught:
        drift = SwarmModel(params, "matrix_free").interaction_drift(x)
    assert f"spans {np.ptp(x[0], axis=0)}" in str(caught[0].message)  # per coordinate
    assert _rel(drift, SwarmModel(params, "dense").interaction_drift(x)) <= 1e-12


def test_operator_rejects_a_misshapen_vector():
    op = LinearizationOperator(CuckerSmaleKernel(0.1, 20.0), _state(50))
    with pytest.raises(ValueError, match="v must have shape"):
        op @ np.ones((50,))
    with pytest.raises(ValueError, match=r"batch shape \(3,\) does not fit \(1,\)"):
        op @ np.ones((3, 50, 1))


def test_operator_of_one_unbatched_state_has_an_empty_batch_shape():
    x = _state(50)
    single = LinearizationOperator(CuckerSmaleKernel(0.1, 20.0), x[0])  # (N, d)
    batched = LinearizationOperator(CuckerSmaleKernel(0.1, 20.0), x)  # (1, N, d)
    assert single.batch_shape == () and batched.batch_shape == (1,)
    v = np.random.default_rng(1).standard_normal((50, 2))
    np.testing.assert_array_equal(single @ v, (batched @ v[None])[0])
    with pytest.raises(ValueError, match="positions must have shape"):
        LinearizationOperator(CuckerSmaleKernel(0.1, 20.0), x[0, :, 0])


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("order", [1, 2])
def test_phi_action_on_the_operator_matches_the_dense_matrix(kernel, order):
    params = _params(kernel, 600)
    x = _state(600)
    v = np.random.default_rng(4).standard_normal((1, 600, 2))
    matrix = 0.02 * SwarmModel(params, "dense").frozen_linearization(x)
    op = 0.02 * SwarmModel(params, "matrix_free").linearization_operator(x)
    sym = kernel == "symmetric"
    expected = phi_action(matrix, v, order, method="expm")
    assert _rel(phi_action(op, v, order, symmetric=sym), expected) <= 1e-9
    # a Krylov space too small for the full step: the action is taken in substeps
    substepped = phi_action(op, v, order, symmetric=sym, max_krylov_dim=12)
    assert _rel(substepped, expected) <= 1e-8
    with pytest.raises(ValueError, match="needs a matrix"):
        phi_action(op, v, order, method="expm")


def test_lanczos_sums_its_basis_for_large_n_like_the_stacked_product(monkeypatch):
    x = _state(600)
    op = 0.02 * SwarmModel(_params("symmetric", 600), "matrix_free").linearization_operator(x)
    v = np.random.default_rng(4).standard_normal((1, 600, 2))
    stacked = phi_action(op, v, 1, symmetric=True)
    monkeypatch.setattr(phi_lanczos, "ACCUMULATE_BASIS_MIN_N", 0)
    np.testing.assert_allclose(
        phi_action(op, v, 1, symmetric=True), stacked, rtol=1e-12, atol=1e-15
    )


# ------------------------------------------------------------------ integrator steps
@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("name", ["serb", "erb"])
@pytest.mark.parametrize("jacobian", ["frozen", "exact"])
def test_one_step_matches_the_dense_path(kernel, name, jacobian):
    params = _params(kernel, sigma=0.1)
    dense, free = SwarmModel(params, "dense"), SwarmModel(params, "matrix_free")
    x = _state()
    rng = np.random.default_rng(5)
    dw = np.sqrt(0.02) * rng.standard_normal(x.shape)
    u = rng.standard_normal(x.shape)
    du = rng.standard_normal(x.shape)
    scheme = make_integrator(name, jacobian=jacobian)
    a = scheme.step(dense, x, u, 0.0, 0.02, dw, du_dt=du)
    b = scheme.step(free, x, u, 0.0, 0.02, dw, du_dt=du)
    assert _rel(b - x, a - x) <= 1e-9
    assert np.max(np.abs(b - a)) <= 1e-9


@pytest.mark.parametrize("kernel", KERNELS)
def test_one_two_dimensional_serb_step_on_the_grid_matches_the_dense_path(kernel, monkeypatch):
    monkeypatch.setitem(operators.GRID_MIN_AGENTS, 2, 0)
    params = _params(kernel, 800, 2, sigma=0.1)
    x = _state(800, 2)
    dw = np.sqrt(0.02) * np.random.default_rng(6).standard_normal(x.shape)
    scheme = make_integrator("serb")
    a = scheme.step(SwarmModel(params, "dense"), x, None, 0.0, 0.02, dw)
    b = scheme.step(SwarmModel(params, "matrix_free"), x, None, 0.0, 0.02, dw)
    assert _rel(b - x, a - x) <= 1e-9


# The integrators' key checks (tests/test_integrators.py) on the matrix-free path.
def _integrate(scheme, model, x0, m, dw, horizon):
    x = x0.copy()
    for n in range(m):
        x = scheme.step(model, x, None, n * horizon / m, horizon / m, dw[:, n])
    return x


@pytest.mark.parametrize(
    ("name", "jacobian", "expected"),
    [("ee", "frozen", 1.0), ("erb", "frozen", 1.0), ("heun", "frozen", 2.0), ("erb", "exact", 2.0)],
)
def test_deterministic_order_on_the_matrix_free_path(name, jacobian, expected):
    params = SwarmParams(
        n_agents=40,
        alpha=0.5,
        epsilon=1.0,
        kernel="nonsymmetric",
        epsilon_min=0.5,
        epsilon_max=2.0,
        sigma=0.0,
        horizon=0.5,
    )  # the non-stiff setting of tests/test_integrators.py, where the orders are visible
    model = SwarmModel(params, "matrix_free")
    x0 = np.linspace(-1, 1, 40)[None, :, None]
    scheme = make_integrator(name, jacobian=jacobian)
    dw = np.zeros((1, 512, 40, 1))
    ref = _integrate(make_integrator("heun"), SwarmModel(params, "dense"), x0, 512, dw, 0.5)
    steps = [16, 32, 64]
    errors = [np.max(np.abs(_integrate(scheme, model, x0, m, dw, 0.5) - ref)) for m in steps]
    slope = np.polyfit(np.log([1 / m for m in steps]), np.log(errors), 1)[0]
    assert slope == pytest.approx(expected, abs=0.25), errors


def test_symmetric_interaction_conserves_the_mean_on_the_matrix_free_path():
    params = _params("symmetric", 1000, sigma=0.0)
    traj = simulate(params, "serb", n_steps=20, n_paths=1, seed=0, linear_operator="matrix_free")
    means = traj.positions[:, 0].mean(axis=-2)
    assert not traj.diverged
    np.testing.assert_allclose(means, np.broadcast_to(means[0], means.shape), atol=1e-11)


def test_frozen_exponential_euler_stays_in_the_convex_hull_on_the_matrix_free_path():
    params = _params("symmetric", 1000, sigma=0.0)
    x0 = np.random.default_rng(3).uniform(-1, 1, 1000)
    traj = simulate(
        params, "erb", n_steps=10, n_paths=1, initial_positions=x0, linear_operator="matrix_free"
    )
    pos = traj.positions[:, 0, :, 0]
    assert pos.min() >= x0.min() - 1e-9 and pos.max() <= x0.max() + 1e-9
    assert np.all(np.diff(pos.max(axis=1) - pos.min(axis=1)) <= 1e-9)


def test_simulate_agrees_with_the_dense_path_over_several_steps():
    params = _params("nonsymmetric", 800, sigma=0.05)
    kw = dict(n_steps=5, n_paths=2, seed=11)
    for name in ("em", "serb"):
        dense = simulate(params, name, linear_operator="dense", **kw).positions
        free = simulate(params, name, linear_operator="matrix_free", **kw).positions
        assert _rel(free, dense) <= 1e-9


# ------------------------------------------------------------------ choosing the path
@pytest.mark.parametrize("dim", [1, 2])
def test_auto_goes_matrix_free_above_the_measured_size(dim):
    size = operators.AUTO_MATRIX_FREE_MIN_AGENTS[dim]
    x_small, x_large = _state(size - 1, dim), _state(size, dim)
    assert not SwarmModel(_params("symmetric", size - 1, dim)).matrix_free(x_small)
    large = SwarmModel(_params("symmetric", size, dim))
    assert large.matrix_free(x_large)
    if dim == 1:
        assert large.matrix_free(x_large, "exact")  # d = 1: the exact Jacobian too
    else:
        with pytest.raises(ValueError, match="matrix-free form only for d = 1"):
            large.matrix_free(x_large, "exact")
    assert not SwarmModel(_params("symmetric", size, 3)).matrix_free(_state(size, 3))


def test_auto_goes_matrix_free_when_dense_would_not_fit_the_budget(monkeypatch):
    model = SwarmModel(_params("symmetric", 300, 2))
    x = _state(300, 2)
    assert not model.matrix_free(x)
    monkeypatch.setattr(
        "agent_envs.dynamics.swarm.DENSE_MEMORY_BUDGET_BYTES",
        operators.dense_bytes(300, 2, 1, "frozen") - 1,
    )
    assert model.matrix_free(x)
    with pytest.raises(ValueError, match="matrix-free form only for d = 1"):
        model.matrix_free(x, "exact")


def test_bad_linear_operator_values_are_named():
    with pytest.raises(ValueError, match="linear_operator must be one of"):
        SwarmModel(_params("symmetric", 10), "sparse")
    params = _params("symmetric", 10)
    with pytest.raises(ValueError, match="linear_operator must be one of"):
        simulate(params, n_steps=1, n_paths=1, linear_operator=1)
    with pytest.raises(ValueError, match="linear_operator applies to the default"):
        simulate(params, n_steps=1, model=SwarmModel(params), linear_operator="dense")
    with pytest.raises(ValueError, match="matrix-free form only for d = 1"):
        simulate(
            _params("symmetric", 10, 2), jacobian="exact", n_steps=1, linear_operator="matrix_free"
        )
    with pytest.raises(ValueError, match="kind must be"):
        LinearizationOperator(CuckerSmaleKernel(0.1, 20.0), _state(10), "jacobian")
    with pytest.raises(ValueError, match="linear_operator must be one of"):
        gym.make("agent_envs/Swarm-v0", n_agents=10, linear_operator="fast")


def test_matrix_free_refuses_torch_states():
    torch = pytest.importorskip("torch")
    model = SwarmModel(_params("symmetric", 10), "matrix_free")
    with pytest.raises(ValueError, match="numpy states"):
        model.drift(0.0, torch.zeros(1, 10, 1, dtype=torch.float64))
    auto = SwarmModel(_params("symmetric", 2 * operators.AUTO_MATRIX_FREE_MIN_AGENTS[1]))
    assert not auto.matrix_free(torch.zeros(1, auto.n_agents, 1, dtype=torch.float64))


def test_the_gym_env_resets_and_steps_one_hundred_thousand_agents():
    env = gym.make("agent_envs/Swarm-v0", n_agents=100_000)
    obs, info = env.reset(seed=0)
    assert obs.shape == (2 * 100_000 + 2,)
    obs, reward, terminated, _, info = env.step(env.action_space.sample())
    assert np.all(np.isfinite(obs)) and np.isfinite(reward) and not terminated
    assert info["positions"].shape == (1, 100_000, 1)
    assert env.unwrapped.model.matrix_free(info["positions"])
    env.close()


def test_env_linear_operator_kwarg_gives_the_dense_result():
    kw = dict(n_agents=600, sigma=0.05)
    obs = []
    for mode in ("dense", "matrix_free"):
        env = gym.make("agent_envs/Swarm-v0", linear_operator=mode, **kw)
        env.reset(seed=3)
        obs.append(env.step(np.full(600, 0.5, dtype=np.float32))[0])
        env.close()
    np.testing.assert_allclose(obs[1], obs[0], rtol=1e-6, atol=1e-6)
