"""The compiled Lanczos (numba) against the numpy Lanczos and the Array-API reference.

`agent_envs.native.lanczos` serves phi_p(c L(x)) V for the frozen L(x) on numpy
when numba is installed; these tests require it (skipped without numba: the `dev` extra
installs it, so CI runs them). Without numba the package must still import and step
(`test_package_works_without_numba`, which runs everywhere).
"""

from __future__ import annotations

import subprocess
import sys
import textwrap

import gymnasium as gym
import numpy as np
import pytest

import agent_envs  # noqa: F401  (registers the env ids)
from agent_envs import SwarmModel, SwarmParams, make_integrator, native
from agent_envs.integrators import phi_functions as pf
from agent_envs.integrators import phi_krylov
from agent_envs.integrators.krylov_space import RowOperator
from agent_envs.integrators.lanczos_stopping import next_checks
from agent_envs.integrators.phi_fused import compiled_frozen_lanczos
from agent_envs.integrators.phi_lanczos import lanczos_action, lanczos_numpy
from agent_envs.native import lanczos_rule

TOL = 1e-12


def _needs_numba():
    pytest.importorskip("numba")
    assert pf.load_compiled(), "numba is installed but the compiled Lanczos did not load"


@pytest.fixture()
def compiled():
    """The compiled path on for the test (and restored after)."""
    _needs_numba()
    before = pf.use_compiled(True)
    yield native.loaded("lanczos")
    pf.use_compiled(before)


@pytest.fixture()
def tridiagonal(compiled):
    """The compiled small eigenproblem of T_m (`agent_envs.native.lanczos_tridiagonal`)."""
    from agent_envs.native import lanczos_tridiagonal

    return lanczos_tridiagonal


def _frozen(n, d, paths, spread, seed, scale, kernel="symmetric"):
    params = SwarmParams(n_agents=n, dim=d, epsilon=0.05, kernel=kernel)
    model = SwarmModel(params, linear_operator="dense")
    rng = np.random.default_rng(seed)
    x = rng.uniform(-spread, spread, (*paths, n, d))
    f, lin = model.drift_and_linearization(0.0, x, None, "frozen")
    return model, x, f, scale * lin.matrix


CASES = [
    # (N, d, batch, spread): spread states (many Krylov steps), near consensus (few), d = 2
    (100, 1, (20,), 1.0),
    (100, 1, (), 0.01),
    (100, 1, (1,), 1e-6),
    (60, 2, (3,), 1.0),
    (100, 1, (2, 3), 0.3),
]


@pytest.mark.parametrize(("n", "d", "batch", "spread"), CASES)
@pytest.mark.parametrize("order", [1, 2])
def test_compiled_equals_numpy_and_reference_lanczos(compiled, n, d, batch, spread, order):
    _, _, f, op = _frozen(n, d, batch, spread, seed=n + d, scale=0.02)
    got, got_ok = compiled_frozen_lanczos(op, f, order, 1e-10, 100, None)
    rows = RowOperator(op)
    numpy_result, numpy_ok = lanczos_numpy(rows, f, order, 1e-10, 100)
    reference, reference_ok = lanczos_action(rows, f, order, 1e-10, 100)
    scale = np.max(np.abs(reference))
    assert got.shape == reference.shape == (*batch, n, d)
    np.testing.assert_array_equal(got_ok, reference_ok)
    np.testing.assert_array_equal(numpy_ok, reference_ok)
    assert np.max(np.abs(got - numpy_result)) <= TOL * scale
    assert np.max(np.abs(got - reference)) <= TOL * scale


@pytest.mark.parametrize("scale", [0.1, 0.3])
def test_compiled_equals_numpy_at_large_krylov_dimensions(compiled, scale):
    """Steps long enough for 23-27 Krylov dimensions (35-60 with Saad's estimate, before the
    error bound): the phi-action equals the numpy Lanczos, and a dimension short of what the
    members need leaves them flagged as not converged."""
    _, _, f, op = _frozen(100, 1, (3,), 1.0, seed=5, scale=scale)
    got, got_ok = compiled_frozen_lanczos(op, f, 1, 1e-10, 100, None)
    expected, expected_ok = lanczos_numpy(RowOperator(op), f, 1, 1e-10, 100)
    assert got_ok.all() and expected_ok.all()
    assert np.max(np.abs(got - expected)) <= TOL * np.max(np.abs(expected))
    _, short_ok = compiled_frozen_lanczos(op, f, 1, 1e-10, 20, None)
    _, short_numpy_ok = lanczos_numpy(RowOperator(op), f, 1, 1e-10, 20)
    assert not short_ok.any()
    np.testing.assert_array_equal(short_ok, short_numpy_ok)


def test_compiled_result_is_phi_of_the_matrix(compiled):
    """Against an independent value: the dense eigendecomposition of c L (to the Krylov
    tolerance), including a column of zeros (breakdown at m = 1)."""
    _, _, f, op = _frozen(100, 2, (4,), 0.5, seed=3, scale=0.02)
    f = np.array(f)
    f[1, :, 1] = 0.0
    got, ok = compiled_frozen_lanczos(op, f, 1, 1e-10, 100, None)
    lam, q = np.linalg.eigh(op.dense())
    want = q @ (pf.phi_scalar(lam, 1)[..., None] * (np.swapaxes(q, -1, -2) @ f))
    assert ok.all()
    assert np.max(np.abs(got - want)) <= 1e-9 * np.max(np.abs(want))
    np.testing.assert_array_equal(got[1, :, 1], 0.0)


@pytest.mark.parametrize("order", [1, 2])
def test_a_constant_vector_is_deflated_exactly(compiled, order):
    """phi_p(c L) (a 1) = a / p! (L 1 = 0): the compiled Lanczos deflates the constant vector
    like the numpy one (tests/test_phi_functions.py), so it returns the mean's part alone."""
    _, _, f, op = _frozen(100, 2, (3,), 0.5, seed=4, scale=0.02)
    v = np.empty_like(f)
    v[..., 0], v[..., 1] = 2.5, -0.75
    got, ok = compiled_frozen_lanczos(op, v, order, 1e-10, 100, None)
    assert ok.all()
    np.testing.assert_array_equal(got, v / order)  # 1/1!, 1/2!: the mean's part, exactly


def test_bounds_given_or_read_from_the_row_sums_agree(compiled):
    _, _, f, op = _frozen(100, 1, (5,), 1.0, seed=7, scale=0.02)
    from_sums, _ = compiled_frozen_lanczos(op, f, 1, 1e-10, 100, None)
    given, _ = compiled_frozen_lanczos(op, f, 1, 1e-10, 100, op.krylov_bounds())
    np.testing.assert_array_equal(from_sums, given)


def test_not_converged_members_are_flagged_like_the_reference(compiled):
    """With a Krylov dimension too small, the members that did not converge are the
    reference's, and `phi_action` replaces exactly those with the dense method."""
    _, _, f, op = _frozen(100, 1, (6,), 1.0, seed=11, scale=0.02)
    _, got_ok = compiled_frozen_lanczos(op, f, 1, 1e-10, 6, None)
    _, want_ok = lanczos_action(RowOperator(op), f, 1, 1e-10, 6)
    np.testing.assert_array_equal(got_ok, want_ok)
    assert not got_ok.all()
    with pytest.warns(RuntimeWarning, match="falling back"):
        got = pf.phi_action(op, f, 1, method="krylov", symmetric=True, max_krylov_dim=6)
    dense = pf.phi_action(op.dense(), f, 1, method="eigh", symmetric=True)
    assert np.max(np.abs(got - dense)) <= 1e-9 * np.max(np.abs(dense))


def test_a_member_does_not_depend_on_the_batch(compiled):
    """Each member is computed on its own: the batch's result equals the members' one by one
    bit for bit (what the native vector env's equality with SyncVectorEnv needs)."""
    model, x, f, op = _frozen(100, 1, (5,), 1.0, seed=5, scale=0.02)
    batched, _ = compiled_frozen_lanczos(op, f, 1, 1e-10, 100, None)
    for i in range(5):
        fi, lin = model.drift_and_linearization(0.0, x[i : i + 1], None, "frozen")
        one, _ = compiled_frozen_lanczos(0.02 * lin.matrix, fi, 1, 1e-10, 100, None)
        np.testing.assert_array_equal(one[0], batched[i])


def test_stale_operator_raises(compiled):
    model, x, f, op = _frozen(100, 1, (2,), 1.0, seed=1, scale=0.02)
    model.drift_and_linearization(0.0, x + 0.1, None, "frozen")  # overwrites P
    with pytest.raises(RuntimeError, match="overwritten"):
        compiled_frozen_lanczos(op, f, 1, 1e-10, 100, None)


def test_tridiagonal_eigensolver_against_lapack(tridiagonal):
    """The QL iteration's eigenvalues equal LAPACK's; its recorded rotations form an orthogonal
    Z with T Z = Z diag(d) (`apply_z` on the unit vectors), whose first and last rows are the
    two it carried along."""
    rng = np.random.default_rng(0)
    for m in (1, 2, 5, 17, 40):
        diag, off = rng.normal(size=m), rng.normal(size=m)
        off[m // 2] = 0.0  # a split
        d, e, rows = diag.copy(), off.copy(), np.empty((2, m))
        size = 2 * m * m + 8
        rot_c, rot_s, rot_at = np.empty(size), np.empty(size), np.empty(size, int)
        count = tridiagonal.tridiagonal_ql(d, e, rows, m, rot_c, rot_s, rot_at)
        assert count >= 0
        z = np.eye(m)
        for j in range(m):
            tridiagonal.apply_z(z[:, j], count, rot_c, rot_s, rot_at)
        t = np.diag(diag) + np.diag(off[: m - 1], 1) + np.diag(off[: m - 1], -1)
        order = np.argsort(d)
        np.testing.assert_allclose(d[order], np.linalg.eigvalsh(t), atol=1e-13)
        np.testing.assert_allclose(z.T @ z, np.eye(m), atol=1e-13)
        np.testing.assert_allclose(t @ z, z * d, atol=1e-12)
        np.testing.assert_allclose(rows, z[[0, m - 1]], atol=1e-14)


def test_tridiagonal_eigensolver_reports_a_full_rotation_buffer(tridiagonal):
    """More rotations than the buffers hold: -1 (the caller then takes LAPACK's eigh)."""
    m = 12
    rng = np.random.default_rng(1)
    d, e, rows = rng.normal(size=m), rng.normal(size=m), np.empty((2, m))
    tiny = np.empty(3)
    assert tridiagonal.tridiagonal_ql(d, e, rows, m, tiny, tiny.copy(), np.empty(3, int)) == -1


@pytest.mark.parametrize("order", [1, 2])
def test_phi_of_tridiagonal_from_rotations_equals_lapack(tridiagonal, order):
    """phi_p(T_m) e_1, Saad's estimate's parts and the error bound's (eigenvalues, Z's first
    and last rows, phi_p of the eigenvalues) from the QL rotations equal those from LAPACK's
    eigh, which the compiled Lanczos takes when the rotation buffer is full."""
    m = 9
    rng = np.random.default_rng(2)
    alphas, betas = -np.abs(rng.normal(size=(m, 1))) * 5, np.abs(rng.normal(size=(m, 1)))
    fact = tridiagonal.factorials(tridiagonal.TAYLOR_TERMS + order + 1)
    t = np.diag(alphas[:, 0]) + np.diag(betas[: m - 1, 0], 1) + np.diag(betas[: m - 1, 0], -1)
    lam, vec = np.linalg.eigh(t)
    phi = (np.expm1(lam) / lam) if order == 1 else (np.expm1(lam) - lam) / lam**2
    expected = vec @ (phi * vec[0])
    bounds = []
    for capacity in (2 * m * m + 8, 2):
        out, d, e, rows = np.empty(m), np.empty(m), np.empty(m), np.empty((2, m))
        rot_c, rot_s, rot_at = np.empty(capacity), np.empty(capacity), np.empty(capacity, int)
        phis = np.empty(m)
        last, size, count = tridiagonal.phi_of_tridiagonal(
            alphas, betas, m, 0, order, fact, out, d, e, rows, rot_c, rot_s, rot_at, phis
        )
        order_of = np.argsort(d)
        np.testing.assert_allclose(d[order_of], lam, rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(phis[order_of], phi, rtol=1e-12)
        # Z's rows up to the sign of each eigenvector: their products g_j are sign-free
        g = rows[0] * rows[1]
        np.testing.assert_allclose(g[order_of], vec[0] * vec[-1], rtol=1e-9, atol=1e-14)
        bounds.append(tridiagonal.error_bound(d, rows, phis, m, order, fact, 0.0))
        assert (count >= 0) == (capacity > 2)
        if count > 0:
            tridiagonal.apply_z(out, count, rot_c, rot_s, rot_at)
        np.testing.assert_allclose(out, expected, rtol=1e-12, atol=1e-15)
        assert last == pytest.approx(abs(expected[-1]), rel=1e-10)
        assert size == pytest.approx(np.linalg.norm(expected), rel=1e-12)
    assert bounds[0] == pytest.approx(bounds[1], rel=1e-8)


@pytest.mark.parametrize(
    "setting",
    [{"n_agents": 100, "n_paths": 20, "max_control": 1.0}, {"n_agents": 60, "max_control": 1.0}],
)
def test_env_episode_compiled_equals_numpy(setting):
    """One SERB episode of the env with and without the compiled Lanczos: the paths' positions
    (float64; the observation is float32) and the rewards agree to 1e-12.

    With max_control = 1 the swarm stays near consensus. Random actions at max_control = 25
    spread it, and then a trajectory is only reproducible to the Krylov tolerance (1e-10) per
    step, amplified by the steps after it: the numpy path itself, started 1e-15 away, ends
    2e-6 away after 20 such steps (a perturbation moves a Krylov stopping dimension), and so
    does the compiled one; each phi-action agrees to 1e-12 (the tests above)."""
    _needs_numba()

    def episode(enabled):
        before = pf.use_compiled(enabled)
        try:
            env = gym.make("agent_envs/Swarm-v0", n_steps=20, epsilon=0.05, **setting)
            env.reset(seed=3)
            rng = np.random.default_rng(0)
            trace = []
            for _ in range(20):
                action = rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
                _, reward, *_ = env.step(action)
                trace += [env.unwrapped.episode.positions, np.array([reward])]
            return np.concatenate([np.ravel(a).astype(float) for a in trace])
        finally:
            pf.use_compiled(before)

    fast, slow = episode(True), episode(False)
    assert np.max(np.abs(fast - slow)) <= TOL * np.max(np.abs(slow))


def test_serb_step_uses_the_compiled_path(compiled, monkeypatch):
    calls = []
    original = phi_krylov.compiled_frozen_lanczos
    monkeypatch.setattr(
        phi_krylov, "compiled_frozen_lanczos", lambda *a: calls.append(1) or original(*a)
    )
    model = SwarmModel(SwarmParams(n_agents=100, epsilon=0.05), linear_operator="dense")
    x = np.random.default_rng(0).uniform(-1, 1, (2, 100, 1))
    make_integrator("serb").step(model, x, None, 0.0, 0.02, np.zeros_like(x))
    assert calls


def test_switched_off_by_environment_variable():
    """AGENT_ENVS_NUMBA=0 switches off both compiled parts: the Lanczos and the kernel pass."""
    code = (
        "from agent_envs.integrators import phi_functions as pf; "
        "from agent_envs.dynamics import laplacian; "
        "print(pf.load_compiled(), laplacian.load_compiled_kernel())"
    )
    env = {"AGENT_ENVS_NUMBA": "0", "PATH": "/usr/bin:/bin"}
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True
    )
    assert done.stdout.strip() == "False False"


def test_package_works_without_numba():
    """With numba made unimportable, `import agent_envs` works, the compiled path reports
    unavailable, and a SERB env steps (the numpy Lanczos)."""
    code = textwrap.dedent(
        """
        import sys
        sys.modules["numba"] = None  # import numba raises ImportError
        import gymnasium as gym
        import agent_envs
        from agent_envs.integrators import phi_functions as pf
        env = gym.make("agent_envs/Swarm-v0", n_agents=100, n_steps=3, n_paths=2)
        env.reset(seed=0)
        for _ in range(3):
            env.step(env.action_space.sample())
        assert pf.load_compiled() is False
        from agent_envs.dynamics import laplacian
        assert laplacian.load_compiled_kernel() is False
        assert "torch" not in sys.modules
        print("ok")
        """
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "ok"


@pytest.mark.parametrize(("n", "d", "batch", "spread"), CASES)
def test_compiled_product_pass_equals_the_product_taken_first(compiled, n, d, batch, spread):
    """SERB's V + e (c L) W with the product taken inside the compiled pass, against the numpy
    product taken first and then the compiled and the reference Lanczos (1e-12)."""
    _, _, f, op = _frozen(n, d, batch, spread, seed=n + d, scale=0.02)
    w = 0.01 * np.random.default_rng(2).standard_normal(f.shape)
    got, ok = compiled_frozen_lanczos(op, f, 1, 1e-10, 100, None, (w, 50.0))
    rhs = f + 50.0 * (op @ w)
    first, first_ok = compiled_frozen_lanczos(op, rhs, 1, 1e-10, 100, None)
    reference, _ = lanczos_action(RowOperator(op), rhs, 1, 1e-10, 100)
    scale = np.max(np.abs(reference))
    np.testing.assert_array_equal(ok, first_ok)
    assert np.max(np.abs(got - first)) <= TOL * scale
    assert np.max(np.abs(got - reference)) <= TOL * scale


def test_steps_use_the_machine_code_loaded_at_make():
    """numba keeps one machine code per argument type (read-only is part of it) and loads a new
    one at its first call: the env's first step paid 15 ms for that before its inputs were
    made read-only like the warm-up's. After make, steps of the env and of `simulate` (writable
    states) add no type."""
    _needs_numba()
    code = textwrap.dedent(
        """
        import gymnasium as gym
        import agent_envs
        from agent_envs import SwarmParams, simulate
        from agent_envs.native import kernel
        from agent_envs.native import lanczos
        env = gym.make("agent_envs/Swarm-v0", n_agents=100, n_paths=3, integrator="serb")
        counts = lambda: (len(kernel.cucker_smale_drift.signatures),
                          len(lanczos.frozen_lanczos.signatures),
                          len(lanczos.frozen_advance.signatures))
        made = counts()
        env.reset(seed=0)
        for _ in range(3):
            env.step(env.action_space.sample())
        simulate(SwarmParams(n_agents=100), n_steps=3, n_paths=2, integrator="serb", seed=0)
        print(made, counts())
        """
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "(1, 1, 1) (1, 1, 1)"


def _episode(
    fused: bool, num_envs: int | None, steps: int = 60, integrator: str = "serb"
) -> list[np.ndarray]:
    """Observations, rewards and final positions of a run at N = 100, 20 paths, with the fused
    step on or off (a single env resets at its horizon; the vector env autoresets)."""
    from agent_envs.integrators import exponential

    before = exponential.use_fused_step(fused)
    try:
        kwargs = {"n_agents": 100, "n_steps": 25, "n_paths": 20, "integrator": integrator}
        if num_envs is None:
            env = gym.make("agent_envs/Swarm-v0", **kwargs).unwrapped
        else:
            env = gym.make_vec(
                "agent_envs/Swarm-v0", num_envs=num_envs,
                vectorization_mode="vector_entry_point", **kwargs,
            )  # fmt: skip
        env.reset(seed=3)
        action = np.random.default_rng(1).uniform(-0.5, 0.5, env.action_space.shape)
        action = action.astype(np.float32)
        seen = []
        for _ in range(steps):
            obs, reward, terminated, truncated, _ = env.step(action)
            seen += [np.array(obs), np.array(reward)]
            if num_envs is None and (terminated or truncated):
                env.reset()
        return [*seen, np.array(env.unwrapped.positions)]
    finally:
        exponential.use_fused_step(before)


@pytest.mark.parametrize(("num_envs", "integrator"), [(None, "serb"), (3, "serb"), (None, "erb")])
def test_fused_step_equals_the_general_path_bit_for_bit(
    compiled, monkeypatch, num_envs, integrator
):
    """The fused step (phi-action, update and next kernel pass per member in one compiled
    call) gives the envs the same observations, rewards and states as the phi-action and the
    kernel pass taken apart, across episode ends (SERB with its sigma L dW product, ERB
    without); and the envs take it."""
    from agent_envs.integrators import exponential

    calls = []
    original = exponential.frozen_advance
    monkeypatch.setattr(exponential, "frozen_advance", lambda *a: calls.append(1) or original(*a))
    fused = _episode(True, num_envs, integrator=integrator)
    assert len(calls) == 60
    general = _episode(False, num_envs, integrator=integrator)
    assert len(calls) == 60
    for got, expected in zip(fused, general, strict=True):
        np.testing.assert_array_equal(got, expected)


def test_fused_step_that_gives_up_takes_the_general_path(compiled, monkeypatch):
    """A member whose Lanczos did not converge leaves the workspace's P partly overwritten:
    the step discards it, evaluates L(x) again and takes the general path, with the general
    path's result (simulated: the compiled call reports one member unconverged)."""
    calls = []
    original = native.loaded("lanczos").frozen_advance

    def unconverged(*args):
        assert original(*args) == 0
        calls.append(1)
        return 1  # the number of members that did not converge

    monkeypatch.setattr(native.loaded("lanczos"), "frozen_advance", unconverged)
    gave_up = _episode(True, None, steps=8)
    assert len(calls) == 8
    monkeypatch.setattr(native.loaded("lanczos"), "frozen_advance", original)
    general = _episode(False, None, steps=8)
    for got, expected in zip(gave_up, general, strict=True):
        np.testing.assert_array_equal(got, expected)


def test_fused_step_leaves_the_linearization_of_its_result(compiled):
    """After a fused step the model holds L(x_next) and its drift, equal bit for bit to a
    fresh model's evaluation at x_next, and the operator of x^n is no longer current."""
    from agent_envs.dynamics.linearization_cache import LinearizationCache

    params = SwarmParams(n_agents=100, epsilon=0.05)
    model = LinearizationCache(params)
    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, (4, 100, 1))
    x.flags.writeable = False
    _, lin = model.drift_and_linearization(0.0, x, None, "frozen")
    x_next = make_integrator("serb").step(model, x, 0.1, 0.0, 0.02, rng.normal(size=x.shape))
    assert not x_next.flags.writeable and not lin.matrix.current
    drift, next_lin = model.drift_and_linearization(0.0, x_next, None, "frozen")
    fresh_drift, fresh_lin = SwarmModel(params).drift_and_linearization(0.0, x_next, None, "frozen")
    np.testing.assert_array_equal(drift, fresh_drift)
    np.testing.assert_array_equal(next_lin.matrix.dense(), fresh_lin.matrix.dense())


def test_compiled_reads_the_callers_interval_like_numpy(compiled):
    """Bounds from the caller: without the interval's bottom (a 2-tuple, or None there) both
    iterations fall back to Saad's estimate, with it both take the error bound; either way they
    stop at the same dimensions (equal to round-off, where a different dimension differs by
    about the Krylov tolerance)."""
    _, _, f, op = _frozen(100, 1, (4,), 0.01, seed=7, scale=0.02)
    norms, widths, low = op.krylov_bounds()
    rows = RowOperator(op)
    results = []
    for bounds in ((norms, widths), (norms, widths, None), (norms, widths, low)):
        got, got_ok = compiled_frozen_lanczos(op, f, 1, 1e-10, 100, bounds)
        want, want_ok = lanczos_numpy(rows, f, 1, 1e-10, 100, bounds=bounds)
        np.testing.assert_array_equal(got_ok, want_ok)
        assert np.max(np.abs(got - want)) <= 1e-14 * np.max(np.abs(want))
        results.append(got)
    # the bound stops earlier than Saad's estimate near consensus: other values
    assert np.max(np.abs(results[2] - results[0])) > 1e-14 * np.max(np.abs(results[0]))


def test_check_schedule_is_the_same_rule_compiled_and_numpy(compiled):
    """The schedule compiled (`lanczos_rule.next_check` under numba) and numpy
    (`next_checks`, vectorized over members): the same next dimension over a grid of (m, ratio,
    previous check), on both sides of the full-step threshold FULL_STEP_FROM n; the compiled
    rules are the plain-Python ones of `lanczos_rule`, the one source of the rule."""
    assert compiled._next_check.py_func is lanczos_rule.next_check
    assert compiled._spectrum_top.py_func is lanczos_rule.spectrum_top
    assert compiled._first_check.py_func is lanczos_rule.first_check
    for n in (20, 100, 400):
        for m in (3, 4, 5, 6, 9, 13, 19, 25):
            for prev_m in (0, 1, m - 1, max(m - 8, 1)):
                for prev_ratio in (0.0, 2.0, 1e3, 1e9, np.inf):
                    ratio = np.array([1.5, 10.0, 1e3, 1e8, 1e30, np.inf])
                    want = next_checks(
                        m, ratio, np.full(6, float(prev_m)), np.full(6, prev_ratio), 8, n
                    )
                    got = [compiled._next_check(m, r, prev_m, prev_ratio, 8, n) for r in ratio]
                    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("n", [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 13, 100])
def test_product_reads_the_lower_triangle_and_equals_the_dense_product(compiled, n):
    """`lower_product` (four rows per block, the n % 4 rows after them one by one) against P q for
    a symmetric P, to round-off; NaN above the diagonal blocks does not reach the result (only
    the lower triangle and the 4 x 4 blocks on the diagonal are read); and a second call with
    the same inputs, from other buffers, gives the same bits."""
    from agent_envs.native import kernel

    rng = np.random.default_rng(n)
    half = rng.uniform(0.1, 2.0, (n, n))
    p = np.tril(half) + np.tril(half, -1).T
    q = rng.standard_normal(n)
    want = p @ q
    w = np.full(n, np.nan)
    kernel.lower_product(p, q, w, n)
    assert np.all(np.abs(w - want) <= 1e-14 * np.maximum(np.abs(p) @ np.abs(q), 1e-300))
    upper = p.copy()
    top = n - n % 4
    for i in range(n):
        block_end = (i // 4 + 1) * 4 if i < top else i + 1
        upper[i, block_end:] = np.nan
    again = np.full(n, np.nan)
    kernel.lower_product(upper.copy(), q.copy(), again, n)
    np.testing.assert_array_equal(again, w)


@pytest.mark.parametrize("n", [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 13, 100])
@pytest.mark.parametrize("k", [1, 2, 3, 4])
def test_products_of_several_vectors_read_the_lower_triangle(compiled, n, k):
    """`_products` (the Lanczos's products of k vectors: pairs in one pass over P by
    `lower_product_pair`, an odd last one alone) against P q for each vector, to round-off;
    NaN outside the triangle and the diagonal blocks does not reach the result; the same
    inputs from other buffers give the same bits; and each column of a pair is the same
    whatever the other column holds (a member's result depends only on its own data)."""
    from agent_envs.native import kernel

    rng = np.random.default_rng(100 * n + k)
    half = rng.uniform(0.1, 2.0, (n, n))
    p = np.tril(half) + np.tril(half, -1).T
    q = rng.standard_normal((k, n))
    w = np.full((k, n), np.nan)
    compiled._products(p, q, w, k, n)
    for c in range(k):
        tol = 1e-14 * np.maximum(np.abs(p) @ np.abs(q[c]), 1e-300)
        assert np.all(np.abs(w[c] - p @ q[c]) <= tol)
    upper = p.copy()
    top = n - n % 4
    for i in range(n):
        block_end = (i // 4 + 1) * 4 if i < top else i + 1
        upper[i, block_end:] = np.nan
    again = np.full((k, n), np.nan)
    compiled._products(upper.copy(), q.copy(), again, k, n)
    np.testing.assert_array_equal(again, w)
    if k >= 2:
        other = q.copy()
        other[1] = rng.standard_normal(n)
        v = np.full((k, n), np.nan)
        kernel.lower_product_pair(p, other[0], other[1], v[0], v[1], n)
        np.testing.assert_array_equal(v[0], w[0])
        tol = 1e-14 * np.maximum(np.abs(p) @ np.abs(other[1]), 1e-300)
        assert np.all(np.abs(v[1] - p @ other[1]) <= tol)
        # the second column whatever the first holds: other[1] beside q[0] instead of other[0]
        first, second = np.full(n, np.nan), np.full(n, np.nan)
        kernel.lower_product_pair(p, q[0], other[1], first, second, n)
        np.testing.assert_array_equal(second, v[1])
        np.testing.assert_array_equal(first, w[0])


@pytest.mark.parametrize("n", [0, 1, 3, 4, 5, 17, 100])
def test_recurrence_passes_equal_their_formulas(compiled, n):
    """The recurrence's passes (`_dot`, `_axpy_dot`, `_scale_dot`: an element-wise update, then
    a dot whose sum the compiler may reassociate) against numpy: the updated vector bit for bit
    (the same IEEE operations element by element), the dots to round-off of the sum of |terms|;
    n below, at and off the vector width."""
    rng = np.random.default_rng(n)
    a, b, s = rng.standard_normal(n), rng.standard_normal(n), rng.uniform(0.5, 2.0, n)
    scale = lambda terms: 1e-14 * max(float(np.abs(terms).sum()), 1e-300)  # noqa: E731
    assert abs(compiled._dot(a, b, n) - float(a @ b)) <= scale(a * b)
    w = a.copy()
    got = compiled._axpy_dot(w, -0.37, b, s, n)
    want_w = a + (-0.37) * b
    np.testing.assert_array_equal(w, want_w)
    assert abs(got - float(want_w @ s)) <= scale(want_w * s)
    w = a.copy()
    norm2 = compiled._axpy_dot(w, 0.5, b, w, n)  # y = w itself: |w|^2 of the updated w
    assert abs(norm2 - float(w @ w)) <= scale(w * w)
    w = a.copy()
    got = compiled._scale_dot(w, s, b, 0.25, n)
    want_w = (a - s * b) * 0.25
    np.testing.assert_array_equal(w, want_w)
    assert abs(got - float(want_w @ b)) <= scale(want_w * b)


def test_member_bounds_equal_their_formulas(compiled):
    """`_member_bounds`, one pass: ||c L||_inf <= |c| (2 / n) max_i |s_i - P_ii| and the width
    |c| 2 max(peak - min_i s_i / n, 0) of the interval holding spec(c L) on 1^perp (inf
    without a peak), against those formulas in numpy, bit for bit."""
    rng = np.random.default_rng(3)
    n = 37
    p = rng.uniform(0.1, 2.0, (n, n))
    s = p.sum(axis=1)
    c, peak = 0.03, 2.5
    norm, width = compiled._member_bounds(p, s, n, c, peak)
    assert norm == c * ((2.0 / n) * float(np.max(np.abs(s - np.diag(p)))))
    assert width == c * (2.0 * max(float(np.max(peak - s / n)), 0.0))
    assert compiled._member_bounds(p, s, n, c, -1.0) == (norm, np.inf)
    assert compiled._member_bounds(p, s, n, c, 0.0)[1] == 0.0  # peak below every s_i / n
