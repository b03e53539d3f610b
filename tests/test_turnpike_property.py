"""`reproduce turnpike-property`: arc fits and bounds on known inputs, a tiny end-to-end run."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest

from agent_envs.training.experiments.turnpike_property import (
    arc_rates,
    centre_mode_rate,
    cheap_constant,
    theorem_sides,
    turnpike_curve,
)


def test_arc_rates_recover_exponential_entry_and_exit():
    times = np.linspace(0.0, 4.0, 81)
    curve = np.exp(-6.0 * times) + np.exp(3.0 * (times - 4.0)) * 1e-3
    rates = arc_rates(times, curve, delta=1e-4)
    assert rates.entry_rate == pytest.approx(6.0, rel=1e-3)
    assert rates.exit_rate == pytest.approx(3.0, rel=0.1)
    inside = np.count_nonzero(curve <= 1e-4)
    assert rates.share_within_delta == pytest.approx(inside / curve.size)


def test_arc_rates_without_a_turnpike_fit_the_decay_to_the_minimum():
    times = np.linspace(0.0, 1.0, 11)
    rates = arc_rates(times, np.exp(-2.0 * times), delta=1e-6)
    assert rates.entry_rate == pytest.approx(2.0)
    assert math.isnan(rates.exit_rate) and rates.share_within_delta == 0.0


def test_turnpike_curve_and_cheap_constant_formulas():
    mean = np.zeros((3, 2, 1)) + 0.5
    controls = np.ones((2, 2, 1))
    np.testing.assert_allclose(turnpike_curve(mean, controls, np.array([0.0])), [2.5, 2.5])
    dt, gamma, sup = 0.1, 0.01, 5.0
    beta_p = 2.0 * ((12.0 + sup) ** 2 + sup**2)
    expected = 2 * dt * (1 + gamma * beta_p) / (gamma * (1 - math.exp(-2 * 12.0 * dt)))
    assert cheap_constant(dt, gamma, sup) == pytest.approx(expected)


def test_theorem_sides_on_a_state_at_the_static_pair():
    positions = np.full((5, 3, 4, 1), 0.7)
    positions[0] = 0.0
    lhs, rhs = theorem_sides(positions, np.zeros((4, 4, 1)), np.array([0.7]), 0.01, 0.1, 2.0)
    assert lhs == 0.0
    alpha0 = 0.01 / 8 * (4 * 0.49)
    assert rhs == pytest.approx(4.0 / (0.1 * 2) * alpha0)


def test_tiny_run_writes_figure_and_table(tmp_path):
    pytest.importorskip("torch")
    from agent_envs.training.commands.cli import main

    out = tmp_path / "tp"
    argv = [
        "reproduce", "turnpike-property", "--out", str(out), "--n-agents", "4",
        "--n-paths", "2", "--tau", "0.25", "--horizons", "0.5", "1",
        "--sigmas", "0", "0.1", "--epsilons", "1", "--kernels", "symmetric", "--no-progress",
    ]  # fmt: skip
    assert main(argv) == 0
    assert (out / "turnpike_property.png").stat().st_size > 0
    rows = list(csv.DictReader(open(out / "turnpike_property.csv")))
    assert [(r["sigma"], r["T"], r["m"]) for r in rows] == [
        ("0.0", "0.5", "2"), ("0.0", "1.0", "4"), ("0.1", "0.5", "2"), ("0.1", "1.0", "4"),
    ]  # fmt: skip
    assert all(r["converged"] == "True" for r in rows)
    assert all(float(r["cheap_bound"]) >= float(r["V"]) for r in rows)
    bad = ["reproduce", "turnpike-property", "--out", str(out), "--tau", "0.3", "--horizons", "1"]
    assert main(bad) == 2


def test_centre_mode_rate_is_the_scalar_riccati_rate():
    # gamma = 0.01, tau = 0.05: iterate the scalar Riccati map to its fixed point independently
    gamma, dt = 0.01, 0.05
    p = 1.0
    for _ in range(10_000):
        p = dt + p - (p * dt) ** 2 / (dt * gamma + dt**2 * p)
    gain = p * dt / (dt * gamma + dt**2 * p)
    expected = -2.0 * math.log(1.0 - dt * gain) / dt
    assert centre_mode_rate(20.0, 10, gamma, dt) == pytest.approx(expected, rel=1e-12)
    # unequal weights make the weighted centre cheaper to move (g < gamma): a faster decay
    assert centre_mode_rate(np.linspace(1.0, 10.0, 10), 10, gamma, dt) > expected
