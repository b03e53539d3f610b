"""The optimal-control solver: gradients, the LQ case vs Riccati, optimality against other
controls, the cost contract, bad input, non-convergence, and the planning controllers."""

from __future__ import annotations

import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
from episodes import episode_cost

import agent_envs  # noqa: F401  (registers the env id)
from agent_envs.baselines import (
    BASELINES,
    MPCController,
    OptimalController,
    cheap_control,
    make_baseline,
    solve_optimal_control,
    turnpike_time,
)
from agent_envs.baselines.linear_quadratic import (
    constant_linearization,
    discrete_linear_dynamics,
    solve_linear_quadratic,
)
from agent_envs.baselines.optimal_control import DiscreteCostObjective
from agent_envs.costs import discrete_cost
from agent_envs.dynamics.swarm import SwarmModel
from agent_envs.params import SwarmParams
from agent_envs.simulator import simulate

torch = pytest.importorskip("torch")

ENV_ID = "agent_envs/Swarm-v0"


class ConstantKernel:
    """p(x, y) = c: the dynamics x' = L x + u are linear (written for numpy and torch)."""

    symmetric = True
    radial = True

    def __init__(self, c: float) -> None:
        self.c = c

    def value(self, xk, xl):
        return 0.0 * (xk - xl).sum(-1) + self.c

    def grad_x(self, xk, xl):
        return 0.0 * (xl - xk)

    def grad_y(self, xk, xl):
        return 0.0 * (xl - xk)


def sample_cost(params, integrator, controls, seed, x0, n_paths, n_steps):
    traj = simulate(
        params,
        integrator,
        n_steps=n_steps,
        n_paths=n_paths,
        seed=seed,
        initial_positions=x0,
        control=controls,
    )
    dt = params.horizon / n_steps
    return float(
        np.mean(
            discrete_cost(traj.positions, traj.controls, params.target_vector, params.gamma, dt)
        )
    )


# ------------------------------------------------------------------------------------------
# Gradients
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("integrator", ["serb", "em"])
def test_gradient_matches_central_differences(integrator):
    # eps = 1, alpha = 0.5: EM is stable at this tau, so the comparison is meaningful for both.
    params = SwarmParams(n_agents=5, epsilon=1.0, alpha=0.5, sigma=0.1, gamma=0.05)
    n_steps, x0 = 4, np.linspace(-1.0, 1.0, 5)[:, None]
    objective = DiscreteCostObjective(params, integrator, "frozen", "auto", n_steps, 3, 7, x0)
    rng = np.random.default_rng(1)
    u = rng.normal(scale=2.0, size=n_steps * 5)
    value, grad = objective(u)
    assert value == pytest.approx(
        sample_cost(params, integrator, u.reshape(n_steps, 5, 1), 7, x0, 3, n_steps), rel=1e-12
    )
    h = 1e-5
    for _ in range(4):
        direction = rng.normal(size=u.size)
        fd = (objective(u + h * direction)[0] - objective(u - h * direction)[0]) / (2 * h)
        assert grad @ direction == pytest.approx(fd, rel=1e-7, abs=1e-12)


# ------------------------------------------------------------------------------------------
# LQ case vs the Riccati recursion
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("integrator", ["serb", "em"])
@pytest.mark.parametrize("sigma", [0.0, 0.05])
def test_linear_quadratic_case_matches_riccati(integrator, sigma):
    params = SwarmParams(n_agents=6, kernel=ConstantKernel(3.0), sigma=sigma, gamma=0.01)
    n_steps, n_paths, seed = 10, 4, 3
    dt = params.horizon / n_steps
    x0 = np.linspace(-1.0, 1.0, 6)[:, None]
    a, b = discrete_linear_dynamics(constant_linearization(params), dt, integrator)
    free = simulate(
        params, integrator, n_steps=n_steps, n_paths=n_paths, seed=seed, initial_positions=x0
    ).positions
    disturbance = (free[1:] - np.einsum("ij,npjd->npid", a, free[:-1])).mean(axis=1)
    reference = solve_linear_quadratic(
        a, b, x0, params.target_vector, params.gamma, dt, n_steps, disturbance
    )
    ref_cost = sample_cost(params, integrator, reference.controls, seed, x0, n_paths, n_steps)
    res = solve_optimal_control(
        params,
        integrator,
        n_steps=n_steps,
        n_paths=n_paths,
        seed=seed,
        initial_positions=x0,
        max_control=1e3,
        gtol=1e-9,
    )
    assert res.converged
    assert abs(res.cost - ref_cost) / ref_cost <= 1e-8
    assert np.max(np.abs(res.controls - reference.controls)) <= 1e-6
    if sigma == 0.0:
        assert abs(res.cost - reference.mean_cost) / reference.mean_cost <= 1e-8


# ------------------------------------------------------------------------------------------
# V below the cost of every other control on the same paths
# ------------------------------------------------------------------------------------------


def feedback_controls(params, integrator, n_steps, n_paths, seed, x0, kind, max_control):
    """The control sequence a feedback baseline applies on the K paths (path means, clipped)."""
    model = SwarmModel(params)
    target = params.target_vector
    tbar = turnpike_time(x0, target, horizon=params.horizon)

    def control(t, x):
        if kind == "zero" or t >= tbar - 1e-9:
            return np.zeros(x.shape[1:])
        u = cheap_control(
            x.mean(0),
            model.interaction_drift(x).mean(0),
            target,
            cancel_interaction=kind == "turnpike",
        )
        return np.clip(u, -max_control, max_control)

    traj = simulate(
        params,
        integrator,
        n_steps=n_steps,
        n_paths=n_paths,
        seed=seed,
        initial_positions=x0,
        control=control,
    )
    return traj.controls[:, 0]


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_value_is_below_zero_proportional_and_turnpike(seed):
    params = SwarmParams(n_agents=8, epsilon=0.05, sigma=0.01)
    n_steps, n_paths, bound = 12, 5, 150.0
    x0 = np.random.default_rng(100 + seed).uniform(-1.0, 1.0, size=(8, 1))
    res = solve_optimal_control(
        params,
        "serb",
        n_steps=n_steps,
        n_paths=n_paths,
        seed=seed,
        initial_positions=x0,
        max_control=bound,
    )
    assert res.converged
    for kind in ("zero", "proportional", "turnpike"):
        u = feedback_controls(params, "serb", n_steps, n_paths, seed, x0, kind, bound)
        other = sample_cost(params, "serb", u, seed, x0, n_paths, n_steps)
        assert res.cost <= other * (1 + 1e-12), kind


@pytest.mark.slow
def test_value_is_below_a_trained_ppo():
    """V <= the cost of the control sequence a (briefly) trained PPO applies from x0, on the
    solver's own paths, for several seeds: the optimum is a lower bound for learners too."""
    sb3 = pytest.importorskip("stable_baselines3")
    n, n_steps, n_paths, bound = 8, 12, 5, 150.0
    kwargs = {"n_agents": n, "n_steps": n_steps, "n_paths": n_paths, "max_control": bound}
    params = SwarmParams(n_agents=n, epsilon=0.05, sigma=0.01)
    model = sb3.PPO("MlpPolicy", gym.make(ENV_ID, **kwargs), n_steps=64, batch_size=64, seed=0)
    model.learn(512)
    env = gym.make(ENV_ID, **kwargs)
    for seed in range(3):
        x0 = np.random.default_rng(200 + seed).uniform(-1.0, 1.0, size=(n, 1))
        obs, _ = env.reset(seed=seed, options={"initial_positions": x0})
        controls = []
        for _ in range(n_steps):
            action, _ = model.predict(obs, deterministic=True)
            obs, _, _, _, info = env.step(action)
            controls.append(info["control"])
        u = np.asarray(controls)  # (n_steps, N, d), the clipped control the env applied
        res = solve_optimal_control(
            params,
            "serb",
            n_steps=n_steps,
            n_paths=n_paths,
            seed=seed,
            initial_positions=x0,
            max_control=bound,
        )
        assert res.converged
        other = sample_cost(params, "serb", u, seed, x0, n_paths, n_steps)
        assert res.cost <= other * (1 + 1e-12), seed
        assert other > 1.01 * res.cost  # a short-trained PPO is not optimal: the check can fail


# ------------------------------------------------------------------------------------------
# Contract, bad input, non-convergence
# ------------------------------------------------------------------------------------------


def test_result_cost_is_simulate_plus_costs_and_shapes():
    params = SwarmParams(n_agents=5, dim=2, epsilon=0.5, sigma=0.01, target=(0.5, -0.2))
    x0 = np.random.default_rng(0).uniform(-1.0, 1.0, size=(5, 2))
    res = solve_optimal_control(
        params, "serb", n_steps=6, n_paths=4, seed=0, initial_positions=x0, max_control=150.0
    )
    assert res.controls.shape == (6, 5, 2)
    assert res.positions.shape == (7, 4, 5, 2)
    assert np.all(np.abs(res.controls) <= 150.0)
    traj = simulate(
        params, "serb", n_steps=6, n_paths=4, seed=0, initial_positions=x0, control=res.controls
    )
    np.testing.assert_array_equal(traj.positions, res.positions)
    expected = np.mean(
        discrete_cost(
            traj.positions, traj.controls, params.target_vector, params.gamma, params.horizon / 6
        )
    )
    assert res.cost == expected
    assert res.cost < res.initial_cost
    assert res.relative_gradient_norm <= 1e-6


def test_box_bound_is_active_when_small():
    params = SwarmParams(n_agents=4, epsilon=1.0, sigma=0.0, target=2.0)
    res = solve_optimal_control(
        params, "serb", n_steps=5, n_paths=1, initial_positions=np.zeros(4), max_control=0.5
    )
    assert res.converged
    assert np.max(np.abs(res.controls)) == pytest.approx(0.5)


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"params": "nope"}, TypeError, "params"),
        ({"integrator": "rk4"}, ValueError, "integrator"),
        ({"jacobian": "approx"}, ValueError, "jacobian"),
        ({"n_steps": 0}, ValueError, "n_steps"),
        ({"n_paths": 0}, ValueError, "n_paths"),
        ({"seed": -1}, ValueError, "seed"),
        ({"seed": np.random.default_rng(0)}, TypeError, "seed"),
        ({"initial_positions": np.zeros(3)}, ValueError, "initial_positions"),
        ({"max_control": 0.0}, ValueError, "max_control"),
        ({"gtol": -1.0}, ValueError, "gtol"),
        ({"max_iterations": 0}, ValueError, "max_iterations"),
        ({"initial_controls": np.zeros((2, 4, 1))}, ValueError, "initial_controls"),
        ({"initial_controls": np.zeros((4, 4, 1))}, ValueError, "initial_controls"),
        ({"threads": 0}, ValueError, "threads"),
        ({"memory": 0}, ValueError, "memory"),
    ],
)
def test_bad_input_is_named(kwargs, error, match):
    call = {"params": SwarmParams(n_agents=4), "n_steps": 3, "n_paths": 1, **kwargs}
    params = call.pop("params")
    with pytest.raises(error, match=match):
        solve_optimal_control(params, **call)


def test_non_convergence_warns_and_is_flagged():
    params = SwarmParams(n_agents=6, epsilon=0.05, sigma=0.01)
    with pytest.warns(RuntimeWarning, match="did not converge"):
        res = solve_optimal_control(params, n_steps=8, n_paths=2, max_iterations=1)
    assert not res.converged
    assert res.relative_gradient_norm > 1e-6
    assert res.iterations == 1


def test_stiff_em_whose_gradient_overflows_is_a_failed_solve():
    """Stiff EM (eps = 0.001, m = 400, tau lambda >> 2): the forward simulation stays bounded
    (the kernel saturates far apart) but the backward pass overflows to inf at u = 0. The
    objective then stands in a penalty with a zero gradient, which passed the relative gradient
    test after 0 iterations (converged=True) before the fix: the README's "stiff EM does not
    solve (converged=False)"."""
    params = SwarmParams(n_agents=10, epsilon=0.001, sigma=0.01)
    with pytest.warns(
        RuntimeWarning, match="did not converge: failed: at u = 0: .*non-finite"
    ) as record:
        res = solve_optimal_control(params, "em", n_steps=400, n_paths=2, max_iterations=20)
    # the gradient's warning points at the integrator, not at EM's absent phi-method
    assert any("try integrator='serb'" in str(w.message) for w in record)
    assert not res.converged
    assert res.failure is not None and "non-finite gradient" in res.failure
    assert np.isfinite(res.cost)


def test_stiff_em_at_the_paper_setting_does_not_solve():
    """The README's case (eps = 0.05, m = 20, tau lambda ~ 100): gradients of ~1e11 at u = 0,
    the line search fails; finite numbers, so no `failure`, but never `converged`."""
    params = SwarmParams(n_agents=10, epsilon=0.05, sigma=0.01)
    with pytest.warns(RuntimeWarning, match="did not converge"):
        res = solve_optimal_control(params, "em", n_steps=20, n_paths=2, max_iterations=20)
    assert not res.converged
    assert res.failure is None
    assert res.relative_gradient_norm > 1e-6


def test_a_finite_solve_reports_no_failure():
    import warnings

    params = SwarmParams(n_agents=4, epsilon=1.0, sigma=0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a converged solve warns about nothing
        res = solve_optimal_control(params, n_steps=5, n_paths=1)
    assert res.converged and res.failure is None


def test_baselines_import_without_torch_and_solve_names_the_extra():
    code = (
        "import sys\n"
        "class NoTorch:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name.split('.')[0] == 'torch':\n"
        "            raise ImportError('no torch here')\n"
        "sys.meta_path.insert(0, NoTorch())\n"
        "import agent_envs.baselines as b\n"
        "from agent_envs.params import SwarmParams\n"
        "try:\n"
        "    b.solve_optimal_control(SwarmParams(n_agents=3), n_steps=2, n_paths=1)\n"
        "except ImportError as e:\n"
        "    print('IMPORTERROR', e)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert "IMPORTERROR" in out.stdout and "train" in out.stdout


# ------------------------------------------------------------------------------------------
# Controllers
# ------------------------------------------------------------------------------------------


def run_episode(env, policy, seed):
    return episode_cost(policy, env, seed)


def test_registered_as_baselines():
    assert BASELINES["optimal"] is OptimalController
    assert BASELINES["mpc"] is MPCController


def test_optimal_controller_reaches_the_value_in_a_noise_free_env():
    kwargs = {"n_agents": 5, "n_steps": 8, "sigma": 0.0, "epsilon": 0.05}
    env = gym.make(ENV_ID, **kwargs)
    ctrl = make_baseline("optimal", env, noise_free=True)
    cost = run_episode(env, ctrl, seed=3)
    res = ctrl.last_result
    assert res.converged
    # float32 observations/actions are the only difference between the plan and the env.
    assert cost == pytest.approx(res.cost, rel=1e-5)
    zero = run_episode(env, make_baseline("zero", env), seed=3)
    assert cost < zero


def test_mpc_matches_open_loop_without_noise_and_handles_batches():
    kwargs = {"n_agents": 4, "n_steps": 6, "sigma": 0.0, "epsilon": 0.05}
    env = gym.make(ENV_ID, **kwargs)
    optimal = run_episode(env, OptimalController(env, noise_free=True), seed=1)
    mpc = MPCController(env, noise_free=True)
    cost = run_episode(env, mpc, seed=1)
    assert mpc.solves == 6
    assert cost == pytest.approx(optimal, rel=1e-4)
    # a batch of two observations (a VecEnv) gets one plan per row
    obs = np.stack([env.reset(seed=s)[0] for s in (1, 2)])
    actions, _ = mpc.predict(obs)
    assert actions.shape == (2, 4) and actions.dtype == np.float32
    assert np.all(np.abs(actions) <= 1.0)


def test_controllers_reject_per_agent_rows():
    env = gym.make(ENV_ID, n_agents=4, n_steps=3)
    ctrl = OptimalController(env, noise_free=True)
    with pytest.raises(ValueError, match="per-agent"):
        ctrl.predict(np.zeros(4, np.float32))


@pytest.mark.parametrize(
    "device",
    [
        "cpu",
        pytest.param(
            "cuda",
            marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA"),
        ),
    ],
)
def test_device_gives_the_same_solution(device):
    params = SwarmParams(n_agents=5, epsilon=0.05, sigma=0.01)
    common = {"n_steps": 6, "n_paths": 3, "seed": 2}
    base = solve_optimal_control(params, **common)
    res = solve_optimal_control(params, device=device, **common)
    assert res.converged
    np.testing.assert_allclose(res.controls, base.controls, rtol=1e-6, atol=1e-6)
    assert res.cost == pytest.approx(base.cost, rel=1e-10)


def test_act_on_the_pettingzoo_parallel_env_reaches_the_value():
    from agent_envs import swarm_v0

    env = swarm_v0.parallel_env(n_agents=4, n_steps=5, sigma=0.0)
    obs, _ = env.reset(seed=1)
    ctrl = OptimalController(env, noise_free=True)
    total = 0.0
    while env.agents:
        obs, rewards, _, _, _ = env.step(ctrl.act(obs))
        total -= sum(rewards.values())
    assert total == pytest.approx(ctrl.last_result.cost, rel=1e-5)


def test_differentiated_phi_method_is_dense_unless_chosen():
    from agent_envs.baselines.optimal_control import differentiated_phi_method

    assert differentiated_phi_method(SwarmParams(n_agents=4), "frozen", None) == "eigh"
    assert differentiated_phi_method(SwarmParams(n_agents=4), "exact", "auto") == "eigh"
    nonsym = SwarmParams(n_agents=4, kernel="nonsymmetric")
    assert differentiated_phi_method(nonsym, "frozen", None) == "expm"
    assert differentiated_phi_method(nonsym, "frozen", "krylov") == "krylov"


@pytest.mark.slow
def test_large_batched_solve_converges_with_the_default_phi_method():
    # N = 100 with 20 paths is where 'auto' picks Krylov, whose torch backward gave NaN
    # gradients (see differentiated_phi_method); the default must still converge.
    params = SwarmParams(n_agents=100, epsilon=0.05, sigma=0.01)
    res = solve_optimal_control(params, n_steps=20, n_paths=20, seed=0)
    assert res.converged
    assert res.cost < 0.5 * res.initial_cost


def test_optimal_references_run_only_when_asked_for():
    """`evaluate` without -p and `compare --optimum ''` run the three feedback references only:
    the optimal-control ones solve an optimization per episode (or step) and must be named."""
    from agent_envs.training.commands.compare import CompareConfig
    from agent_envs.training.commands.evaluate_options import parse_policy_specs
    from agent_envs.training.defaults import FEEDBACK_BASELINES

    assert tuple(parse_policy_specs(None)) == FEEDBACK_BASELINES
    assert parse_policy_specs(["optimal", "mpc"]) == {"optimal": "optimal", "mpc": "mpc"}
    assert CompareConfig(optimum="").optimum_policies == []
    # the quick preset names the optimum only (MPC equals it at sigma = 0.01, docs/presets.md),
    # the paper preset both
    assert CompareConfig().optimum_policies == ["optimal"]
    assert CompareConfig(preset="paper").optimum_policies == ["optimal", "mpc"]


# ------------------------------------------------------- details (mutation run)
def test_projected_gradient_zeroes_only_components_pushing_against_an_active_bound():
    from agent_envs.baselines.optimal_control import projected_gradient

    u = np.array([2.0, 2.0, 3.0, -2.0, -2.0, -3.0, 0.0, 1.9])
    g = np.array([-0.5, 0.5, -0.5, 0.5, -0.5, 0.5, -0.5, -0.5])
    want = np.array([0.0, 0.5, 0.0, 0.0, -0.5, 0.0, -0.5, -0.5])
    np.testing.assert_array_equal(projected_gradient(u, g, 2.0), want)


def test_warm_start_relative_gradient_is_against_the_gradient_at_zero():
    """The reference of the relative gradient norm is max|projected gradient| at u = 0, also
    when the solve starts elsewhere (a warm start); evaluations are counted; the wall time is
    the solve's."""
    import time

    from agent_envs.baselines.optimal_control import projected_gradient

    params = SwarmParams(n_agents=3, epsilon=1.0, sigma=0.0)
    start = np.full((4, 3, 1), 1.0)
    began = time.perf_counter()
    res = solve_optimal_control(
        params, n_steps=4, n_paths=1, initial_controls=start, max_iterations=1, warn=False
    )
    elapsed = time.perf_counter() - began
    objective = DiscreteCostObjective(
        params, "serb", "frozen", "eigh", 4, 1, 0, res.positions[0, 0]
    )
    _, g_zero = objective(np.zeros(12))
    reference = np.max(np.abs(projected_gradient(np.zeros(12), g_zero, 150.0)))
    assert res.relative_gradient_norm == pytest.approx(res.gradient_norm / reference, rel=1e-9)
    assert res.evaluations >= res.iterations + 2  # the start, u = 0, and the iterations
    assert 0.0 < res.wall_time <= elapsed
    # a (m, N) warm start in d = 1 is the same start
    again = solve_optimal_control(
        params, n_steps=4, n_paths=1, initial_controls=start[..., 0], max_iterations=1, warn=False
    )
    np.testing.assert_array_equal(again.controls, res.controls)
    assert res.mean_positions.shape == (5, 3, 1)  # a property: E x^n over the paths
    np.testing.assert_array_equal(res.mean_positions, res.positions.mean(axis=1))
    # a warm start below zero: the reference is still the gradient at u = 0
    low = solve_optimal_control(
        params, n_steps=4, n_paths=1, initial_controls=-start, max_iterations=1, warn=False
    )
    assert low.relative_gradient_norm == pytest.approx(low.gradient_norm / reference, rel=1e-9)


def test_minimize_in_box_at_an_optimal_start_has_relative_gradient_zero():
    """u = 0 optimal with a zero gradient: the reference is 0 and the relative gradient is 0
    (converged), not 0 / 0; the box's solution of a shifted quadratic is found."""
    from agent_envs.baselines.optimal_control import minimize_in_box

    run = minimize_in_box(lambda u: (float(u @ u), 2 * u), np.zeros(3), 1.0, 1e-6, 10, 5)
    assert run.relative == 0.0 and run.gradient_norm == 0.0 and run.failure is None
    np.testing.assert_array_equal(run.result.x, 0.0)
    shifted = minimize_in_box(
        lambda u: (float((u - 2.0) @ (u - 2.0)), 2 * (u - 2.0)), np.zeros(3), 1.0, 1e-6, 10, 5
    )
    np.testing.assert_allclose(shifted.result.x, 1.0)  # the bound is active
    assert shifted.relative == 0.0  # its gradient pushes against the bound: projected to 0
    # an interior optimum: stopped by our relative test (the callback), not L-BFGS-B's own
    c = np.array([1.0, 10.0, 100.0])
    inner = minimize_in_box(
        lambda u: (float(c @ (u - 0.3) ** 2), 2 * c * (u - 0.3)), np.zeros(3), 1.0, 1e-6, 50, 5
    )
    assert "StopIteration" in inner.result.message and inner.result.nit < 50
    # a zero reference with a non-zero gradient at the end: not converged (inf), not 0
    stopped = minimize_in_box(
        lambda u: (float(c @ (u * u)), 2 * c * u), np.full(3, 0.5), 1.0, 1e-6, 1, 5
    )
    assert stopped.gradient_norm > 0 and stopped.relative == np.inf
    assert inner.relative <= 1e-6
    np.testing.assert_allclose(inner.result.x, 0.3, rtol=1e-5)


def test_threads_none_keeps_torch_setting():
    previous = torch.get_num_threads()
    res = solve_optimal_control(SwarmParams(n_agents=3), n_steps=2, n_paths=1, threads=None)
    assert torch.get_num_threads() == previous and np.isfinite(res.cost)


def test_objective_counts_evaluations_and_warns_once_about_a_failed_backward_pass():
    params = SwarmParams(n_agents=10, epsilon=0.001, sigma=0.01)
    x0 = simulate(params, "em", n_steps=400, n_paths=1, seed=0).positions[0, 0]
    objective = DiscreteCostObjective(params, "em", "frozen", "eigh", 400, 2, 0, x0)
    assert objective.evaluations == 0 and objective.last_failure is None
    with pytest.warns(RuntimeWarning, match="non-finite gradient") as record:
        for _ in range(2):
            value, grad = objective(np.zeros(400 * 10))
            assert value == objective.penalty and not np.any(grad)
    assert len([w for w in record if "non-finite gradient" in str(w.message)]) == 1
    assert objective.evaluations == 2 and "non-finite gradient" in objective.last_failure


def test_differentiated_phi_method():
    """Dense strategies whose gradients are tested: eigh for a symmetric linearization (with
    the exact Jacobian only for a radial kernel), expm otherwise; an explicit one is kept."""
    from agent_envs.baselines.optimal_control import differentiated_phi_method

    sym, nonsym = SwarmParams(n_agents=4), SwarmParams(n_agents=4, kernel="nonsymmetric")

    class NotRadial(ConstantKernel):
        radial = False  # symmetric, but its exact Jacobian is not taken as symmetric

    user = SwarmParams(n_agents=4, kernel=NotRadial(1.0))
    assert differentiated_phi_method(sym, "frozen", None) == "eigh"
    assert differentiated_phi_method(sym, "exact", "auto") == "eigh"
    assert differentiated_phi_method(nonsym, "frozen", None) == "expm"
    assert differentiated_phi_method(nonsym, "exact", None) == "expm"
    assert differentiated_phi_method(user, "frozen", None) == "eigh"
    assert differentiated_phi_method(user, "exact", None) == "expm"
    assert differentiated_phi_method(sym, "frozen", "krylov") == "krylov"


def test_torch_threads_sets_and_restores():
    from agent_envs.baselines.optimal_control import torch_threads

    previous = torch.get_num_threads()
    with torch_threads(torch, 1):
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == previous
    with torch_threads(torch, None):
        assert torch.get_num_threads() == previous


def test_documented_defaults():
    """The defaults the README and docstrings quote (gtol 1e-6, 500 iterations, memory 20, one
    torch thread, the env's action bound)."""
    import inspect

    defaults = {
        k: v.default for k, v in inspect.signature(solve_optimal_control).parameters.items()
    }
    assert defaults["gtol"] == 1e-6 and defaults["max_iterations"] == 500
    assert defaults["memory"] == 20 and defaults["threads"] == 1
    assert defaults["integrator"] == "serb" and defaults["jacobian"] == "frozen"
    assert defaults["max_control"] == 150.0
    assert defaults["n_steps"] == 50 and defaults["n_paths"] == 20 and defaults["seed"] == 0


def test_warm_start_is_clipped_to_the_box_and_memory_one_is_allowed():
    from agent_envs.baselines.optimal_control import _initial_controls

    clipped = _initial_controls(np.array([[[200.0]], [[-200.0]], [[0.5]]]), (3, 1, 1), 150.0)
    np.testing.assert_array_equal(clipped[:, 0, 0], [150.0, -150.0, 0.5])
    res = solve_optimal_control(SwarmParams(n_agents=3), n_steps=2, n_paths=1, memory=1)
    assert np.isfinite(res.cost)


def test_the_non_convergence_warning_points_at_the_caller():
    params = SwarmParams(n_agents=6, epsilon=0.05, sigma=0.01)
    with pytest.warns(RuntimeWarning, match="did not converge") as record:
        solve_optimal_control(params, n_steps=8, n_paths=2, max_iterations=1)
    assert record[0].filename == __file__
