"""Contracts of the phi-function modules that their value tests do not pin (each found by a
mutant that survived the mutation run, docs/mutation.md): the "auto" strategy's documented
decisions, the fused step's conditions, the large-n basis accumulation of the Lanczos
iteration, its breakdown threshold's scale, the spectrum interval's bottom at 0 and the
fallback warning pointing at the caller."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from agent_envs import SwarmModel, SwarmParams
from agent_envs.integrators import phi_functions as pf
from agent_envs.integrators import phi_lanczos
from agent_envs.integrators.krylov_space import RowOperator
from agent_envs.integrators.lanczos_stopping import spectrum_interval
from agent_envs.integrators.phi_functions import (
    auto_phi_method,
    frozen_advance_applies,
    phi_action,
    phi_scalar,
)
from agent_envs.integrators.phi_lanczos import lanczos_action, lanczos_numpy


def _symmetric(n: int, seed: int, scale: float = 1.0) -> np.ndarray:
    """A random symmetric (n, n) matrix with a spectrum of width about 2 `scale`."""
    b = np.random.default_rng(seed).standard_normal((n, n))
    return scale * (b + b.T) / (2 * np.sqrt(n))


# ------------------------------------------------------------------ "auto"'s decisions
@pytest.mark.parametrize(
    ("size", "n_matrices", "symmetric", "expected"),
    [
        # n <= 48: "expm" whatever the batch and symmetry
        (48, 1, True, "expm"),
        (48, 20, True, "expm"),
        (48, 20, False, "expm"),
        # symmetric: "expm" for a single matrix up to n = 80, else "krylov"
        (60, 1, True, "expm"),
        (80, 1, True, "expm"),
        (81, 1, True, "krylov"),
        (49, 2, True, "krylov"),
        (60, 20, True, "krylov"),
        # not symmetric: "expm" up to n = 80, and for a single matrix up to n = 128
        (80, 20, False, "expm"),
        (81, 2, False, "krylov"),
        (100, 1, False, "expm"),
        (128, 1, False, "expm"),
        (129, 1, False, "krylov"),
    ],
)
def test_auto_picks_the_documented_strategy(size, n_matrices, symmetric, expected):
    """The crossovers of phi_functions' docstring (benchmarks/bench_integrators.py, table 1)."""
    assert auto_phi_method(size, n_matrices, symmetric) == expected


def test_auto_counts_the_matrices_of_the_broadcast_batch():
    """Three matrices acting on one block of vectors are three problems: "auto" computes
    what "krylov" computes (three symmetric matrices of n = 60), bit for bit, not the single
    matrix's "expm" (whose value differs in the last digits)."""
    a = np.stack([_symmetric(60, seed) for seed in range(3)]) - 2.0 * np.eye(60)
    v = np.random.default_rng(3).standard_normal((60, 2))
    auto = phi_action(a, v, 1, symmetric=True)
    np.testing.assert_array_equal(auto, phi_action(a, v, 1, method="krylov", symmetric=True))
    assert not np.array_equal(auto, phi_action(a, v, 1, method="expm", symmetric=True))


def test_fallback_warning_points_at_the_caller():
    """The RuntimeWarning of a Krylov space that did not converge names the line that called
    `phi_action` (stacklevel), not a line inside the package."""
    a = np.random.default_rng(0).standard_normal((60, 60))
    v = np.random.default_rng(1).standard_normal((60, 1))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got = phi_action(a, v, 1, method="krylov", max_krylov_dim=2)
    (warning,) = [w for w in caught if issubclass(w.category, RuntimeWarning)]
    assert "did not reach" in str(warning.message)
    assert warning.filename == __file__
    np.testing.assert_allclose(got, phi_action(a, v, 1, method="expm"), rtol=1e-12, atol=0)


# ------------------------------------------------------------------ the fused step's conditions
@pytest.fixture()
def compiled():
    """The compiled Lanczos on for the test (and restored after)."""
    pytest.importorskip("numba")
    assert pf.load_compiled(), "numba is installed but the compiled Lanczos did not load"
    before = pf.use_compiled(True)
    yield
    pf.use_compiled(before)


def _frozen_step(n=100, paths=2, kernel="symmetric"):
    """(model, A = tau c L(x), rhs, x, noise) of one exponential Rosenbrock-Euler step, over
    `paths` paths (None: unbatched)."""
    model = SwarmModel(SwarmParams(n_agents=n, dim=1, epsilon=0.05, kernel=kernel), "dense")
    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, (n, 1) if paths is None else (paths, n, 1))
    rhs, lin = model.drift_and_linearization(0.0, x, None, "frozen")
    return model, 0.02 * lin.matrix, rhs, x, rng.standard_normal(x.shape)


class _Subclass(np.ndarray):
    """An ndarray subclass: not the plain float64 array the compiled step reads."""


def test_fused_step_applies_to_the_frozen_laplacian(compiled):
    """A current symmetric frozen L(x), float64 arrays batched like P, "krylov", or "auto"
    where it chooses "krylov" (n = 100 > 80; n = 60 batched)."""
    _, a, rhs, x, noise = _frozen_step()
    assert frozen_advance_applies(a, rhs, x, noise, "krylov")
    assert frozen_advance_applies(a, rhs, x, noise, "auto")
    _, a, rhs, x, noise = _frozen_step(n=60, paths=2)
    assert frozen_advance_applies(a, rhs, x, noise, "auto")


def test_fused_step_follows_auto_where_it_picks_the_dense_method(compiled):
    """n = 60, one path: "auto" picks "expm" (a single symmetric matrix up to n = 80), so the
    fused Krylov step does not apply, while an explicit "krylov" does."""
    _, a, rhs, x, noise = _frozen_step(n=60, paths=1)
    assert auto_phi_method(60, 1, True) == "expm"
    assert not frozen_advance_applies(a, rhs, x, noise, "auto")
    assert frozen_advance_applies(a, rhs, x, noise, "krylov")
    _, a, rhs, x, noise = _frozen_step(n=40, paths=4)
    assert not frozen_advance_applies(a, rhs, x, noise, "auto")


@pytest.mark.parametrize(
    "refusal",
    [
        "x subclass", "rhs subclass", "noise subclass", "x float32", "rhs float32",
        "noise float32", "rhs shape", "noise shape", "batch", "method expm", "method eigh",
        "dense matrix", "nonsymmetric", "no peak", "not current", "not compiled",
    ],
)  # fmt: skip
def test_fused_step_refuses_each_condition(compiled, refusal):
    """Each of `frozen_advance_applies`' conditions alone refuses the fused step."""
    model, a, rhs, x, noise = _frozen_step()
    method = "krylov"
    if refusal.endswith("subclass"):
        name = refusal.split()[0]
        arrays = {"x": x, "rhs": rhs, "noise": noise}
        arrays[name] = arrays[name].view(_Subclass)
        x, rhs, noise = arrays["x"], arrays["rhs"], arrays["noise"]
    elif refusal.endswith("float32"):
        name = refusal.split()[0]
        arrays = {"x": x, "rhs": rhs, "noise": noise}
        arrays[name] = arrays[name].astype(np.float32)
        x, rhs, noise = arrays["x"], arrays["rhs"], arrays["noise"]
    elif refusal == "rhs shape":
        rhs = rhs[..., :-1, :]
    elif refusal == "noise shape":
        noise = np.concatenate([noise, noise], axis=-1)
    elif refusal == "batch":
        x, rhs, noise = x[:1], rhs[:1], noise[:1]
    elif refusal.startswith("method"):
        method = refusal.split()[1]
    elif refusal == "dense matrix":
        a = a.dense()
    elif refusal == "nonsymmetric":
        _, a, rhs, x, noise = _frozen_step(kernel="nonsymmetric")
    elif refusal == "no peak":
        a = a.scaled(1.0)
        a.peak = None
    elif refusal == "not current":
        model.drift_and_linearization(0.0, x + 0.1, None, "frozen")  # overwrites P
        assert not a.current
    elif refusal == "not compiled":
        pf.use_compiled(False)
    assert not frozen_advance_applies(a, rhs, x, noise, method)


@pytest.mark.parametrize("paths", [(), (1,), (3,)])
def test_compiled_lanczos_takes_any_float_block_like_a_fresh_float64_one(compiled, paths):
    """The compiled phi-action of the frozen L(x) on a read-only block (a single env's state
    is passed as it is), on an unbatched one and with a float32 W in `add_product` gives what
    it gives on a fresh writable float64 copy, bit for bit."""
    _, a, rhs, _, noise = _frozen_step(paths=paths[0] if paths else None)
    kw = {"method": "krylov", "symmetric": True}
    want = phi_action(a, rhs.copy(), 1, **kw)
    read_only = rhs.copy()
    read_only.flags.writeable = False
    np.testing.assert_array_equal(phi_action(a, read_only, 1, **kw), want)
    w32 = noise.astype(np.float32)
    np.testing.assert_array_equal(
        phi_action(a, rhs, 1, add_product=(w32, 50.0), **kw),
        phi_action(a, rhs, 1, add_product=(w32.astype(np.float64), 50.0), **kw),
    )


def test_compiled_lanczos_broadcasts_a_block_over_the_members(compiled):
    """One block V (n, k) for a batch of three frozen L(x): each member acts on V, bit for bit
    as on V repeated per member, and so does W of `add_product`."""
    _, a, rhs, _, noise = _frozen_step(paths=3)
    kw = {"method": "krylov", "symmetric": True}
    v, w = rhs[1], noise[2]
    full = np.broadcast_to(v, rhs.shape).copy()
    np.testing.assert_array_equal(phi_action(a, v, 1, **kw), phi_action(a, full, 1, **kw))
    np.testing.assert_array_equal(
        phi_action(a, rhs, 1, add_product=(w, 50.0), **kw),
        phi_action(a, rhs, 1, add_product=(np.broadcast_to(w, rhs.shape).copy(), 50.0), **kw),
    )


def test_a_block_batched_beyond_the_operator_takes_the_general_lanczos(compiled):
    """V (2, B, n, k) on B frozen L(x): the compiled Lanczos, member by member over P's batch,
    declines, and the general Lanczos broadcasts: each slice as on its own (to round-off)."""
    _, a, rhs, _, _ = _frozen_step(paths=3)
    kw = {"method": "krylov", "symmetric": True}
    got = phi_action(a, np.stack([rhs, -2.0 * rhs]), 1, **kw)
    for i, v in enumerate([rhs, -2.0 * rhs]):
        want = phi_action(a, v, 1, **kw)
        np.testing.assert_allclose(got[i], want, rtol=1e-9, atol=1e-12 * np.max(np.abs(want)))


@pytest.mark.parametrize("layout", ["fortran", "strided"])
def test_compiled_lanczos_on_a_non_contiguous_block(compiled, layout):
    """A block that is not C-contiguous (Fortran order, a strided view) gives what its
    C-contiguous copy gives, bit for bit."""
    _, a, rhs, _, noise = _frozen_step(paths=2)
    block = np.concatenate([rhs, noise], axis=-1)  # (2, n, 2)
    if layout == "fortran":
        v = np.asfortranarray(block)
    else:
        v = np.repeat(block, 2, axis=-1)[..., ::2]
    assert not v.flags.c_contiguous
    kw = {"method": "krylov", "symmetric": True}
    np.testing.assert_array_equal(
        phi_action(a, v, 1, **kw), phi_action(a, np.ascontiguousarray(v), 1, **kw)
    )


def test_compiled_lanczos_without_the_kernels_peak(compiled):
    """A symmetric frozen L(x) whose kernel has no peak (`peak` None: no interval for the error
    bound) still takes the compiled Lanczos, stopped by Saad's estimate: phi_p(A) V to the
    tolerance."""
    _, a, rhs, _, _ = _frozen_step(paths=2)
    a = a.scaled(1.0)
    a.peak = None
    got = phi_action(a, rhs, 1, method="krylov", symmetric=True)
    want = phi_action(a.dense(), rhs, 1, method="eigh", symmetric=True)
    assert np.max(np.abs(got - want)) <= 1e-8 * np.max(np.abs(want))


def test_fused_advance_runs_on_the_calling_thread_by_default(compiled, monkeypatch):
    """`frozen_advance` without `threads` is one pass on the calling thread (the threaded
    driver needs `load_compiled_threads` first), and its x_next is the step's formula
    x + dt phi_1(dt A) rhs + noise."""
    from agent_envs import native
    from agent_envs.dynamics.linearization_cache import LinearizationCache

    model = LinearizationCache(SwarmParams(n_agents=100, epsilon=0.05))
    x = np.random.default_rng(0).uniform(-1, 1, (3, 100, 1))
    x.flags.writeable = False
    rhs, lin = model.drift_and_linearization(0.0, x, None, "frozen")
    noise = 0.01 * np.random.default_rng(1).standard_normal(x.shape)
    want = x + 0.02 * phi_action(0.02 * lin.matrix, rhs, 1, method="krylov", symmetric=True)
    want = want + noise

    def threaded(*args):
        raise AssertionError("the threaded driver ran without threads > 1")

    monkeypatch.setattr(native.loaded("lanczos"), "frozen_advance_threads", threaded)
    found = pf.frozen_advance(
        lin.matrix, rhs, x, 0.02, noise, None, *model.fused_relinearization(x)
    )
    assert found is not None
    np.testing.assert_allclose(found[0], want, rtol=1e-12, atol=1e-14)


# ------------------------------------------------------------------ the Lanczos iteration
class _Diagonal:
    """A matrix-free operator diag(d): the exact phi_p(A) v is phi_p(d) v."""

    def __init__(self, d: np.ndarray) -> None:
        self.d = d
        self.shape = (d.size, d.size)
        self.norm_inf = float(np.max(np.abs(d)))

    def matvec(self, v: np.ndarray) -> np.ndarray:
        return self.d[:, None] * v

    def scaled(self, c: float) -> _Diagonal:
        return _Diagonal(c * self.d)


def _count_stacked(monkeypatch) -> list[int]:
    """Records each stacked-basis assembly (`gather_members`) of the Lanczos iteration."""
    calls: list[int] = []
    original = phi_lanczos.gather_members

    def spy(*args):
        calls.append(1)
        return original(*args)

    monkeypatch.setattr(phi_lanczos, "gather_members", spy)
    return calls


@pytest.mark.parametrize(("n", "stacked"), [(2**14 - 1, 1), (2**14, 0)])
def test_lanczos_sums_its_basis_from_n_2_pow_14(monkeypatch, n, stacked):
    """From n = 2^14 on (`ACCUMULATE_BASIS_MIN_N`) the iteration sums its basis vector by
    vector (no stacked (k, m, n) copy); below, it stacks it. Both are phi_p(A) v."""
    calls = _count_stacked(monkeypatch)
    d = -np.linspace(0.0, 2.0, n)
    v = np.random.default_rng(0).standard_normal((n, 2))
    got = phi_action(_Diagonal(d), v, 1, symmetric=True)
    assert len(calls) == stacked
    np.testing.assert_allclose(got, phi_scalar(d, 1)[:, None] * v, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("lanczos", [lanczos_numpy, lanczos_action])
@pytest.mark.parametrize("batch", [(), (3,)])
def test_summed_basis_equals_the_stacked_product(monkeypatch, lanczos, batch):
    """The vector-by-vector sum of the basis (taken for a small n with the threshold lowered)
    equals the stacked product to round-off, for one member and a batch, two columns."""
    a = _symmetric(40, seed=1, scale=3.0)
    rng = np.random.default_rng(2)
    v = np.broadcast_to(rng.standard_normal((40, 2)), (*batch, 40, 2))  # one stopping m
    stacked, stacked_ok = lanczos(RowOperator(a), v, 1, 1e-10, 40)
    calls = _count_stacked(monkeypatch)
    monkeypatch.setattr(phi_lanczos, "ACCUMULATE_BASIS_MIN_N", 1)
    summed, summed_ok = lanczos(RowOperator(a), v, 1, 1e-10, 40)
    assert not calls  # the summed path was taken
    assert summed.shape == stacked.shape == (*batch, 40, 2)
    np.testing.assert_array_equal(summed_ok, stacked_ok)
    np.testing.assert_allclose(summed, stacked, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("scale", [1e-9, 1.0, 1e6])
def test_breakdown_threshold_scales_with_the_norm(scale):
    """The happy-breakdown tolerance is relative to ||A||_inf: a matrix of tiny norm is not
    taken for a breakdown at m = 1 (its Lanczos value is phi_p(A) v to round-off, not
    phi_p(a_1) v), at every scale of A."""
    a = _symmetric(60, seed=4, scale=scale) - 3.0 * scale * np.eye(60)
    v = np.random.default_rng(5).standard_normal((60, 1))
    got = phi_action(a, v, 1, method="krylov", symmetric=True, rtol=1e-13)
    want = phi_action(a, v, 1, method="eigh", symmetric=True)
    assert np.max(np.abs(got - want)) <= 1e-11 * np.max(np.abs(want))


def test_a_column_that_breaks_down_stays_zero_while_its_member_continues():
    """Column 0 lies in an invariant subspace of dimension 2 (b_2 ~ round-off: its breakdown),
    column 1 does not, so the member goes on; the broken-down column's next basis vectors are
    0 in both executors, which agree bit for bit."""
    rng = np.random.default_rng(6)
    q, _ = np.linalg.qr(rng.standard_normal((50, 50)))
    a = (q * np.linspace(-4.0, 0.0, 50)) @ q.T
    a = (a + a.T) / 2
    v = np.stack([q[:, 3] + q[:, 40], rng.standard_normal(50)], axis=-1)
    got, got_ok = lanczos_numpy(RowOperator(a), v, 1, 1e-10, 50)
    want, want_ok = lanczos_action(RowOperator(a), v, 1, 1e-10, 50)
    assert got_ok and want_ok
    np.testing.assert_array_equal(got, want)
    np.testing.assert_allclose(got, phi_action(a, v, 1, method="eigh", symmetric=True),
                               rtol=1e-8, atol=1e-12)  # fmt: skip


def test_an_operator_whose_space_does_not_converge_takes_substeps():
    """A matrix-free operator (without `dense()`) whose Krylov space does not converge within
    `max_krylov_dim` gets its action in substeps: phi_p(A) v to the tolerance, not the
    unconverged Krylov value; one that converges gets the Krylov value itself."""
    d = -np.linspace(0.0, 8.0, 300)
    v = np.random.default_rng(7).standard_normal((300, 2))
    want = phi_scalar(d, 1)[:, None] * v
    substepped = phi_action(_Diagonal(d), v, 1, symmetric=True, max_krylov_dim=12)
    np.testing.assert_allclose(substepped, want, rtol=1e-8, atol=1e-10)
    direct, ok = lanczos_numpy(RowOperator(_Diagonal(d)), v, 1, 1e-10, 100)
    assert ok
    np.testing.assert_array_equal(phi_action(_Diagonal(d), v, 1, symmetric=True), direct)


def test_row_operator_bounds_a_matrix_by_its_row_sums():
    """Without bounds given, a matrix's ||A||_inf is its largest absolute row sum (not the
    column sum: a matrix that is not symmetric tells them apart), per batch member, with an
    unknown width (inf) and bottom (nan)."""
    a = np.random.default_rng(11).uniform(0.0, 1.0, (2, 5, 5))
    a[0, 0, :] = 10.0  # row 0 of member 0 sums to 50, no column to more than 10.8
    norm, width, low = RowOperator(a).member_bounds((2,))
    np.testing.assert_array_equal(norm, np.max(np.sum(np.abs(a), axis=-1), axis=-1))
    assert norm[0] == 50.0
    np.testing.assert_array_equal(width, [np.inf, np.inf])
    assert np.all(np.isnan(low))


def test_substeps_double_when_the_order_2_tail_does_not_converge(monkeypatch):
    """phi_2 in substeps: where the tail phi_2(hA) v does not converge (here: made to fail
    once, at s = 4 substeps), the number of substeps doubles rather than stepping without it:
    the result is still phi_2(A) v."""
    from agent_envs.integrators import phi_matrix_free

    original = phi_matrix_free.krylov_or_none
    tails = []

    def tail_fails_once(op, v, order, *args):
        # fails the tail once at s = 4 (||hA|| = 2), where the phi_1 substeps converge
        if order == 2 and op.norm_inf <= 2.0:
            tails.append(1)
            if len(tails) == 1:
                return None
        return original(op, v, order, *args)

    monkeypatch.setattr(phi_matrix_free, "krylov_or_none", tail_fails_once)
    d = -np.linspace(0.0, 8.0, 300)
    v = np.random.default_rng(14).standard_normal((300, 1))
    got = phi_action(_Diagonal(d), v, 2, symmetric=True, max_krylov_dim=12)
    assert len(tails) >= 2
    np.testing.assert_allclose(got, phi_scalar(d, 2)[:, None] * v, rtol=1e-8, atol=1e-10)


def test_substeps_refuse_order_3():
    """An operator's substeps are implemented for p = 1, 2 only: p = 3 where the Krylov space
    does not converge is refused as not implemented (not taken for a non-convergence)."""
    d = -np.linspace(0.0, 8.0, 300)
    v = np.random.default_rng(15).standard_normal((300, 1))
    with pytest.raises(ValueError, match="order 3 > 2 is not implemented"):
        phi_action(_Diagonal(d), v, 3, symmetric=True, max_krylov_dim=12)


# ------------------------------------------------------------------ the Arnoldi iteration
def _invariant_pair(n: int = 40, seed: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """A non-symmetric A with span{e_0, e_1} invariant, and V whose column 0 lies there (its
    Arnoldi breaks down at m = 2) and column 1 does not."""
    rng = np.random.default_rng(seed)
    a = np.diag(np.linspace(-3.0, 0.0, n))
    a[2:, 2:] += np.triu(rng.uniform(0.0, 0.3, (n - 2, n - 2)), 1)
    a[0, 1], a[1, 0] = 0.7, -0.2
    v = np.zeros((n, 2))
    v[:2, 0] = 1.0, 0.5
    v[:, 1] = rng.standard_normal(n)
    return a, v


def test_arnoldi_column_that_breaks_down_equals_it_alone():
    """Column 0 breaks down at m = 2 while column 1 goes on: its next basis vectors are 0, so
    its value is the one it gets alone, bit for bit, and both are phi_p(A) v."""
    a, v = _invariant_pair()
    both = phi_action(a, v, 1, method="krylov")
    np.testing.assert_array_equal(both[:, 0], phi_action(a, v[:, :1], 1, method="krylov")[:, 0])
    np.testing.assert_allclose(both, phi_action(a, v, 1, method="expm"), rtol=1e-10, atol=1e-13)


def test_arnoldi_zero_column_gives_zero():
    """A zero column (|v| = 0) gives phi_p(A) 0 = 0, and the other column its own value."""
    a, v = _invariant_pair()
    v[:, 0] = 0.0
    got = phi_action(a, v, 2, method="krylov")
    np.testing.assert_array_equal(got[:, 0], 0.0)
    np.testing.assert_allclose(got, phi_action(a, v, 2, method="expm"), rtol=1e-10, atol=1e-13)


class _Counting:
    """A matrix as a matrix-free operator that counts its products."""

    def __init__(self, a: np.ndarray) -> None:
        self.a, self.shape, self.products = a, a.shape, 0
        self.norm_inf = float(np.max(np.sum(np.abs(a), axis=-1)))

    def matvec(self, v: np.ndarray) -> np.ndarray:
        self.products += 1
        return self.a @ v

    def scaled(self, c: float) -> _Counting:
        return _Counting(c * self.a)


def test_arnoldi_checks_every_fourth_dimension():
    """Arnoldi compares its coefficients every 4 dimensions (the default `check_every`): it
    stops at a multiple of 4, here after 20 products (5 checks) of a 300 x 300 A."""
    a = np.diag(-np.linspace(0.0, 4.0, 300)) + np.diag(np.full(299, 0.4), 1)
    op = _Counting(a)
    v = np.random.default_rng(13).standard_normal((300, 1))
    got = phi_action(op, v, 1)
    assert op.products == 20
    np.testing.assert_allclose(got, phi_action(a, v, 1, method="expm"), rtol=1e-9, atol=1e-12)


# ------------------------------------------------------------------ the dense methods
@pytest.mark.parametrize("order", [1, 2, 3])
@pytest.mark.parametrize("k", [1, 2, 3])
def test_augmented_expm_on_torch_equals_numpy(order, k):
    """Sidje's augmented matrix built for torch (its identity blocks placed by concatenation)
    gives numpy's value, for every order and block width."""
    torch = pytest.importorskip("torch")
    a = _symmetric(12, seed=8) + 0.3 * np.random.default_rng(9).standard_normal((12, 12))
    v = np.random.default_rng(10).standard_normal((2, 12, k))
    want = phi_action(a, v, order, method="expm")
    got = phi_action(torch.tensor(a), torch.tensor(v), order, method="expm")
    np.testing.assert_allclose(got.numpy(), want, rtol=1e-12, atol=1e-14)


# ------------------------------------------------------------------ the spectrum's interval
def test_spectrum_interval_at_a_bottom_of_zero():
    """low = 0 (the zero operator: c p_max = 0) is an interval [0, 0] with the bound (tight);
    a positive bottom is not (the frozen c L is negative semidefinite), nor an unknown width."""
    norm, width = np.array([2.0, 2.0, 2.0]), np.array([0.0, 0.0, np.inf])
    lo, hi, tight = spectrum_interval(norm, width, np.array([0.0, 1e-3, 0.0]))
    np.testing.assert_array_equal(tight, [True, False, False])
    np.testing.assert_array_equal(lo, [0.0, -2.0, -2.0])
    np.testing.assert_array_equal(hi, [0.0, 2.0, 2.0])


def test_phi_1s_torch_gradient_near_zero_is_its_series():
    """d phi_1 / dz = 1/2 + z/3 + ... : at z = 0 (the constant branch) and at tiny z (where
    autograd of expm1(z) / z cancels) the gradient is the series', the values unchanged."""
    torch = pytest.importorskip("torch")
    from agent_envs.integrators.phi_dense import phi_scalar

    z = torch.tensor([0.0, -0.0, 1e-30, -1e-12, 5e-8, 1e-3, -0.5], dtype=torch.float64)
    z.requires_grad_(True)
    value = phi_scalar(z, 1)
    value.sum().backward()
    plain = phi_scalar(z.detach(), 1)
    assert torch.equal(value.detach(), plain)  # the same bits as without autograd
    want = 0.5 + z.detach() / 3.0
    assert torch.allclose(z.grad[:5], want[:5], rtol=1e-12, atol=0.0)
    exact = (z.detach() * torch.exp(z.detach()) - torch.expm1(z.detach())) / z.detach() ** 2
    assert torch.allclose(z.grad[5:], exact[5:], rtol=1e-9, atol=0.0)


def test_a_numpy_matrix_with_a_torch_vector_is_a_named_type_error():
    torch = pytest.importorskip("torch")
    from agent_envs.integrators.phi_functions import phi_action

    a = -np.eye(3)
    v = np.ones((3, 1))
    for method in ("auto", "expm", "eigh", "krylov"):
        with pytest.raises(TypeError, match="must both be numpy arrays or both torch tensors"):
            phi_action(a, torch.as_tensor(v), 1, method=method, symmetric=True)
        with pytest.raises(TypeError, match="must both be numpy arrays or both torch tensors"):
            phi_action(torch.as_tensor(a), v, 1, method=method, symmetric=True)
