"""The compiled kernel pass (numba) against the numpy passes of the dense workspace path.

`agent_envs.native.kernel` builds P, s = P 1 and L(x) x for the symmetric
Cucker-Smale kernel when numba is installed; these tests require it (skipped without numba:
the `dev` extra installs it, so CI runs them).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agent_envs import SwarmModel, SwarmParams
from agent_envs.dynamics import laplacian


@pytest.fixture()
def compiled():
    pytest.importorskip("numba")
    before = laplacian.use_compiled_kernel(True)
    assert laplacian.load_compiled_kernel(), "numba is installed but the kernel did not load"
    yield
    laplacian.use_compiled_kernel(before)


def _numpy_pass(x, alpha, weight):
    """P, s and L(x) x as the numpy path computes them (fill_cucker_smale, P [x | 1])."""
    n = x.shape[-2]
    p = np.empty((*x.shape[:-1], n))
    laplacian.fill_cucker_smale(x, alpha, weight, out=p)
    s = p.sum(axis=-1)
    return p, s, (p @ x - s[..., None] * x) / n


@pytest.mark.parametrize("d", [1, 2, 3])
@pytest.mark.parametrize("batch", [(), (3,), (2, 3)])
def test_kernel_pass_equals_the_numpy_passes(compiled, d, batch):
    n, alpha, weight = 37, 0.3, 1.0 / 0.05
    x = np.random.default_rng(d).uniform(-1, 1, (*batch, n, d))
    p = np.empty((*batch, n, n))
    p = np.full((*batch, n, n), np.nan)
    s, drift = laplacian.compiled_cucker_smale_drift(x, weight, alpha**2, p)
    want_p, want_s, want_drift = _numpy_pass(x, alpha, weight)
    assert s.shape == want_s.shape and drift.shape == want_drift.shape
    lower = np.tril(np.ones((n, n), dtype=bool))
    assert not np.isnan(p[..., lower]).any()  # the lower triangle and the diagonal written,
    assert np.isnan(p[..., ~lower]).all()  # the upper one left
    laplacian.UpperTriangle(p).complete()
    np.testing.assert_array_equal(p, np.swapaxes(p, -1, -2))  # exactly symmetric
    np.testing.assert_array_equal(p, want_p)  # each entry the same IEEE operations
    assert np.max(np.abs(s - want_s)) <= 1e-14 * np.max(want_s)
    assert np.max(np.abs(drift - want_drift)) <= 1e-13 * np.max(np.abs(want_drift))


def test_a_member_does_not_depend_on_the_batch(compiled):
    x = np.random.default_rng(0).uniform(-1, 1, (5, 40, 2))
    p = np.zeros((5, 40, 40))
    s, drift = laplacian.compiled_cucker_smale_drift(x, 3.0, 0.01, p)
    for i in range(5):
        pi = np.zeros((1, 40, 40))
        si, di = laplacian.compiled_cucker_smale_drift(x[i : i + 1], 3.0, 0.01, pi)
        np.testing.assert_array_equal(pi[0], p[i])
        np.testing.assert_array_equal(si[0], s[i])
        np.testing.assert_array_equal(di[0], drift[i])


@pytest.mark.parametrize("kernel", ["symmetric", "nonsymmetric"])
def test_the_model_drift_and_operator_agree_with_the_numpy_path(compiled, kernel):
    """The model's drift and its frozen operator (P, s) with and without the compiled pass; the
    non-symmetric kernel (per-agent weights) keeps the numpy passes."""
    params = SwarmParams(n_agents=60, dim=2, epsilon=0.05, kernel=kernel)
    x = np.random.default_rng(1).uniform(-1, 1, (4, 60, 2))

    def evaluate(enabled):
        before = laplacian.use_compiled_kernel(enabled)
        try:
            model = SwarmModel(params, linear_operator="dense")
            f, lin = model.drift_and_linearization(0.0, x, None, "frozen")
            return f, np.array(lin.matrix.dense())
        finally:
            laplacian.use_compiled_kernel(before)

    (f_fast, l_fast), (f_slow, l_slow) = evaluate(True), evaluate(False)
    assert np.max(np.abs(f_fast - f_slow)) <= 1e-13 * np.max(np.abs(f_slow))
    assert np.max(np.abs(l_fast - l_slow)) <= 1e-14 * np.max(np.abs(l_slow))
    if kernel == "nonsymmetric":
        np.testing.assert_array_equal(f_fast, f_slow)


@given(
    n=st.integers(1, 40),
    d=st.integers(1, 3),
    paths=st.integers(1, 3),
    spread=st.sampled_from([0.0, 1e-6, 0.3, 5.0]),
    alpha=st.floats(0.05, 2.0),
    seed=st.integers(0, 2**16),
)
@settings(max_examples=60, deadline=None)
def test_kernel_pass_equals_the_numpy_passes_on_any_swarm(n, d, paths, spread, alpha, seed):
    """Any N (one agent included), d, batch and spread (coincident agents included)."""
    pytest.importorskip("numba")
    assert laplacian.load_compiled_kernel()
    weight = 1.0 / 0.05
    x = np.random.default_rng(seed).uniform(-spread, spread, (paths, n, d))
    p = np.empty((paths, n, n))
    s, drift = laplacian.compiled_cucker_smale_drift(x, weight, alpha**2, p)
    laplacian.UpperTriangle(p).complete()
    want_p, want_s, want_drift = _numpy_pass(x, alpha, weight)
    np.testing.assert_array_equal(p, want_p)  # each entry the same IEEE operations
    assert np.max(np.abs(s - want_s)) <= 1e-14 * np.max(want_s)
    scale = max(np.max(np.abs(want_drift)), np.max(want_s) * max(spread, 1e-300) / n)
    assert np.max(np.abs(drift - want_drift)) <= 1e-13 * scale


def test_upper_triangle_is_filled_once_compiled_or_not(compiled):
    """`UpperTriangle.complete` mirrors the lower triangle, compiled and with numpy alike, and
    only the first time; the operator's `matrix` asks for it, `parts()` (the compiled Lanczos,
    which reads the lower triangle) does not."""
    x = np.random.default_rng(3).uniform(-1, 1, (2, 30, 1))
    p = np.full((2, 30, 30), np.nan)
    laplacian.compiled_cucker_smale_drift(x, 20.0, 0.01, p)
    numpy_filled = p.copy()
    upper = laplacian.UpperTriangle(numpy_filled)
    before = laplacian.use_compiled_kernel(False)
    try:
        upper.complete()
    finally:
        laplacian.use_compiled_kernel(before)
    compiled_filled = p.copy()
    laplacian.UpperTriangle(compiled_filled).complete()
    np.testing.assert_array_equal(compiled_filled, numpy_filled)
    np.testing.assert_array_equal(compiled_filled, np.swapaxes(compiled_filled, -1, -2))
    numpy_filled[0, 0, 1] = -1.0  # done: a second call writes nothing
    upper.complete()
    assert numpy_filled[0, 0, 1] == -1.0

    model = SwarmModel(SwarmParams(n_agents=30, epsilon=0.05), linear_operator="dense")
    _, lin = model.drift_and_linearization(0.0, x, None, "frozen")
    raw, _ = lin.matrix.parts()
    assert not np.array_equal(raw, np.swapaxes(raw, -1, -2))  # the upper triangle unwritten
    full = lin.matrix.matrix
    np.testing.assert_array_equal(full, np.swapaxes(full, -1, -2))
    want = model.frozen_linearization(x)  # the Array-API path: sums in another order
    assert np.max(np.abs(lin.matrix.dense() - want)) <= 1e-14 * np.max(np.abs(want))


@pytest.mark.parametrize("integrator", ["serb", "erb", "em"])
def test_env_steps_never_fill_the_upper_triangle(compiled, monkeypatch, integrator):
    """The kernel pass leaves P's upper triangle unwritten so that a step does not pay for it:
    an env step (the compiled Lanczos, the fused step, Euler-Maruyama) never asks for it."""
    import gymnasium as gym

    from agent_envs.envs import ENV_ID

    filled = []
    original = laplacian.UpperTriangle.complete

    def complete(self):
        filled.append(self.done)
        original(self)

    monkeypatch.setattr(laplacian.UpperTriangle, "complete", complete)
    env = gym.make(ENV_ID, n_agents=100, n_steps=5, n_paths=3, integrator=integrator)
    env.reset(seed=0)
    for _ in range(5):
        env.step(env.action_space.sample())
    assert filled == []


def test_copies_and_pickles_carry_the_whole_matrix(compiled):
    """A model or env copied (deepcopy, pickle) after the compiled pass wrote only P's lower
    triangle: the copy's operator is the whole P, and a copied env steps like the original
    (found in review: the copy of the operator's view of P kept the unwritten triangle)."""
    import copy
    import pickle

    import gymnasium as gym

    from agent_envs.envs import ENV_ID

    model = SwarmModel(SwarmParams(n_agents=13, epsilon=0.05), linear_operator="dense")
    x = np.random.default_rng(5).uniform(-1, 1, (3, 13, 1))
    x.flags.writeable = False
    want = model.frozen_linearization(x)
    for clone in (copy.deepcopy, lambda m: pickle.loads(pickle.dumps(m))):
        _, lin = model.drift_and_linearization(0.0, x, None, "frozen")
        copied = clone(lin)
        assert np.max(np.abs(copied.matrix.dense() - want)) <= 1e-14 * np.max(np.abs(want))

    env = gym.make(ENV_ID, n_agents=13, n_paths=2, integrator="erb", phi_method="eigh")
    env.reset(seed=0)
    action = np.zeros(env.action_space.shape, dtype=np.float32)
    env.step(action)
    twin = copy.deepcopy(env)
    np.testing.assert_array_equal(env.step(action)[0], twin.step(action)[0])
