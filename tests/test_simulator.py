"""The public `simulate` contract: shapes, seeding, controls, divergence flagging."""

import numpy as np
import pytest

from agent_envs import SwarmParams, simulate
from agent_envs.integrators import INTEGRATORS


def test_contract_call_from_the_issue():
    x0 = np.random.default_rng(0).uniform(-1, 1, 100)
    traj = simulate(
        SwarmParams(n_agents=100, epsilon=0.05, sigma=0.01),
        integrator="serb",
        jacobian="frozen",
        n_steps=25,
        n_paths=20,
        seed=0,
        initial_positions=x0,
        control=None,
    )
    assert traj.times.shape == (26,)
    assert traj.positions.shape == (26, 20, 100, 1)
    assert traj.times[0] == 0.0 and traj.times[-1] == pytest.approx(1.0)
    np.testing.assert_array_equal(traj.positions[0, 3, :, 0], x0)
    assert not traj.diverged
    assert np.all(np.isfinite(traj.positions))


@pytest.mark.parametrize("name", sorted(INTEGRATORS))
def test_same_seed_gives_bit_identical_trajectories(name):
    params = SwarmParams(n_agents=8, dim=2, sigma=0.1)
    a = simulate(params, name, n_steps=10, n_paths=3, seed=42)
    b = simulate(params, name, n_steps=10, n_paths=3, seed=42)
    np.testing.assert_array_equal(a.positions, b.positions)
    c = simulate(params, name, n_steps=10, n_paths=3, seed=43)
    assert not np.array_equal(a.positions, c.positions)


def test_integrators_see_the_same_brownian_increments():
    """With zero interaction (huge epsilon) every scheme reduces to x + sigma W(t)."""
    params = SwarmParams(n_agents=5, epsilon=1e12, sigma=0.3)
    runs = [
        simulate(params, name, n_steps=12, n_paths=2, seed=5).positions
        for name in sorted(INTEGRATORS)
    ]
    for positions in runs[1:]:
        np.testing.assert_allclose(positions, runs[0], atol=1e-9)


def test_initial_positions_do_not_change_the_noise():
    params = SwarmParams(n_agents=4, epsilon=1e12, sigma=1.0)
    x0 = np.zeros(4)
    a = simulate(params, "em", n_steps=5, n_paths=2, seed=1, initial_positions=x0)
    b = simulate(params, "em", n_steps=5, n_paths=2, seed=1)
    np.testing.assert_allclose(
        a.positions - a.positions[0], b.positions - b.positions[0], atol=1e-9
    )


def test_generator_seed_is_accepted_and_reproducible():
    params = SwarmParams(n_agents=4)
    a = simulate(params, "em", n_steps=5, seed=np.random.default_rng(3))
    b = simulate(params, "em", n_steps=5, seed=np.random.default_rng(3))
    np.testing.assert_array_equal(a.positions, b.positions)


def test_control_as_array_and_callable_agree():
    params = SwarmParams(n_agents=6, dim=2, sigma=0.05)
    m = 8
    u = np.random.default_rng(0).normal(size=(m, 6, 2))
    times = np.linspace(0, 1, m + 1)
    a = simulate(params, "serb", n_steps=m, n_paths=2, seed=0, control=u)

    def feedback(t, x):
        assert x.shape == (2, 6, 2)
        return u[int(np.argmin(np.abs(times - t)))]

    b = simulate(params, "serb", n_steps=m, n_paths=2, seed=0, control=feedback)
    np.testing.assert_allclose(a.positions, b.positions)
    np.testing.assert_allclose(a.controls[:, 1], u)


def test_constant_control_moves_the_mean_exactly():
    """Symmetric interaction: d/dt mean = mean(u); every scheme is exact for the mean."""
    params = SwarmParams(n_agents=10, sigma=0.0, epsilon=0.05)
    u = np.full((20, 10, 1), 0.5)
    for name in sorted(INTEGRATORS):
        traj = simulate(params, name, n_steps=20, n_paths=1, seed=0, control=u)
        means = traj.positions[:, 0].mean(axis=(-2, -1))
        np.testing.assert_allclose(means - means[0], 0.5 * traj.times, atol=1e-12)


def test_integrator_instance_with_conflicting_options_is_rejected():
    from agent_envs import make_integrator

    params = SwarmParams(n_agents=4)
    scheme = make_integrator("serb", jacobian="exact")
    traj = simulate(params, scheme, n_steps=3, seed=0)  # the instance's own choice
    assert traj.jacobian == "exact"
    with pytest.raises(ValueError, match="jacobian"):
        simulate(params, scheme, jacobian="frozen", n_steps=3)
    frozen = make_integrator("serb", jacobian="frozen", phi_method="expm")
    with pytest.raises(ValueError, match="jacobian='exact' conflicts"):
        simulate(params, frozen, jacobian="exact", n_steps=3)
    with pytest.raises(ValueError, match="phi_method='auto' conflicts"):
        simulate(params, frozen, phi_method="auto", n_steps=3)
    simulate(params, frozen, jacobian="frozen", phi_method="expm", n_steps=3)  # agreeing


def test_divergence_is_flagged_not_silent():
    params = SwarmParams(n_agents=20, epsilon=1e-4, sigma=0.0)
    traj = simulate(params, "em", n_steps=5, n_paths=1, seed=0, divergence_threshold=5.0)
    assert traj.diverged
    assert traj.divergence_step is not None and 1 <= traj.divergence_step <= 5
    assert traj.diverged_paths.tolist() == [True]
    assert np.all(np.isfinite(traj.positions[: traj.divergence_step]))
    # the rows after the divergence are NaN, the shapes those of a finished run
    assert traj.positions.shape == (6, 1, 20, 1) and traj.controls.shape == (5, 1, 20, 1)
    assert np.all(np.isnan(traj.positions[traj.divergence_step :]))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(n_steps=0), "n_steps"),
        (dict(n_paths=0), "n_paths"),
        (dict(integrator="rk45"), "integrator"),
        (dict(jacobian="numeric"), "jacobian"),
        (dict(phi_method="pade"), "phi_method"),
        (dict(initial_positions=np.zeros(3)), "initial_positions"),
        (dict(initial_positions=[np.nan] * 4), "initial_positions"),
        (dict(control=np.zeros((2, 4, 1))), "control"),
        (dict(seed="abc"), "seed"),
        (dict(seed=-1), "seed"),
        (dict(divergence_threshold=0.0), "divergence_threshold"),
    ],
)
def test_bad_arguments_raise_clear_errors(kwargs, match):
    with pytest.raises((ValueError, TypeError), match=match):
        simulate(SwarmParams(n_agents=4), **{"n_steps": 5, **kwargs})


def test_hot_path_limits_blas_threads_and_restores_them():
    from threadpoolctl import ThreadpoolController

    from agent_envs import arrays

    controller = ThreadpoolController()
    blas = controller.select(user_api="blas")
    if not blas.lib_controllers:
        pytest.skip("no BLAS library found by threadpoolctl")
    with controller.limit(limits=2, user_api="blas"):
        before = [lib["num_threads"] for lib in blas.info()]
        with arrays.hot_path_threads():
            inside = [lib["num_threads"] for lib in controller.select(user_api="blas").info()]
        simulate(SwarmParams(n_agents=5), n_steps=2, n_paths=1, seed=0)
        after = [lib["num_threads"] for lib in controller.select(user_api="blas").info()]
    assert inside == [1] * len(inside)
    assert after == before


# ----------------------------------------------------------------------- one simulation spec


def test_one_simulation_spec_holds_every_default():
    """`simulate`, the solver, the MPC/optimal controllers and the envs take their defaults
    from `SimulationSpec`'s constants; the one deliberate difference is the number of paths
    (an env episode: 1; a sample average: the paper's K = 20)."""
    import inspect

    from agent_envs.baselines.optimal_control import solve_optimal_control
    from agent_envs.baselines.optimal_controllers import PlanningController
    from agent_envs.envs.episode_config import EpisodeConfig
    from agent_envs.params import SwarmParams
    from agent_envs.simulator import (
        ENV_N_PATHS,
        SAMPLE_AVERAGE_PATHS,
        SimulationSpec,
        simulate,
    )

    spec = SimulationSpec()
    assert (spec.integrator, spec.jacobian, spec.n_steps, spec.max_control) == (
        "serb",
        "frozen",
        50,
        150.0,
    )
    assert ENV_N_PATHS == spec.n_paths == 1 and SAMPLE_AVERAGE_PATHS == 20
    env = EpisodeConfig.from_kwargs(n_agents=4)
    assert env.simulation == spec
    for function in (simulate, solve_optimal_control):
        defaults = {k: p.default for k, p in inspect.signature(function).parameters.items()}
        assert defaults["n_steps"] == spec.n_steps and defaults["integrator"] == spec.integrator
        assert defaults["n_paths"] == SAMPLE_AVERAGE_PATHS
    assert solve_optimal_control.__kwdefaults__["max_control"] == spec.max_control
    planner = inspect.signature(PlanningController).parameters
    assert planner["n_paths"].default == SAMPLE_AVERAGE_PATHS
    # the env's own spec is what a planner reads
    params = SwarmParams(n_agents=4)
    config = EpisodeConfig.from_kwargs(n_agents=4, n_steps=7, max_control=3.0, integrator="em")
    assert config.simulation.for_params(params).time_step(params) == 1 / 7


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"integrator": "rk4"}, "integrator"),
        ({"jacobian": "dense"}, "jacobian"),
        ({"n_steps": 0}, "n_steps"),
        ({"n_paths": 0}, "n_paths"),
        ({"max_control": float("nan")}, "max_control"),
        ({"max_control": -1.0}, "max_control"),
        ({"seed": -1}, "seed"),
        ({"seed": 1.5}, "seed"),
    ],
)
def test_simulation_spec_names_a_bad_field(kwargs, name):
    from agent_envs.simulator import SimulationSpec

    with pytest.raises((ValueError, TypeError), match=name):
        SimulationSpec(**kwargs)


def test_simulation_spec_checks_the_batch_size_against_the_model():
    from agent_envs.params import SwarmParams
    from agent_envs.simulator import SimulationSpec

    with pytest.raises(ValueError, match="n_paths"):
        SimulationSpec(n_paths=10**6).for_params(SwarmParams(n_agents=1000))


def test_batched_brownian_increments_equal_each_generators_own_bit_for_bit():
    """`fill_brownian_increments` (the native vector env's draws: each row from its own
    generator, scaled once) gives each row the bits `brownian_increments` gives that generator
    alone, and leaves the other rows as they were; the scaling is sqrt(dt) z itself."""
    from agent_envs.draws import brownian_increments, fill_brownian_increments

    dt, shape = 0.02, (3, 7, 2)
    alone = [brownian_increments(np.random.default_rng(s), shape, dt) for s in (4, 5, 6)]
    out = fill_brownian_increments(
        [np.random.default_rng(s) for s in (4, 6)], [0, 2], np.zeros((3, *shape)), dt
    )
    np.testing.assert_array_equal(out[0], alone[0])
    np.testing.assert_array_equal(out[2], alone[2])
    np.testing.assert_array_equal(out[1], 0.0)
    z = np.random.default_rng(4).standard_normal(shape)
    np.testing.assert_array_equal(alone[0], np.sqrt(dt) * z)


def _same_state(a, b) -> bool:
    """Bit generator states (dicts of ints, strings and arrays) equal entry by entry."""
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same_state(a[k], b[k]) for k in a)
    if isinstance(a, np.ndarray):
        return np.array_equal(a, b)
    return a == b


def _compiled_noise_or_skip():
    pytest.importorskip("numba")
    from agent_envs.draws import load_compiled_noise

    if not load_compiled_noise():
        pytest.skip("compiled draws switched off (AGENT_ENVS_NUMBA=0)")


@pytest.mark.parametrize("bit_generator", ["PCG64", "MT19937", "Philox", "SFC64", "PCG64DXSM"])
def test_compiled_draws_are_numpys_bit_for_bit_and_advance_the_generator_alike(bit_generator):
    """One compiled call over many generators (`GeneratorHandles`) gives each row numpy's own
    normals from that generator, scaled by sqrt(dt) as numpy scales them, over enough draws to
    take the ziggurat's rare branches (about 1 % of the draws: the wedges and the tail); each
    generator's state then continues as numpy's would (the next numpy draw is the same)."""
    _compiled_noise_or_skip()
    from agent_envs.draws import GeneratorHandles, fill_brownian_increments

    kind = getattr(np.random, bit_generator)
    seeds, rows, dt = (11, 12, 13), [2, 0, 3], 0.05
    rngs = [np.random.Generator(kind(s)) for s in seeds]
    twins = [np.random.Generator(kind(s)) for s in seeds]
    shape = (4, 250_000)  # a million normals with the empty row
    out = fill_brownian_increments(rngs, rows, np.zeros(shape), dt, GeneratorHandles(rngs))
    expected = np.zeros(shape)
    for twin, row in zip(twins, rows, strict=True):
        expected[row] = twin.standard_normal(shape[1])
    expected *= np.sqrt(dt)
    np.testing.assert_array_equal(out, expected)
    assert np.all(out[1] == 0.0)
    for rng, twin in zip(rngs, twins, strict=True):
        assert _same_state(rng.bit_generator.state, twin.bit_generator.state)
        assert rng.standard_normal() == twin.standard_normal()


def test_compiled_draws_take_the_tail_of_the_ziggurat_as_numpy():
    """Normals beyond the ziggurat's last rectangle (|z| > 3.654, drawn by the tail branch)
    are numpy's too: 4e6 draws hold about a thousand of them."""
    _compiled_noise_or_skip()
    from agent_envs.draws import GeneratorHandles, fill_brownian_increments

    rngs = [np.random.default_rng(99)]
    out = fill_brownian_increments(rngs, [0], np.zeros((1, 4_000_000)), 1.0, GeneratorHandles(rngs))
    expected = np.random.default_rng(99).standard_normal(4_000_000)
    assert np.sum(np.abs(expected) > 3.6541528853610088) > 100
    np.testing.assert_array_equal(out[0], expected)


def test_generator_handles_check_their_generators_and_survive_copies():
    """Handles are used only with their own generators (else ValueError); a copy (deepcopy,
    pickle) takes this process's addresses again, and draws the copied generators' numbers."""
    _compiled_noise_or_skip()
    import copy
    import pickle

    from agent_envs.draws import GeneratorHandles, fill_brownian_increments

    rngs = [np.random.default_rng(s) for s in (1, 2)]
    handles = GeneratorHandles(rngs)
    assert handles.holds(rngs) and not handles.holds(rngs[::-1])
    with pytest.raises(ValueError, match="handles"):
        fill_brownian_increments(rngs[::-1], [0, 1], np.zeros((2, 5)), 1.0, handles)
    with pytest.raises(ValueError, match="rows"):
        fill_brownian_increments(rngs, [0], np.zeros((2, 5)), 1.0, handles)
    with pytest.raises(TypeError, match="Generator"):
        GeneratorHandles([np.random.RandomState(0)])
    with pytest.raises(AttributeError, match="cannot be changed"):
        handles.rngs = tuple(rngs[::-1])
    with pytest.raises(ValueError, match="read-only"):
        handles.states[0] = 0
    others = [np.random.default_rng(s) for s in (1, 2)]
    other_handles = GeneratorHandles(others)
    for bad in ([2, 0], [0, -3]):  # outside the 2 rows of out: never a write past it
        base = np.zeros((4, 5))
        with pytest.raises(IndexError, match="rows"):
            fill_brownian_increments(others, bad, base[:2], 1.0, other_handles)
        assert not base.any()
    negative = fill_brownian_increments(others, [-1, 0], np.zeros((2, 5)), 1.0, other_handles)
    expected = [np.random.default_rng(s).standard_normal(5) for s in (2, 1)]
    np.testing.assert_array_equal(negative, np.stack(expected))
    for clone in (copy.deepcopy, lambda h: pickle.loads(pickle.dumps(h))):
        twin = clone(handles)
        assert twin.holds(twin.rngs) and not twin.holds(rngs)
        assert not np.array_equal(twin.states, handles.states)
        out = fill_brownian_increments(twin.rngs, [1, 0], np.zeros((2, 5)), 1.0, twin)
        expected = [np.random.default_rng(s).standard_normal(5) for s in (2, 1)]
        np.testing.assert_array_equal(out, np.stack(expected))


def test_draws_without_the_compiled_call_are_the_same_bits():
    """The compiled draws switched off, the same handles give the same bits through numpy's
    one call per generator."""
    _compiled_noise_or_skip()
    from agent_envs.draws import (
        GeneratorHandles,
        fill_brownian_increments,
        use_compiled_noise,
    )

    def draw(out):
        rngs = [np.random.default_rng(s) for s in (7, 8)]
        return fill_brownian_increments(rngs, [1, 0], out, 0.3, GeneratorHandles(rngs))

    fast = draw(np.zeros((2, 40)))
    before = use_compiled_noise(False)
    try:
        np.testing.assert_array_equal(draw(np.zeros((2, 40))), fast)
        rngs = [np.random.default_rng(1)]
        with pytest.raises(ValueError, match="handles"):  # checked with or without numba
            fill_brownian_increments(rngs, [0], np.zeros((1, 3)), 1.0, GeneratorHandles([]))
    finally:
        use_compiled_noise(before)


def test_compiled_draws_that_differ_from_numpys_are_switched_off(monkeypatch):
    """The load-time check: a module whose draws differ from numpy's (or that fails to build)
    is never used, with a RuntimeWarning, and the draws are numpy's calls."""
    _compiled_noise_or_skip()
    from agent_envs import draws
    from agent_envs.native import loader

    def failing(module):
        raise RuntimeError("no codegen")

    for check, message in ((lambda module: False, "differ"), (failing, "did not load")):
        monkeypatch.setattr(draws, "_draws_equal_numpys", check)
        monkeypatch.setitem(loader._loaded, "noise", None)
        with pytest.warns(RuntimeWarning, match=message):
            assert draws.load_compiled_noise() is False
        rngs = [np.random.default_rng(3)]
        out = draws.fill_brownian_increments(
            rngs, [0], np.zeros((1, 6)), 1.0, draws.GeneratorHandles(rngs)
        )
        np.testing.assert_array_equal(out[0], np.random.default_rng(3).standard_normal(6))
    monkeypatch.undo()
    draws.use_compiled_noise(True)
    assert draws.load_compiled_noise()


@pytest.mark.parametrize("torch_too", [False, True])
def test_diverged_paths_flags_non_finite_and_beyond_threshold(torch_too):
    """A path diverged when some coordinate is NaN, +-inf or |x| > threshold (exactly at the
    threshold it has not), per leading index; numpy and torch alike."""
    from agent_envs.simulator import diverged_paths

    x = np.zeros((7, 3, 2))
    x[1, 0, 1] = np.nan
    x[2, 2, 0] = np.inf
    x[3, 1, 1] = -np.inf
    x[4, 0, 0] = 10.0  # at the threshold
    x[5, 0, 0] = -np.nextafter(10.0, 11.0)  # just beyond it
    x[6] = 9.9
    want = [False, True, True, True, False, True, False]
    if torch_too:
        torch = pytest.importorskip("torch")
        got = diverged_paths(torch.as_tensor(x), 10.0).numpy()
    else:
        got = diverged_paths(x, 10.0)
    np.testing.assert_array_equal(got, want)
    batched = diverged_paths(np.stack([x, x[::-1]]), 10.0)
    np.testing.assert_array_equal(np.asarray(batched), [want, want[::-1]])
    # an infinite threshold: only non-finite coordinates diverge
    np.testing.assert_array_equal(
        np.asarray(diverged_paths(x, np.inf)), [False, True, True, True, False, False, False]
    )
