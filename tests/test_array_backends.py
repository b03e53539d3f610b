"""The core on torch: agreement with numpy, gradients (gradcheck, Daleckii-Krein), devices."""

from __future__ import annotations

import numpy as np
import pytest

from agent_envs import SwarmModel, SwarmParams, make_integrator, simulate
from agent_envs.integrators.phi_functions import phi_action

torch = pytest.importorskip("torch")

SCHEMES = ("em", "ee", "heun", "erb", "serb")
PHI = ("auto", "expm", "eigh", "krylov")
CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")


def _x0(n: int, seed: int = 1) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1.0, 1.0, n)


@pytest.mark.parametrize("integrator", SCHEMES)
@pytest.mark.parametrize("jacobian", ["frozen", "exact"])
@pytest.mark.parametrize("phi_method", PHI)
def test_torch_cpu_matches_numpy(integrator, jacobian, phi_method):
    # Moderately stiff and stable for the explicit schemes too, with noise and a control.
    params = SwarmParams(n_agents=12, alpha=0.5, epsilon=0.5, sigma=0.05)
    control = np.random.default_rng(4).normal(size=(8, 3, 12, 1))
    kw = dict(
        integrator=integrator,
        jacobian=jacobian,
        phi_method=phi_method,
        n_steps=8,
        n_paths=3,
        seed=7,
    )
    ref = simulate(params, control=control, **kw)
    got = simulate(params, control=torch.as_tensor(control), **kw)
    assert isinstance(got.positions, torch.Tensor) and got.positions.dtype == torch.float64
    assert not ref.diverged and not got.diverged
    np.testing.assert_allclose(got.positions.numpy(), ref.positions, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(got.controls.numpy(), ref.controls, rtol=0, atol=0)


@pytest.mark.parametrize("kernel", ["symmetric", "nonsymmetric"])
@pytest.mark.parametrize("phi_method", PHI)
def test_backend_argument_and_stiff_nonsymmetric_runs_agree(kernel, phi_method):
    if kernel == "nonsymmetric" and phi_method == "eigh":
        pytest.skip("eigh needs a symmetric matrix")
    params = SwarmParams(n_agents=70, kernel=kernel, epsilon=0.05, sigma=0.01)
    kw = dict(integrator="serb", phi_method=phi_method, n_steps=5, n_paths=2, seed=3)
    ref = simulate(params, **kw)
    got = simulate(params, backend="torch", device="cpu", **kw)
    np.testing.assert_allclose(got.positions.numpy(), ref.positions, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("order", [1, 2])
@pytest.mark.parametrize("method", ["expm", "eigh", "krylov"])
def test_phi_action_torch_matches_numpy(order, method):
    rng = np.random.default_rng(0)
    b = rng.normal(size=(3, 30, 30))
    a = -np.einsum("bij,bkj->bik", b, b) / 30 * 20.0
    v = rng.normal(size=(3, 30, 2))
    ref = phi_action(a, v, order, method=method, symmetric=True)
    got = phi_action(torch.as_tensor(a), torch.as_tensor(v), order, method=method, symmetric=True)
    np.testing.assert_allclose(got.numpy(), ref, rtol=1e-12, atol=1e-12)


def test_issue_snippet_gives_gradient_and_the_numpy_noise():
    x0 = _x0(20)
    u = torch.zeros((5, 20, 1), dtype=torch.float64, requires_grad=True)
    params = SwarmParams(n_agents=20, epsilon=0.05, sigma=0.01)
    traj = simulate(
        params,
        integrator="serb",
        n_steps=5,
        n_paths=2,
        seed=0,
        initial_positions=torch.as_tensor(x0, dtype=torch.float64),
        control=u,
    )
    traj.positions.pow(2).sum().backward()
    assert isinstance(traj.positions, torch.Tensor)
    assert u.grad is not None and torch.all(torch.isfinite(u.grad)) and u.grad.abs().sum() > 0
    ref = simulate(params, integrator="serb", n_steps=5, n_paths=2, seed=0, initial_positions=x0)
    np.testing.assert_allclose(traj.positions.detach().numpy(), ref.positions, atol=1e-12)


def _small_setup(n=5, paths=2):
    params = SwarmParams(n_agents=n, epsilon=0.05, sigma=0.1)
    rng = np.random.default_rng(2)
    x = torch.as_tensor(rng.uniform(-1, 1, (paths, n, 1)), dtype=torch.float64)
    u = torch.as_tensor(rng.normal(size=(paths, n, 1)), dtype=torch.float64)
    dw = torch.as_tensor(rng.normal(size=(paths, n, 1)) * 0.1, dtype=torch.float64)
    return params, x.requires_grad_(), u.requires_grad_(), dw


@pytest.mark.parametrize(
    "integrator, jacobian, phi_method",
    [
        ("em", "frozen", "auto"),
        ("serb", "frozen", "eigh"),
        ("serb", "frozen", "expm"),
        ("serb", "frozen", "krylov"),
        ("serb", "exact", "eigh"),
    ],
)
def test_gradcheck_one_step(integrator, jacobian, phi_method):
    params, x, u, dw = _small_setup()
    model = SwarmModel(params)
    scheme = make_integrator(integrator, jacobian=jacobian, phi_method=phi_method)
    assert torch.autograd.gradcheck(
        lambda x, u: scheme.step(model, x, u, 0.0, 0.02, dw), (x, u), atol=1e-7, rtol=1e-6
    )


@pytest.mark.parametrize("integrator", ["em", "serb"])
def test_gradcheck_five_step_rollout(integrator):
    # Stable for EM at tau = 0.2 (alpha = 0.5, eps = 0.5), so finite differences are meaningful.
    params = SwarmParams(n_agents=5, alpha=0.5, epsilon=0.5, sigma=0.1)
    rng = np.random.default_rng(5)
    x0 = torch.as_tensor(rng.uniform(-1, 1, 5), dtype=torch.float64).requires_grad_()
    u = torch.as_tensor(rng.normal(size=(5, 2, 5, 1)), dtype=torch.float64).requires_grad_()

    def rollout(x0, u):
        traj = simulate(
            params,
            integrator=integrator,
            n_steps=5,
            n_paths=2,
            seed=0,
            initial_positions=x0,
            control=u,
        )
        return traj.positions

    assert torch.autograd.gradcheck(rollout, (x0, u), atol=1e-7, rtol=1e-6)


def _fd_gradient(fun, a: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """Central differences of a scalar function along symmetric perturbations E_ij + E_ji."""
    n = a.shape[0]
    grad = np.zeros_like(a)
    for i in range(n):
        for j in range(i, n):
            e = np.zeros_like(a)
            e[i, j] += 0.5
            e[j, i] += 0.5
            grad[i, j] = grad[j, i] = (fun(a + h * e) - fun(a - h * e)) / (2 * h)
    return grad


@pytest.mark.parametrize("order", [1, 2])
def test_eigh_gradient_at_repeated_eigenvalue_is_finite_and_matches_fd(order):
    # L(x) at consensus: all agents at one point, an (N-1)-fold eigenvalue -p(0)/1 and 0.
    n = 6
    model = SwarmModel(SwarmParams(n_agents=n, epsilon=0.05))
    lx = model.frozen_linearization(np.full((n, 1), 0.3))
    lam = np.linalg.eigvalsh(lx)
    assert np.sum(np.isclose(lam, lam[0])) == n - 1  # repeated
    a = 0.02 * lx
    rng = np.random.default_rng(0)
    v = rng.normal(size=(n, 2))
    w = rng.normal(size=(n, 2))

    at = torch.as_tensor(a).requires_grad_()
    y = phi_action(at, torch.as_tensor(v), order, method="eigh", symmetric=True)
    (y * torch.as_tensor(w)).sum().backward()
    grad = at.grad.numpy()
    assert np.all(np.isfinite(grad))
    # torch's own eigh backward is not finite here (the reason for the custom backward).
    at2 = torch.as_tensor(a).requires_grad_()
    lam_t, q_t = torch.linalg.eigh(at2)
    (q_t @ torch.diag(lam_t) @ q_t.mT).sum().backward()
    assert not torch.all(torch.isfinite(at2.grad))

    def fun(b):
        return float(np.sum(phi_action(b, v, order, method="expm") * w))

    np.testing.assert_allclose(grad, _fd_gradient(fun, a), rtol=1e-6, atol=1e-8)


def test_eigh_gradient_matches_expm_and_krylov_gradients():
    n = 8
    params = SwarmParams(n_agents=n, epsilon=0.05)
    x = torch.as_tensor(_x0(n, 3)[:, None])
    v = torch.as_tensor(np.random.default_rng(1).normal(size=(n, 1)))
    grads = {}
    for method in ("eigh", "expm", "krylov"):
        xg = x.clone().requires_grad_()
        a = 0.02 * SwarmModel(params).frozen_linearization(xg)
        phi_action(a, v, 1, method=method, symmetric=True).pow(2).sum().backward()
        grads[method] = xg.grad.numpy()
    np.testing.assert_allclose(grads["eigh"], grads["expm"], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(grads["krylov"], grads["expm"], rtol=1e-7, atol=1e-10)


def test_gradient_through_consensus_state_is_finite():
    # All agents start together: L(x) has an (N-1)-fold eigenvalue on the first step.
    u = torch.zeros((3, 10, 1), dtype=torch.float64, requires_grad=True)
    traj = simulate(
        SwarmParams(n_agents=10, epsilon=0.05, sigma=0.0),
        integrator="serb",
        phi_method="eigh",
        n_steps=3,
        n_paths=1,
        seed=0,
        initial_positions=torch.full((10,), 0.2, dtype=torch.float64),
        control=u,
    )
    traj.positions.sum().backward()
    assert torch.all(torch.isfinite(u.grad))


def test_divergence_is_flagged_on_torch():
    # A control of 1e6 on the third step throws the agents past the threshold (1e4).
    params = SwarmParams(n_agents=30, epsilon=0.05, sigma=0.01)
    control = np.zeros((5, 30, 1))
    control[2] = 1e6
    kw = dict(integrator="serb", n_steps=5, n_paths=2, seed=0)
    ref = simulate(params, control=control, **kw)
    got = simulate(params, control=torch.as_tensor(control), **kw)
    assert ref.diverged and got.diverged and got.divergence_step == 3
    assert got.divergence_step == ref.divergence_step
    np.testing.assert_array_equal(got.diverged_paths, ref.diverged_paths)
    step = got.divergence_step
    assert torch.all(torch.isnan(got.positions[step:]))
    assert torch.all(torch.isfinite(got.positions[:step]))


def test_bad_backend_and_device_are_rejected():
    params = SwarmParams(n_agents=5)
    with pytest.raises(ValueError, match="backend"):
        simulate(params, backend="jax", n_steps=2)
    with pytest.raises(ValueError, match="device"):
        simulate(params, backend="numpy", device="cuda", n_steps=2)
    with pytest.raises(ValueError, match="torch tensors"):
        simulate(params, backend="numpy", n_steps=2, initial_positions=torch.zeros(5))


@CUDA
@pytest.mark.parametrize("integrator", SCHEMES)
def test_cuda_matches_cpu(integrator):
    params = SwarmParams(n_agents=40, epsilon=0.5, sigma=0.05)
    kw = dict(integrator=integrator, n_steps=6, n_paths=4, seed=1)
    cpu = simulate(params, **kw)
    gpu = simulate(params, device="cuda", **kw)
    assert gpu.positions.device.type == "cuda"
    np.testing.assert_allclose(gpu.positions.cpu().numpy(), cpu.positions, rtol=1e-9, atol=1e-10)


@CUDA
def test_cuda_gradient_is_finite():
    u = torch.zeros((4, 30, 1), dtype=torch.float64, device="cuda", requires_grad=True)
    traj = simulate(SwarmParams(n_agents=30), n_steps=4, n_paths=3, seed=0, control=u)
    traj.positions.pow(2).sum().backward()
    assert torch.all(torch.isfinite(u.grad))


def _symmetric_tridiagonals(batch: int, m: int, device: str) -> torch.Tensor:
    gen = torch.Generator(device=device).manual_seed(0)
    diag = torch.randn((batch, 1, m), generator=gen, device=device, dtype=torch.float64)
    off = torch.rand((batch, 1, m - 1), generator=gen, device=device, dtype=torch.float64)
    return torch.diag_embed(diag) + torch.diag_embed(off, 1) + torch.diag_embed(off, -1)


def test_eigh_off_cuda_is_the_library_call():
    from agent_envs import arrays

    t = _symmetric_tridiagonals(7, 5, "cpu")
    lam, q = arrays.eigh(t)
    want = torch.linalg.eigh(t)
    assert torch.equal(lam, want[0]) and torch.equal(q, want[1])
    lam_np, q_np = arrays.eigh(t.numpy())
    want_np = np.linalg.eigh(t.numpy())
    np.testing.assert_array_equal(lam_np, want_np[0])
    np.testing.assert_array_equal(q_np, want_np[1])


@CUDA
def test_cuda_eigh_in_batches_equals_one_call(monkeypatch):
    from agent_envs import arrays

    t = _symmetric_tridiagonals(10, 6, "cuda")
    whole = torch.linalg.eigh(t)
    monkeypatch.setattr(arrays, "CUDA_EIGH_MAX_BATCH", 3)
    lam, q = arrays.eigh(t)
    assert lam.shape == whole[0].shape and q.shape == whole[1].shape
    torch.testing.assert_close(lam, whole[0], rtol=0, atol=1e-12)
    residual = t @ q - q * lam[..., None, :]
    assert float(residual.abs().max()) < 1e-12


@CUDA
def test_cuda_eigh_of_the_paper_scale_batch():
    """81 920 tridiagonals (4096 envs x 20 paths): one cuSOLVER call of this batch failed with
    an internal error on an H100; `arrays.eigh` splits it."""
    from agent_envs import arrays

    t = _symmetric_tridiagonals(81_920, 27, "cuda")
    lam, q = arrays.eigh(t)
    residual = t @ q - q * lam[..., None, :]
    assert float(residual.abs().max()) < 1e-12
    assert bool(torch.all(lam[..., 1:] >= lam[..., :-1]))


def test_krylov_gradient_is_finite_when_some_columns_break_down():
    """Agents on a line in d = 2: the second coordinate's Krylov column is zero and breaks
    down at once while the first goes on; the gradient must stay finite (the Lanczos norm's
    gradient at 0)."""
    torch = pytest.importorskip("torch")
    n = 60
    x0 = np.zeros((n, 2))
    x0[:, 0] = np.linspace(-1.0, 1.0, n)
    u = torch.zeros((3, n, 2), dtype=torch.float64, requires_grad=True)
    traj = simulate(
        SwarmParams(n_agents=n, dim=2, sigma=0.0),
        integrator="serb",
        n_steps=3,
        n_paths=1,
        seed=0,
        initial_positions=torch.as_tensor(x0),
        control=u,
        phi_method="krylov",
    )
    traj.positions.pow(2).sum().backward()
    assert u.grad is not None
    assert bool(torch.all(torch.isfinite(u.grad)))


# --------------------------------------------------------------- user kernels on the torch path


class NumpyGaussianKernel:
    """Written the natural numpy way: works on numpy, not on torch."""

    symmetric = True

    def value(self, xk, xl):
        return np.exp(-np.sum((xk - xl) ** 2, axis=-1))

    def grad_x(self, xk, xl):
        return 2.0 * (xl - xk) * self.value(xk, xl)[..., None]

    def grad_y(self, xk, xl):
        return -self.grad_x(xk, xl)


class ArrayGenericGaussianKernel(NumpyGaussianKernel):
    """The same kernel written array-generically (the docs' example): numpy and torch."""

    def value(self, xk, xl):
        from agent_envs import arrays

        xp = arrays.namespace(xk)
        return xp.exp(-xp.sum((xk - xl) ** 2, axis=-1))


class AnswersNumpyKernel(NumpyGaussianKernel):
    """Runs on torch input but answers a numpy array (converts its input)."""

    def value(self, xk, xl):
        return super().value(np.asarray(xk), np.asarray(xl))


@pytest.mark.parametrize("kernel", [NumpyGaussianKernel(), AnswersNumpyKernel()])
def test_numpy_style_kernel_on_torch_is_one_clear_type_error(kernel):
    pytest.importorskip("torch")
    params = SwarmParams(n_agents=4, kernel=kernel)
    simulate(params, "serb", n_steps=3, n_paths=2, seed=0)  # fine on numpy
    # (?s): torch's own message, quoted in ours, spans lines in some releases (2.11's does)
    pattern = f"(?s)kernel {type(kernel).__name__}.value.*arrays.namespace"
    with pytest.raises(TypeError, match=pattern):
        simulate(params, "serb", n_steps=3, n_paths=2, seed=0, backend="torch")


def test_numpy_style_kernel_in_the_solver_is_one_clear_type_error():
    pytest.importorskip("torch")
    from agent_envs.baselines.optimal_control import solve_optimal_control

    params = SwarmParams(n_agents=3, kernel=NumpyGaussianKernel())
    with pytest.raises(TypeError, match="kernel NumpyGaussianKernel"):
        solve_optimal_control(params, "serb", n_steps=2, n_paths=1, max_iterations=1)


def test_array_generic_kernel_runs_on_both_libraries_alike():
    pytest.importorskip("torch")
    params = SwarmParams(n_agents=5, kernel=ArrayGenericGaussianKernel(), sigma=0.1)
    a = simulate(params, "serb", n_steps=4, n_paths=2, seed=3)
    b = simulate(params, "serb", n_steps=4, n_paths=2, seed=3, backend="torch")
    np.testing.assert_allclose(np.asarray(b.positions), a.positions, rtol=0, atol=1e-12)
