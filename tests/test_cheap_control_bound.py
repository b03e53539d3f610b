"""`reproduce cheap-control-bound` (issue 21): the counterexample to Lemma lem:cheap, the noise
floor and the corrected bound (docs/cheap-control-bound.md), on small cases."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest

from agent_envs.draws import brownian_increments
from agent_envs.dynamics.swarm import SwarmModel
from agent_envs.params import SwarmParams
from agent_envs.simulator import simulate
from agent_envs.training.experiments.cheap_control_config import CheapControlBoundConfig
from agent_envs.training.experiments.cheap_control_formulas import (
    StartStatistics,
    centre_control,
    corrected_upper_bound,
    crossing_horizon,
    crossings,
    disagreement_sums,
    fiedler_bound,
    fit_exponent,
    noise_floor,
    paper_rhs,
    sample_floor,
)
from agent_envs.training.experiments.cheap_control_measurements import measure
from agent_envs.training.experiments.turnpike_property import cheap_constant, kernel_bound

TINY = {
    "n_agents": 4, "n_paths": 3, "eval_paths": 40, "tau": 0.25, "horizons": (0.5, 1.0),
    "scaling_agents": (3, 4), "scaling_horizon": 0.5, "scaling_epsilons": (0.5, 1.0),
    "epsilon": 1.0, "max_iterations": 200, "progress": False,
}  # fmt: skip


def test_centre_moves_only_by_the_control_and_the_mean_noise():
    # 1^T L(x) = 0 for the symmetric kernel, so under SERB (frozen and exact J) and EM the
    # centre obeys c^{n+1} = c^n + tau mean_k u_k^n + sigma mean_k dW_k^n, whatever the state
    n, m, sigma = 5, 6, 0.3
    params = SwarmParams(n_agents=n, epsilon=1.0, sigma=sigma, horizon=0.06)
    rng = np.random.default_rng(1)
    dw = brownian_increments(rng, (m, 3, n, 1), params.horizon / m)
    control = rng.normal(size=(m, n, 1))
    for integrator, jacobian in (("serb", "frozen"), ("serb", "exact"), ("em", None)):
        traj = simulate(
            params, integrator, jacobian=jacobian, n_steps=m, n_paths=3, seed=2,
            increments=dw, control=control, initial_positions=rng.uniform(-1, 1, (n, 1)),
        )  # fmt: skip
        centre = traj.positions.mean(axis=2)  # (m+1, K, d)
        step = centre[1:] - centre[:-1]
        assert not traj.diverged
        expected = 0.01 * control.mean(axis=1)[:, None, :] + sigma * dw.mean(axis=2)
        np.testing.assert_allclose(step, expected, atol=1e-10)


def test_counterexample_x0_at_the_target_has_positive_value():
    # Lemma lem:cheap's right side is 0 at x^0 = xbar; the optimum's cost is not
    pytest.importorskip("torch")
    from agent_envs.baselines.optimal_control import solve_optimal_control

    n, m, sigma = 4, 4, 0.2
    params = SwarmParams(n_agents=n, epsilon=1.0, sigma=sigma, horizon=1.0)
    x0 = np.full((n, 1), params.target_vector[0])
    res = solve_optimal_control(params, "serb", n_steps=m, n_paths=4, seed=0, initial_positions=x0)
    c0 = cheap_constant(0.25, params.gamma, kernel_bound(params))
    start = StartStatistics.of(x0[None], params.target_vector)
    assert paper_rhs(c0, params.gamma, start.sq_dist0, n) == 0.0
    floor_k = sample_floor(res.positions, 0.25)
    assert floor_k > 0.0
    assert res.cost >= floor_k * (1 - 1e-9)
    # in expectation: the zero control on many fresh paths costs >= F = sigma^2 tau^2 m(m-1)/(2N)
    traj = simulate(params, "serb", n_steps=m, n_paths=4000, seed=7, initial_positions=x0)
    per_path = np.mean((traj.positions[:m, :, :, 0] - params.target_vector[0]) ** 2, axis=-1)
    costs = 0.25 * per_path.sum(axis=0)  # (paths,)
    se = costs.std(ddof=1) / math.sqrt(costs.size)
    floor = noise_floor(sigma, 0.25, m, n, 1)
    assert floor == pytest.approx(sigma**2 * 0.25**2 * m * (m - 1) / (2 * n))
    assert costs.mean() >= floor - 3 * se and floor > 10 * se


def test_centre_control_contracts_the_mean_centre_exactly_and_costs_at_most_u():
    # sigma = 0, deterministic x^0: the expectation is exact, so cost <= U must hold exactly
    n, m, dt, beta = 6, 40, 0.05, 12.0
    for eps in (0.05, 1.0):
        params = SwarmParams(n_agents=n, epsilon=eps, sigma=0.0, horizon=m * dt)
        x0 = np.random.default_rng(3).uniform(-1, 1, (n, 1))
        target = params.target_vector
        u = centre_control(x0.mean(axis=0), target, beta, dt, m, n)
        traj = simulate(params, "serb", n_steps=m, n_paths=1, seed=0, initial_positions=x0,
                        control=u)  # fmt: skip
        centre = traj.positions[:, 0].mean(axis=-2)[:, 0] - target[0]
        expected = centre[0] * np.exp(-beta * dt * np.arange(m + 1))
        np.testing.assert_allclose(centre, expected, rtol=0, atol=1e-9 * abs(centre[0]))
        x = traj.positions[:m, 0, :, 0]
        cost = dt * np.sum(np.mean((x - target[0]) ** 2, axis=-1) + params.gamma * u[:, 0, 0] ** 2)
        start = StartStatistics.of(x0[None], target)
        mu = fiedler_bound(eps, params.alpha, start.diameter)
        upper = corrected_upper_bound(
            start, sigma=0.0, dt=dt, m=m, n_agents=n, dim=1, gamma=params.gamma, beta=beta, mu=mu
        )
        assert cost <= upper
        # the bound is not loose by orders of magnitude in this deterministic case
        assert upper < 20 * cost


def test_fiedler_bound_is_below_the_second_eigenvalue():
    rng = np.random.default_rng(4)
    for eps in (0.05, 1.0):
        params = SwarmParams(n_agents=7, epsilon=eps)
        model = SwarmModel(params)
        for _ in range(5):
            x = rng.uniform(-2, 2, (7, 1))
            eig = np.sort(np.linalg.eigvalsh(-model.frozen_linearization(x)))
            diameter = float(x.max() - x.min())
            assert eig[0] == pytest.approx(0.0, abs=1e-9)
            assert fiedler_bound(eps, params.alpha, diameter) <= eig[1] * (1 + 1e-12)


def test_disagreement_sums_and_crossings():
    assert disagreement_sums(10, 0.1, 0.0) == pytest.approx((1.0, 0.01 * 45))
    mu, dt, m = 2.0, 0.1, 7
    rho = math.exp(-2 * mu * dt)
    geo = dt * sum(rho**n for n in range(m))
    inner = dt**2 * sum(sum(rho**j for j in range(1, n + 1)) for n in range(m))
    assert disagreement_sums(m, dt, mu) == pytest.approx((geo, inner))
    assert crossing_horizon(lambda k: k - 37.5) == 38
    assert crossing_horizon(lambda k: -1.0, limit=1000) == math.inf
    # at x^0 = xbar the floor exceeds the lemma's zero right side from m = 2 on
    start = StartStatistics(0.0, 0.0, 0.0, 0.0, 0.0)
    lemma, theorem = crossings(start, c0=1e6, sigma=0.1, dt=0.05, n_agents=10, dim=1, gamma=0.01)
    assert lemma == pytest.approx(0.1) and theorem == pytest.approx(0.1)
    # sigma = 0 and a deterministic start: the floor is 0, no crossing
    start = StartStatistics(0.5, 0.0, 1.0, 6.0, 2.0)
    assert crossings(start, c0=10.0, sigma=0.0, dt=0.05, n_agents=4, dim=1, gamma=0.01) == (
        math.inf,
        math.inf,
    )
    assert fit_exponent([1, 2, 4], [3, 12, 48]) == pytest.approx(2.0)


def test_measure_rows_satisfy_the_corrected_bound_and_refute_the_lemma_at_the_target():
    pytest.importorskip("torch")
    config = CheapControlBoundConfig(**TINY)
    x0 = np.random.default_rng(5).uniform(-1, 1, (4, 1))
    for sigma in (0.0, 0.3):
        row, _ = measure("V(T)", config, n_agents=4, horizon=1.0, sigma=sigma, epsilon=1.0, x0=x0)
        assert row["corrected_holds"] and row["corrected_theorem_holds"]
        assert row["floor_K"] <= row["V"] * (1 + 1e-9) and row["V_fresh"] <= row["upper"]
        assert row["lemma_holds"]  # the paper's C0 is loose enough at this T
    at_target = np.full((4, 1), 0.7)
    row, _ = measure("x0=xbar", config, n_agents=4, horizon=1.0, sigma=0.3, epsilon=1.0,
                     x0=at_target)  # fmt: skip
    assert row["lemma_rhs"] == 0.0 and row["V"] > 0.0 and not row["lemma_holds"]
    assert row["corrected_holds"] and row["T_cross_lemma"] == pytest.approx(0.5)


def test_tiny_run_writes_the_table_the_figure_and_the_contraction(tmp_path):
    pytest.importorskip("torch")
    from agent_envs.training.commands.cli import main

    out = tmp_path / "ccb"
    argv = [
        "reproduce", "cheap-control-bound", "--out", str(out), "--n-agents", "4",
        "--n-paths", "3", "--eval-paths", "20", "--tau", "0.25", "--horizons", "0.5", "1",
        "--epsilon", "1", "--scaling-agents", "3", "4", "--scaling-horizon", "0.5",
        "--scaling-epsilons", "0.5", "1", "--max-iterations", "100", "--no-progress",
    ]  # fmt: skip
    assert main(argv) == 0
    assert (out / "cheap_control_bound.png").stat().st_size > 0
    rows = list(csv.DictReader(open(out / "cheap_control_bound.csv")))
    cases = [r["case"] for r in rows]
    assert cases.count("V(T)") == 4 and cases.count("x0=xbar") == 2
    assert cases.count("random x0") == 2 and cases.count("N-scaling") == 2
    assert cases.count("eps-scaling") == 2
    assert all(r["corrected_holds"] == "True" for r in rows)
    assert all(r["lemma_holds"] == "False" for r in rows if r["case"] == "x0=xbar")
    contraction = list(csv.DictReader(open(out / "contraction.csv")))
    closed = [
        r for r in contraction if r["control"].startswith("closed loop") and r["sigma"] == "0.0"
    ]
    # the closed loop of Section 5.2 has the proof's factor exactly; the held control does not
    assert float(closed[0]["factor_median"]) == pytest.approx(float(closed[0]["paper_factor"]))
    held = [r for r in contraction if "frozen J" in r["control"] and r["sigma"] == "0.0"]
    assert float(held[0]["factor_median"]) > 1.5 * float(held[0]["paper_factor"])


@pytest.mark.parametrize(
    ("kwargs", "option"),
    [
        ({"sigma": 0.0}, "--sigma"),
        ({"eval_paths": 1}, "--eval-paths"),
        ({"tau": 0.3}, "--horizons"),
        ({"scaling_horizon": 0.57}, "--scaling-horizon"),
        ({"scaling_agents": (1,)}, "--scaling-agents"),
        ({"scaling_epsilons": (0.0,)}, "--scaling-epsilons"),
        ({"beta": -1.0}, "--beta"),
        ({"horizons": ()}, "--horizons"),
    ],
)
def test_bad_config_names_the_option(kwargs, option):
    with pytest.raises((ValueError, TypeError), match=option):
        CheapControlBoundConfig(**kwargs)
