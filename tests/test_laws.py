"""Laws the numerical core must obey, checked against values computed here, not against another
part of the implementation: the Brownian increments' variance, the swarm centre's random walk
under the symmetric kernel (for every integrator, in `simulate`, the Gymnasium env and the
native vector env), the kernel and its gradients against the formula and finite differences in
d = 1, 2, 3, the drift against its defining double sum, and the running cost's formula.

Statistical tests use fixed seeds (a `numpy.random.Generator` each, never global state) and a
tolerance of 5 standard errors of the estimator, derived in each test's docstring: a correct
implementation fails with probability < 1e-6 per check (and never, with the fixed seed), while
the noise-scale mutation sqrt(dt) -> dt (a variance off by the factor dt) fails by > 20 SE.

The centre law: with a symmetric kernel, sum_k F_k(x, 0) = (1/N) sum_{k,l} p(x_k, x_l)
(x_l - x_k) = 0 (the (k, l) and (l, k) terms cancel), so 1^T L(x) = 0 and 1^T J(x) = 0. Every
scheme here advances x by sigma dW plus terms of the form dt g(dt A) v with A = L or J and
v in the range of A or F: for EM/EE/Heun 1^T F = 0 at every stage; for ERB/SERB
1^T phi_p(dt A) = 1^T phi_p(0) = 1^T / p! and 1^T (F + sigma A dW) = 0. So the centre
c = (1/N) sum_k x_k moves exactly by sigma (1/N) sum_k dW_k with zero control: a random walk
with Var(c(t) - c(0)) = sigma^2 t / N per coordinate, whatever the stiffness.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from agent_envs import SwarmModel, SwarmParams
from agent_envs.costs import agent_running_cost, discrete_cost, running_cost, turnpike_distance
from agent_envs.draws import brownian_increments
from agent_envs.dynamics.kernels import CuckerSmaleKernel
from agent_envs.envs.swarm_env import SwarmEnv
from agent_envs.envs.vector_env import make_swarm_vector_env
from agent_envs.simulator import simulate

N_SE = 5.0  # tolerance in standard errors


def _variance_ratio_bound(n_samples: int) -> float:
    """5 standard errors of s^2 / v with a known mean: Var(s^2) = 2 v^2 / n for Gaussians."""
    return N_SE * math.sqrt(2.0 / n_samples)


def _check_variance(samples: np.ndarray, variance: float) -> None:
    """E s^2 = v with s^2 = mean(samples^2) (mean known to be 0); |s^2/v - 1| <= 5 SE."""
    samples = np.asarray(samples).reshape(-1)
    ratio = float(np.mean(samples**2)) / variance
    bound = _variance_ratio_bound(samples.size)
    assert abs(ratio - 1.0) <= bound, (ratio, bound, samples.size)
    # and the mean is 0: |mean| <= 5 sqrt(v / n)
    assert abs(float(np.mean(samples))) <= N_SE * math.sqrt(variance / samples.size)


# ----------------------------------------------------------------- the noise
def test_brownian_increments_have_variance_dt():
    """dW ~ N(0, dt): 40 000 draws, |s^2/dt - 1| <= 5 sqrt(2/40000) = 3.5%; the mutation
    sqrt(dt) -> dt gives s^2/dt = dt = 0.04."""
    dt = 0.04
    dw = brownian_increments(np.random.default_rng(2024), (100, 40, 10), dt)
    _check_variance(dw, dt)
    # independent coordinates: the lag-one correlation is within 5 SE = 5 / sqrt(n) of 0
    flat = dw.reshape(-1)
    corr = np.mean(flat[1:] * flat[:-1]) / dt
    assert abs(corr) <= N_SE / math.sqrt(flat.size - 1)


# The non-stiff setting of the centre law: alpha = 1 keeps tau lambda < 2 even for EM.
SOFT = {"n_agents": 6, "dim": 2, "alpha": 1.0, "epsilon": 1.0, "sigma": 0.3, "horizon": 1.0}
CENTRE_CASES = [
    ("em", "frozen", SOFT),
    ("ee", "frozen", SOFT),
    ("heun", "frozen", SOFT),
    ("erb", "frozen", SOFT),
    ("erb", "exact", SOFT),
    ("serb", "frozen", SOFT),
    ("serb", "exact", SOFT),
    # the paper's stiff kernel (eps = 0.05, alpha = 0.1): SERB at tau lambda >> 1
    ("serb", "frozen", {**SOFT, "alpha": 0.1, "epsilon": 0.05, "dim": 1}),
]


@pytest.mark.parametrize(("name", "jacobian", "setting"), CENTRE_CASES)
def test_centre_is_a_random_walk_in_simulate(name, jacobian, setting):
    """c(T) - c(0) over K = 1500 paths and d coordinates: Var = sigma^2 T / N, 5 SE =
    5 sqrt(2 / (K d)) (13% for d = 2, 18% for d = 1; the m K d per-step increments: 6.5%, 9%).
    A wrong noise scale (sqrt(dt) -> dt: factor dt = 1/4), a noise term missing or doubled in
    a scheme (factor 0 or 4), or an interaction that moves the centre (a sign error in the
    symmetric kernel's drift) fail by far more."""
    params = SwarmParams(**setting)
    n_paths, n_steps = 1500, 4
    traj = simulate(params, name, jacobian=jacobian, n_steps=n_steps, n_paths=n_paths, seed=11)
    assert not traj.diverged
    centre = traj.positions.mean(axis=-2)  # (m + 1, K, d)
    walk = centre[-1] - centre[0]
    _check_variance(walk, params.sigma**2 * params.horizon / params.n_agents)
    # exactly a random walk: each step's centre increment is sigma * mean_k dW_k, whose
    # variance sigma^2 tau / N the per-step samples check too (m K d samples)
    steps = np.diff(centre, axis=0)
    _check_variance(steps, params.sigma**2 * (params.horizon / n_steps) / params.n_agents)


def test_centre_moves_by_the_mean_increment_exactly():
    """Pathwise: with the increments given, c(T) - c(0) = sigma mean_k sum_n dW_k^n to round-off
    for every scheme (the law above without sampling error)."""
    params = SwarmParams(**SOFT)
    rng = np.random.default_rng(5)
    dw = brownian_increments(rng, (4, 3, params.n_agents, params.dim), params.horizon / 4)
    want = params.sigma * dw.sum(axis=0).mean(axis=-2)
    for name, jacobian, _ in CENTRE_CASES[:-1]:
        traj = simulate(
            params, name, jacobian=jacobian, n_steps=4, n_paths=3, seed=1, increments=dw
        )
        got = traj.positions[-1].mean(axis=-2) - traj.positions[0].mean(axis=-2)
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12, err_msg=name)


def _env_centre_steps(positions: list[np.ndarray]) -> np.ndarray:
    """Per-step centre increments from a list of (..., N, d) states."""
    centres = np.stack([p.mean(axis=-2) for p in positions])
    return np.diff(centres, axis=0)


@pytest.mark.parametrize("integrator", ["em", "serb"])
def test_centre_is_a_random_walk_in_the_gymnasium_env(integrator):
    """Zero action: each step moves every path's centre by sigma mean_k dW_k, variance
    sigma^2 tau / N. 10 episodes x m = 20 steps x P = 10 paths x d = 2 = 4000 samples,
    5 SE = 5 sqrt(2/4000) = 11%; sqrt(dt) -> dt scales the variance by tau = 0.05."""
    kwargs = {
        "n_agents": 5,
        "dim": 2,
        "n_steps": 20,
        "n_paths": 10,
        "sigma": 0.2,
        "alpha": 1.0,
        "epsilon": 1.0,
        "integrator": integrator,
    }
    env = SwarmEnv(**kwargs)
    steps = []
    for episode in range(10):
        _, info = env.reset(seed=100 + episode)
        states = [info["positions"]]
        zero = np.zeros(env.action_space.shape, dtype=np.float32)
        for _ in range(env.unwrapped.n_steps):
            _, _, terminated, _, info = env.step(zero)
            states.append(info["positions"])
            assert not terminated
        steps.append(_env_centre_steps(states))
    dt = env.unwrapped.dt
    _check_variance(np.stack(steps), kwargs["sigma"] ** 2 * dt / kwargs["n_agents"])


def test_centre_is_a_random_walk_in_the_vector_env():
    """The native vector env, B = 20 envs x P = 10 paths x m = 20 steps x d = 1 = 4000
    samples of the per-step centre increment, variance sigma^2 tau / N, 5 SE = 11%."""
    kwargs = {
        "n_agents": 5,
        "dim": 1,
        "n_steps": 20,
        "n_paths": 10,
        "sigma": 0.2,
        "alpha": 0.1,
        "epsilon": 0.05,
    }
    venv = make_swarm_vector_env(num_envs=20, **kwargs)
    venv.reset(seed=7)
    states = [venv.positions.copy()]
    zero = np.zeros(venv.action_space.shape, dtype=np.float32)
    for _ in range(kwargs["n_steps"]):
        *_, terminated, truncated, _ = venv.step(zero)
        if not (terminated.any() or truncated.any()):
            states.append(venv.positions.copy())
    venv.close()
    assert len(states) == kwargs["n_steps"]  # the last step autoresets (next-step mode)
    dt = 1.0 / kwargs["n_steps"]
    _check_variance(_env_centre_steps(states), kwargs["sigma"] ** 2 * dt / kwargs["n_agents"])


# ------------------------------------------------------------- the kernel
def _kernel_formula(x: np.ndarray, alpha: float, w: np.ndarray) -> np.ndarray:
    """p(x_k, x_l) = w_l / (alpha^2 + |x_k - x_l|^2), written with loops."""
    n = len(x)
    p = np.empty((n, n))
    for k, q in itertools.product(range(n), range(n)):
        p[k, q] = w[q] / (alpha**2 + sum((x[k, i] - x[q, i]) ** 2 for i in range(x.shape[1])))
    return p


def _grad_x_formula(x: np.ndarray, alpha: float, w: np.ndarray) -> np.ndarray:
    """d/dx_k of w_l / (alpha^2 + |x_k - x_l|^2) = -2 w_l (x_k - x_l) / D^2 (chain rule)."""
    n, d = x.shape
    g = np.empty((n, n, d))
    for k, q in itertools.product(range(n), range(n)):
        diff = x[k] - x[q]
        denom = alpha**2 + float(diff @ diff)
        g[k, q] = -2.0 * w[q] * diff / denom**2
    return g


def _kernels(n: int):
    sym = CuckerSmaleKernel.symmetric_kernel(0.3, 0.2)
    nonsym = CuckerSmaleKernel.nonsymmetric_kernel(0.3, 0.1, 0.5, n)
    return [
        (sym, np.full(n, 1 / 0.2)),
        (nonsym, 1.0 / np.linspace(0.1, 0.5, n)),
    ]


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_kernel_value_and_gradients_against_the_formula(dim):
    n = 5
    x = np.random.default_rng(dim).uniform(-1, 1, (n, dim))
    xk, xl = x[:, None, :], x[None, :, :]
    for kernel, w in _kernels(n):
        np.testing.assert_allclose(kernel.value(xk, xl), _kernel_formula(x, 0.3, w), rtol=1e-13)
        gx = _grad_x_formula(x, 0.3, w)
        np.testing.assert_allclose(kernel.grad_x(xk, xl), gx, rtol=1e-12, atol=1e-14)
        # p depends on x_k - x_l only, so dp/dy = -dp/dx
        np.testing.assert_allclose(kernel.grad_y(xk, xl), -gx, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_kernel_gradients_against_finite_differences(dim):
    """Central differences of P[k, l] in x_k (dp/dx) and in x_l (dp/dy), k != l, h = 1e-6:
    truncation O(h^2) ~ 1e-10 relative, well inside rtol 1e-6."""
    n, h = 4, 1e-6
    x = np.random.default_rng(10 + dim).uniform(-1, 1, (n, dim))
    for kernel, _ in _kernels(n):
        gx = kernel.grad_x(x[:, None, :], x[None, :, :])
        gy = kernel.grad_y(x[:, None, :], x[None, :, :])
        for a, i in itertools.product(range(n), range(dim)):
            plus, minus = x.copy(), x.copy()
            plus[a, i] += h
            minus[a, i] -= h
            fd = (
                kernel.value(plus[:, None, :], plus[None, :, :])
                - kernel.value(minus[:, None, :], minus[None, :, :])
            ) / (2 * h)
            for b in range(n):
                if b == a:
                    continue
                # row a: agent a is the first argument; column a: the second
                assert gx[a, b, i] == pytest.approx(fd[a, b], rel=1e-6, abs=1e-6)
                assert gy[b, a, i] == pytest.approx(fd[b, a], rel=1e-6, abs=1e-6)


@pytest.mark.parametrize("dim", [1, 2, 3])
@pytest.mark.parametrize("kernel", ["symmetric", "nonsymmetric"])
def test_drift_is_the_double_sum(dim, kernel):
    """F_k = (1/N) sum_l p(x_k, x_l)(x_l - x_k) + u_k with p from the formula above, and the
    batched drift equals the per-path one."""
    n = 6
    params = SwarmParams(
        n_agents=n, dim=dim, kernel=kernel, alpha=0.4, epsilon=0.3, epsilon_min=0.1, epsilon_max=0.5
    )
    w = np.full(n, 1 / 0.3) if kernel == "symmetric" else 1.0 / np.linspace(0.1, 0.5, n)
    rng = np.random.default_rng(20 + dim)
    x = rng.uniform(-1, 1, (3, n, dim))
    u = rng.normal(size=(3, n, dim))
    model = SwarmModel(params)
    got = model.drift(0.0, x, u)
    for j in range(3):
        p = _kernel_formula(x[j], 0.4, w)
        want = (
            np.array([sum(p[k, q] * (x[j, q] - x[j, k]) for q in range(n)) / n for k in range(n)])
            + u[j]
        )
        np.testing.assert_allclose(got[j], want, rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(model.drift(0.0, x[j], u[j]), want, rtol=1e-12, atol=1e-13)


# ------------------------------------------------------------------ the costs
def test_costs_against_their_formulas():
    """c = (1/N) sum_k (|x_k - xbar|^2 + gamma |u_k|^2), tau sum_{n<m} c(x^n, u^n) and
    ||E x - xbar||^2 + ||u||^2, written with loops."""
    rng = np.random.default_rng(3)
    m, k_paths, n, d, gamma, dt = 3, 2, 4, 2, 0.07, 0.1
    x = rng.normal(size=(m + 1, k_paths, n, d))
    u = rng.normal(size=(m, k_paths, n, d))
    target = np.array([0.7, -0.2])
    c = np.zeros((m, k_paths))
    for s, j in itertools.product(range(m), range(k_paths)):
        c[s, j] = (
            sum(
                float((x[s, j, a] - target) @ (x[s, j, a] - target))
                + gamma * float(u[s, j, a] @ u[s, j, a])
                for a in range(n)
            )
            / n
        )
    np.testing.assert_allclose(running_cost(x[:m], u, target, gamma), c, rtol=1e-13)
    np.testing.assert_allclose(
        agent_running_cost(x[0], None, target, 5.0), ((x[0] - target) ** 2).sum(-1), rtol=1e-13
    )
    np.testing.assert_allclose(
        discrete_cost(x, u, target, gamma, dt), dt * c.sum(axis=0), rtol=1e-13
    )
    mean = x[1].mean(axis=0)
    want = sum(
        float((mean[a] - target) @ (mean[a] - target)) + float(u[0, 0, a] @ u[0, 0, a])
        for a in range(n)
    )
    assert float(turnpike_distance(mean, u[0, 0], target)) == pytest.approx(want, rel=1e-13)


@pytest.mark.parametrize("dim", [1, 2])
def test_kernel_on_torch_against_the_formula(dim):
    """The torch path (the differentiable one): same formula, weights moved to the tensor's
    library."""
    torch = pytest.importorskip("torch")
    n = 5
    x = np.random.default_rng(30 + dim).uniform(-1, 1, (n, dim))
    xt = torch.as_tensor(x)
    for kernel, w in _kernels(n):
        got = kernel.value(xt[:, None, :], xt[None, :, :])
        assert isinstance(got, torch.Tensor)
        if not kernel.symmetric:  # the weights live in the tensor's library (CUDA needs it)
            assert isinstance(kernel._weights_like(xt), torch.Tensor)
        np.testing.assert_allclose(got.numpy(), _kernel_formula(x, 0.3, w), rtol=1e-13)
        gx = kernel.grad_x(xt[:, None, :], xt[None, :, :])
        np.testing.assert_allclose(gx.numpy(), _grad_x_formula(x, 0.3, w), rtol=1e-12, atol=1e-14)


def test_costs_batched_and_on_torch():
    """Batched inputs (..., N, d) reduce over the last two axes only; on torch the target may be
    a list or a numpy array (moved to the tensor's library) and the result is a tensor."""
    rng = np.random.default_rng(8)
    mean, u = rng.normal(size=(3, 4, 2)), rng.normal(size=(3, 4, 2))
    target = [0.7, -0.2]
    want = [turnpike_distance(mean[j], u[j], np.array(target)) for j in range(3)]
    np.testing.assert_allclose(turnpike_distance(mean, u, np.array(target)), want, rtol=1e-13)
    torch = pytest.importorskip("torch")
    x, ut = torch.as_tensor(mean), torch.as_tensor(u)
    for tgt in (target, np.array(target)):
        got = running_cost(x, ut, tgt, 0.1)
        assert isinstance(got, torch.Tensor)
        np.testing.assert_allclose(got.numpy(), running_cost(mean, u, np.array(target), 0.1))
        got = turnpike_distance(x, ut, tgt)
        np.testing.assert_allclose(got.numpy(), want, rtol=1e-13)


# ------------------------------------------------------- one step of each scheme
def _phi(a: np.ndarray, order: int, terms: int = 60) -> np.ndarray:
    """phi_p(A) = sum_j A^j / (j + p)! by its Taylor series (||A|| ~ 1 here, 60 terms)."""
    out, power = np.zeros_like(a), np.eye(len(a))
    for j in range(terms):
        out = out + power / math.factorial(j + order)
        power = power @ a
    return out


def _frozen(x: np.ndarray, alpha: float, w: np.ndarray) -> np.ndarray:
    """L(x) = (P - diag(P 1)) / N from the kernel formula."""
    p = _kernel_formula(x, alpha, w)
    return (p - np.diag(p.sum(axis=1))) / len(x)


@pytest.mark.parametrize("sigma", [0.3, 1.0])
@pytest.mark.parametrize("control", ["none", "constant", "with_rate"])
def test_one_step_of_each_scheme_against_its_formula(control, sigma):
    """x+ of EM/EE (x + tau F + sigma dW), Heun (predictor X = x + tau F(x, u) + sigma dW,
    x + tau/2 (F(x, u) + F(X, u + tau v)) + sigma dW), ERB (x + tau phi1(tau L) F + sigma dW)
    and SERB (x + tau phi1(tau L)(F + sigma L dW) + sigma dW), both + tau^2 phi2(tau L) v with
    a control rate v; the frozen L(x) and phi_p from the formulas above; non-stiff."""
    from agent_envs.integrators import make_integrator

    n, d, alpha, eps, tau = 5, 2, 0.5, 0.4, 0.1
    params = SwarmParams(n_agents=n, dim=d, alpha=alpha, epsilon=eps, sigma=sigma)
    model, w = SwarmModel(params), np.full(n, 1 / eps)
    rng = np.random.default_rng(40)
    x, dw = rng.uniform(-1, 1, (n, d)), rng.normal(scale=math.sqrt(tau), size=(n, d))
    u = None if control == "none" else rng.normal(size=(n, d))
    v = rng.normal(size=(n, d)) if control == "with_rate" else None
    zero = np.zeros((n, d))
    u0 = zero if u is None else u
    u1 = u0 if v is None else u0 + tau * v
    v0 = zero if v is None else v

    lin = _frozen(x, alpha, w)
    f = lin @ x + u0
    pred = x + tau * f + sigma * dw
    phi1, phi2 = _phi(tau * lin, 1), _phi(tau * lin, 2)
    want = {
        "em": x + tau * f + sigma * dw,
        "ee": x + tau * f + sigma * dw,
        "heun": x + 0.5 * tau * (f + _frozen(pred, alpha, w) @ pred + u1) + sigma * dw,
        "erb": x + tau * phi1 @ f + tau**2 * phi2 @ v0 + sigma * dw,
        "serb": x + tau * phi1 @ (f + sigma * lin @ dw) + tau**2 * phi2 @ v0 + sigma * dw,
    }
    for name, expected in want.items():
        scheme = make_integrator(name, jacobian="frozen")
        got = scheme.step(model, x, u, 0.0, tau, dw, du_dt=v)
        np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-12, err_msg=name)


def test_default_initial_positions_are_uniform_on_the_cube():
    """The paper's start, U[-1, 1]^d: 4000 draws (through simulate's seeds, d = 2 x 2 paths of
    1000 agents), within [-1, 1], mean 0 and variance 1/3 within 5 SE (SE of the mean
    sqrt(1/(3n)); of the variance sqrt((E x^4 - (1/3)^2)/n) = sqrt((1/5 - 1/9)/n))."""
    params = SwarmParams(n_agents=1000, dim=2, epsilon=1.0, alpha=1.0)
    x = np.concatenate(
        [simulate(params, "em", n_steps=1, n_paths=1, seed=s).positions[0, 0] for s in (0, 1)]
    ).reshape(-1)
    n = x.size
    assert x.min() >= -1.0 and x.max() <= 1.0 and x.min() < -0.99 and x.max() > 0.99
    assert abs(x.mean()) <= N_SE * math.sqrt(1 / 3 / n)
    assert abs(np.mean(x**2) - 1 / 3) <= N_SE * math.sqrt((1 / 5 - 1 / 9) / n)
