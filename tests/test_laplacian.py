"""The workspace path of the frozen linearization (agent_envs.dynamics.laplacian).

Checked against independent values: the drift written out as a double sum, L(x) built entry by
entry, the eigenvalues of L(x) from LAPACK for the Krylov bounds, and the dense eigh phi-action
for the early-stopped Lanczos iteration.
"""

from __future__ import annotations

import numpy as np
import pytest

from agent_envs import SwarmModel, SwarmParams, make_integrator
from agent_envs.integrators.phi_functions import phi_action


def _states(n: int, n_paths: int, d: int = 1) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(3)
    spread = rng.uniform(-1.0, 1.0, (n_paths, n, d))
    # near consensus: the noise-driven spread of the paper's setting (~1e-4 around 0.3)
    consensus = 0.3 + 1e-4 * rng.standard_normal((n_paths, n, d))
    mixed = np.concatenate([spread[: n_paths // 2], consensus[n_paths // 2 :]])
    return {"spread": spread, "consensus": consensus, "mixed": mixed}


def _drift_by_sums(x: np.ndarray, alpha: float, eps: float) -> np.ndarray:
    """(1/N) sum_l p(x_k, x_l)(x_l - x_k), p = 1/(eps (alpha^2 + |x_k - x_l|^2)), by loops."""
    n_paths, n, _ = x.shape
    out = np.zeros_like(x)
    for b in range(n_paths):
        for k in range(n):
            for j in range(n):
                r = x[b, j] - x[b, k]
                out[b, k] += r / (eps * (alpha**2 + r @ r))
    return out / n


@pytest.mark.parametrize("d", [1, 2])
def test_workspace_drift_is_the_double_sum(d):
    params = SwarmParams(n_agents=12, dim=d, target=0.7 if d == 1 else (0.7, 0.7))
    model = SwarmModel(params)
    x = _states(12, 3, d)["spread"]
    expected = _drift_by_sums(x, params.alpha, params.epsilon)
    np.testing.assert_allclose(model.interaction_drift(x), expected, rtol=1e-12, atol=1e-12)
    f, lin = model.drift_and_linearization(0.0, x, None, "frozen")
    np.testing.assert_allclose(f, expected, rtol=1e-12, atol=1e-12)
    # the operator is L(x): its dense form and its products match the public matrix
    dense = model.frozen_linearization(x)
    np.testing.assert_allclose(lin.matrix.dense(), dense, rtol=1e-13, atol=1e-10)
    v = np.random.default_rng(0).standard_normal((3, 12, 2))
    np.testing.assert_allclose(lin.matrix @ v, dense @ v, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose((0.02 * lin.matrix) @ v, 0.02 * (dense @ v), rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("state", ["spread", "consensus", "mixed"])
def test_krylov_bounds_contain_the_spectrum(state):
    """||L||_inf is the row-sum norm, and spec(L) \\ {0} lies in [-p_max, -p_max + width]."""
    params = SwarmParams(n_agents=40)
    model = SwarmModel(params)
    x = _states(40, 6)[state]
    _, lin = model.drift_and_linearization(0.0, x, None, "frozen")
    norms, widths, low = lin.matrix.krylov_bounds()
    dense = model.frozen_linearization(x)
    np.testing.assert_allclose(norms, np.abs(dense).sum(axis=-1).max(axis=-1), rtol=1e-12)
    peak = 1.0 / (params.epsilon * params.alpha**2)
    for b in range(6):
        eig = np.sort(np.linalg.eigvalsh(dense[b]))
        assert abs(eig[-1]) <= 1e-9 * peak  # L 1 = 0: the eigenvalue 0
        rest = eig[:-1]
        assert np.all(rest >= -peak - 1e-9 * peak)
        assert np.all(rest >= low - 1e-9 * peak)  # the bottom the Lanczos error bound reads
        assert np.all(rest <= -peak + widths[b] + 1e-9 * peak)
    if state == "consensus":
        assert np.all(widths < 1e-3 * norms)  # the cluster the early check relies on


def test_early_stopped_lanczos_matches_the_dense_phi_action():
    """With the width bound the iteration stops after a few steps near consensus; the result
    still matches the eigh phi-action of the dense tau L(x) to the Krylov tolerance."""
    params = SwarmParams(n_agents=100)
    model = SwarmModel(params)
    for x in _states(100, 8).values():
        _, lin = model.drift_and_linearization(0.0, x, None, "frozen")
        v = np.random.default_rng(1).standard_normal((8, 100, 1))
        scaled = 0.02 * lin.matrix
        dense = 0.02 * model.frozen_linearization(x)
        for order in (1, 2):
            got = phi_action(scaled, v, order, method="krylov", symmetric=True)
            ref = phi_action(dense, v, order, method="eigh", symmetric=True)
            scale = np.linalg.norm(ref, axis=-2, keepdims=True)
            assert np.max(np.abs(got - ref) / scale) < 1e-8


def test_serb_step_on_the_workspace_matches_the_array_api_path():
    """SERB through the FrozenLaplacian vs a model forced onto the Array-API path (a kernel
    that is not a CuckerSmaleKernel instance, same formula): equal to the Krylov tolerance."""
    params = SwarmParams(n_agents=100)
    model = SwarmModel(params)

    class Plain:
        symmetric = True
        radial = True

        def __init__(self, inner):
            self.inner = inner

        def value(self, xk, xl):
            return self.inner.value(xk, xl)

        def grad_x(self, xk, xl):
            return self.inner.grad_x(xk, xl)

        def grad_y(self, xk, xl):
            return self.inner.grad_y(xk, xl)

    reference = SwarmModel(params)
    reference.kernel = Plain(model.kernel)
    serb = make_integrator("serb")
    dense = make_integrator("serb", phi_method="eigh")
    rng = np.random.default_rng(2)
    for x in _states(100, 6).values():
        dw = np.sqrt(0.02) * rng.standard_normal(x.shape)
        u = rng.uniform(-5, 5, (100, 1))
        got = serb.step(model, x, u, 0.0, 0.02, dw)
        # the reference has no row-sum bounds (user kernel): Saad's estimate from
        # m >= 3.5 sqrt(||A||); the workspace path stops by its error bound, at other
        # dimensions, so the two agree to the Krylov tolerance, and each with the dense step
        ref = serb.step(reference, x, u, 0.0, 0.02, dw)
        exact = dense.step(model, x, u, 0.0, 0.02, dw)
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-10)
        np.testing.assert_allclose(got, exact, rtol=0, atol=1e-10)
        np.testing.assert_allclose(ref, exact, rtol=0, atol=1e-10)


def test_a_stale_operator_raises_instead_of_using_the_overwritten_matrix():
    model = SwarmModel(SwarmParams(n_agents=10))
    x = _states(10, 2)
    _, first = model.drift_and_linearization(0.0, x["spread"], None, "frozen")
    v = np.ones((2, 10, 1))
    first.matrix @ v  # current: fine
    model.interaction_drift(x["consensus"])  # overwrites the workspace's P
    with pytest.raises(RuntimeError, match="overwritten"):
        first.matrix @ v
    # a fresh evaluation works, and the public matrix is never a workspace view
    dense = model.frozen_linearization(x["spread"])
    model.interaction_drift(x["consensus"])
    np.testing.assert_allclose(dense, model.frozen_linearization(x["spread"]))


@pytest.mark.parametrize("integrator", ["serb", "em"])
def test_an_env_step_allocates_no_kernel_sized_array(integrator):
    """After the first step, stepping allocates nothing of the size of one kernel matrix batch
    (n_paths N^2 floats): P lives in the model's workspace (numpy reports its allocations to
    tracemalloc). What remains is small arrays and numpy's own iterator buffer of a broadcast
    ufunc (a fixed 128 KiB, whatever N), below half of the 640 kB batch here."""
    import tracemalloc

    from agent_envs.envs import SwarmEnv

    env = SwarmEnv(n_agents=100, n_paths=8, n_steps=50, integrator=integrator)
    env.reset(seed=0)
    action = np.full(100, 0.1, dtype=np.float32)
    for _ in range(3):
        env.step(action)
    kernel_bytes = 8 * 8 * 100 * 100
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        for _ in range(5):
            env.step(action)
        peak = tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()
    assert peak < kernel_bytes / 2, peak


@pytest.mark.parametrize(("shape", "alignment"), [((3,), 64), ((20, 100, 100), 64), ((2, 7), 32)])
def test_aligned_empty_starts_on_the_alignment(shape, alignment):
    from agent_envs import arrays

    a = arrays.aligned_empty(shape, alignment)
    assert a.shape == shape and a.dtype == np.float64
    assert a.flags.c_contiguous and a.flags.writeable
    assert a.ctypes.data % alignment == 0
    with pytest.raises(ValueError, match="alignment"):
        arrays.aligned_empty(shape, 12)


def test_env_steps_do_not_depend_on_where_the_workspace_lives(monkeypatch):
    """The workspace's P starts on a cache line (`arrays.aligned_empty`), and the steps' bits do
    not depend on where it starts (the vectorized loops' order of sums is the machine code's,
    not the address's): 30 SERB env steps with P at four offsets mod 64 bytes give the same
    positions and rewards bit for bit. The native vector env's equality with its single twins
    rests on this, their P being different arrays."""
    import gymnasium as gym

    import agent_envs  # noqa: F401
    from agent_envs import arrays
    from agent_envs.envs import ENV_ID

    runs = []
    for shift in (0, 1, 2, 5):  # in float64 entries from a 64-byte boundary

        def shifted(shape, alignment=64, shift=shift):
            size = int(np.prod(shape))
            raw = np.empty(size + 16)
            start = (-raw.ctypes.data % 64) // 8 + shift
            return raw[start : start + size].reshape(shape)

        monkeypatch.setattr(arrays, "aligned_empty", shifted)
        env = gym.make(ENV_ID, n_agents=40, n_paths=4, epsilon=0.05).unwrapped
        env.reset(seed=3)
        action = np.random.default_rng(1).uniform(-0.5, 0.5, env.action_space.shape)
        rewards = [env.step(action.astype(np.float32))[1] for _ in range(30)]
        runs.append((np.array(env.episode.positions), np.array(rewards)))
    for positions, rewards in runs[1:]:
        np.testing.assert_array_equal(positions, runs[0][0])
        np.testing.assert_array_equal(rewards, runs[0][1])
