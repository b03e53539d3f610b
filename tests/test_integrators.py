"""Measured orders of convergence, invariants and registry behaviour of the integrators.

Orders are measured as in diffrax's test_sde1.py: integrate on a sequence of step sizes with
the *same* Brownian path (coarse increments are sums of fine ones), compare with a reference,
fit the slope of log(error) against log(dt) and assert it within a tolerance.
"""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from agent_envs import SwarmModel, SwarmParams, make_integrator, simulate
from agent_envs.integrators import INTEGRATORS

PARAMS = dict(n_agents=6, dim=1, alpha=0.5, epsilon=1.0, horizon=0.5)
STEPS = [8, 16, 32, 64]


def _x0(n=6, d=1):
    return np.linspace(-1.0, 1.0, n * d).reshape(n, d)


def _integrate(scheme, model, x0, m, dw_fine, horizon, control=None, control_rate=None):
    """Integrate with m steps, increments summed from the fine ones (paths, m_fine, N, d)."""
    m_fine = dw_fine.shape[1]
    dw = dw_fine.reshape(dw_fine.shape[0], m, m_fine // m, *dw_fine.shape[2:]).sum(axis=2)
    dt = horizon / m
    x = np.broadcast_to(x0, (dw.shape[0], *x0.shape)).copy()
    for n in range(m):
        t = n * dt
        u = None if control is None else control(t)
        du = None if control_rate is None else control_rate(t)
        x = scheme.step(model, x, u, t, dt, dw[:, n], du_dt=du)
    return x


def _order(errors):
    slope, _ = np.polyfit(np.log([1.0 / m for m in STEPS]), np.log(errors), 1)
    return slope


def _ode_reference(model, x0, horizon, control=None):
    def rhs(t, y):
        u = None if control is None else control(t)
        return model.drift(0.0, y.reshape(x0.shape), u).reshape(-1)

    sol = solve_ivp(rhs, (0, horizon), x0.reshape(-1), method="DOP853", rtol=1e-12, atol=1e-13)
    return sol.y[:, -1].reshape(x0.shape)


@pytest.mark.parametrize(
    ("name", "jacobian", "expected"),
    [
        ("ee", "frozen", 1.0),
        ("heun", "frozen", 2.0),
        ("erb", "exact", 2.0),
        ("erb", "frozen", 1.0),
        ("serb", "exact", 2.0),
    ],
)
@pytest.mark.parametrize("kernel", ["symmetric", "nonsymmetric"])
def test_deterministic_order(name, jacobian, expected, kernel):
    params = SwarmParams(**PARAMS, kernel=kernel, epsilon_min=0.5, epsilon_max=2.0, sigma=0.0)
    model = SwarmModel(params)
    x0 = _x0()
    ref = _ode_reference(model, x0, params.horizon)
    scheme = make_integrator(name, jacobian=jacobian)
    dw = np.zeros((1, STEPS[-1], *x0.shape))
    errors = [
        np.max(np.abs(_integrate(scheme, model, x0, m, dw, params.horizon)[0] - ref)) for m in STEPS
    ]
    assert _order(errors) == pytest.approx(expected, abs=0.25), errors
    assert scheme.deterministic_order == expected  # the metadata says what was measured


@pytest.mark.parametrize(
    ("name", "jacobian", "expected"),
    [
        # additive noise: every scheme here has strong order 1 (the literal value, not the
        # class attribute, which the last assertion checks against it)
        ("em", "frozen", 1.0),
        ("heun", "frozen", 1.0),
        ("serb", "frozen", 1.0),
        ("serb", "exact", 1.0),
        ("erb", "frozen", 1.0),
    ],
)
def test_strong_order_additive_noise(name, jacobian, expected):
    params = SwarmParams(**PARAMS, sigma=0.5)
    model = SwarmModel(params)
    x0 = _x0()
    rng = np.random.default_rng(12345)
    m_fine = 2048
    dw = np.sqrt(params.horizon / m_fine) * rng.standard_normal((200, m_fine, *x0.shape))
    ref = _integrate(make_integrator("heun"), model, x0, m_fine, dw, params.horizon)
    scheme = make_integrator(name, jacobian=jacobian)
    errors = [
        np.mean(
            np.max(
                np.abs(_integrate(scheme, model, x0, m, dw, params.horizon) - ref), axis=(-2, -1)
            )
        )
        for m in STEPS
    ]
    assert _order(errors) == pytest.approx(expected, abs=0.25), errors
    assert scheme.strong_order == expected


@pytest.mark.parametrize(
    ("name", "with_rate", "expected"),
    [("serb", True, 2.0), ("serb", False, 1.0), ("heun", True, 2.0)],
)
def test_control_rate_phi2_term_restores_second_order(name, with_rate, expected):
    """eq:serbaut: with a time-dependent control, the phi2 term keeps ERB/SERB of order 2."""
    params = SwarmParams(**PARAMS, sigma=0.0)
    model = SwarmModel(params)
    x0 = _x0()
    weights = np.linspace(1.0, 2.0, 6)[:, None]

    def control(t):
        return weights * np.sin(3.0 * t)

    def rate(t):
        return 3.0 * weights * np.cos(3.0 * t)

    ref = _ode_reference(model, x0, params.horizon, control)
    scheme = make_integrator(name, jacobian="exact")
    dw = np.zeros((1, STEPS[-1], *x0.shape))
    errors = [
        np.max(
            np.abs(
                _integrate(
                    scheme, model, x0, m, dw, params.horizon, control, rate if with_rate else None
                )[0]
                - ref
            )
        )
        for m in STEPS
    ]
    assert _order(errors) == pytest.approx(expected, abs=0.25), errors


@pytest.mark.parametrize("name", sorted(INTEGRATORS))
@pytest.mark.parametrize("jacobian", ["frozen", "exact"])
def test_symmetric_interaction_conserves_the_mean(name, jacobian):
    params = SwarmParams(n_agents=20, dim=2, epsilon=0.05, sigma=0.0)
    traj = simulate(params, name, jacobian=jacobian, n_steps=200, n_paths=1, seed=0)
    means = traj.positions[:, 0].mean(axis=-2)  # (m+1, d)
    assert not traj.diverged
    np.testing.assert_allclose(means, np.broadcast_to(means[0], means.shape), atol=1e-12)


def test_symmetric_interaction_mean_moves_only_by_the_noise():
    """With noise, the agents' mean moves by exactly sigma * mean(dW) for every integrator."""
    params = SwarmParams(n_agents=10, epsilon=0.05, sigma=0.3)
    results = [
        simulate(params, name, n_steps=30, n_paths=3, seed=7).positions
        for name in sorted(INTEGRATORS)
    ]
    for positions in results[1:]:
        np.testing.assert_allclose(positions.mean(axis=-2), results[0].mean(axis=-2), atol=1e-12)


@pytest.mark.parametrize("m", [5, 25, 100])
def test_frozen_exponential_euler_stays_in_the_convex_hull(m):
    params = SwarmParams(n_agents=50, dim=1, epsilon=0.05, sigma=0.0)
    x0 = np.random.default_rng(3).uniform(-1, 1, 50)
    traj = simulate(params, "erb", jacobian="frozen", n_steps=m, n_paths=1, initial_positions=x0)
    pos = traj.positions[:, 0, :, 0]
    assert pos.min() >= x0.min() - 1e-12
    assert pos.max() <= x0.max() + 1e-12
    # and the hull shrinks monotonically
    spread = pos.max(axis=1) - pos.min(axis=1)
    assert np.all(np.diff(spread) <= 1e-12)


def test_serb_one_step_matches_its_closed_form():
    """Frozen L, eq:serb with H = sigma I: x+ = e^{tau L}(x + sigma dW) + tau phi1(tau L) u."""
    from scipy.linalg import expm

    from agent_envs.integrators.phi_functions import phi_action

    params = SwarmParams(n_agents=6, epsilon=0.05, sigma=0.3)
    model = SwarmModel(params)
    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, (1, 6, 1))
    u = rng.normal(size=(1, 6, 1))
    dw = 0.2 * rng.normal(size=x.shape)
    dt = 0.1
    lx = model.frozen_linearization(x)[0]
    expected = expm(dt * lx) @ (x[0] + 0.3 * dw[0]) + dt * phi_action(
        dt * lx, u[0], 1, method="expm"
    )
    got = make_integrator("serb", jacobian="frozen").step(model, x, u, 0.0, dt, dw)[0]
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12)
    # ERB adds the noise without the sigma J dW correction
    erb = make_integrator("erb", jacobian="frozen").step(model, x, u, 0.0, dt, dw)[0]
    expected_erb = (
        expm(dt * lx) @ x[0] + dt * phi_action(dt * lx, u[0], 1, method="expm") + 0.3 * dw[0]
    )
    np.testing.assert_allclose(erb, expected_erb, rtol=1e-12, atol=1e-12)


def test_exact_jacobian_erb_is_unstable_at_m25_where_frozen_is_not():
    """The measured finding behind the default jacobian='frozen' (README, Section 5.1)."""
    params = SwarmParams(n_agents=100, epsilon=0.05, alpha=0.1, sigma=0.0)
    x0 = np.linspace(-1, 1, 100)
    spread = {}
    for jac in ("exact", "frozen"):
        traj = simulate(params, "erb", jacobian=jac, n_steps=25, n_paths=1, initial_positions=x0)
        final = traj.positions[-1, 0, :, 0]
        spread[jac] = final.max() - final.min()
    assert spread["exact"] > 10.0
    assert spread["frozen"] < 1e-10


def test_exact_jacobian_of_a_symmetric_non_radial_kernel_is_not_treated_as_symmetric():
    class Product:
        """p(x, y) = (1 + x^2)(1 + y^2): symmetric in (x, y) but not radial."""

        symmetric = True

        def value(self, xk, xl):
            return (1 + np.sum(xk**2, -1)) * (1 + np.sum(xl**2, -1))

        def grad_x(self, xk, xl):
            return 2 * xk * (1 + np.sum(xl**2, -1))[..., None] + 0 * xl

        def grad_y(self, xk, xl):
            return 2 * xl * (1 + np.sum(xk**2, -1))[..., None] + 0 * xk

    model = SwarmModel(SwarmParams(n_agents=100, kernel=Product(), sigma=0.0))
    x = np.random.default_rng(0).uniform(-1, 1, (1, 100, 1))
    _, lin = model.drift_and_linearization(0.0, x, None, "exact")
    assert not lin.symmetric
    dw = np.zeros_like(x)
    auto = make_integrator("erb", jacobian="exact").step(model, x, None, 0.0, 0.05, dw)
    dense = make_integrator("erb", jacobian="exact", phi_method="expm").step(
        model, x, None, 0.0, 0.05, dw
    )
    np.testing.assert_allclose(auto, dense, rtol=1e-9, atol=1e-12)
    with pytest.raises(ValueError, match="phi_method"):
        simulate(
            SwarmParams(n_agents=5, kernel="nonsymmetric"), "serb", phi_method="eigh", n_steps=2
        )


def test_registry_and_metadata():
    assert set(INTEGRATORS) == {"em", "ee", "heun", "erb", "serb"}
    for name, cls in INTEGRATORS.items():
        assert cls.name == name
        assert cls.needs_jacobian is (name in ("erb", "serb"))
    assert make_integrator("heun").deterministic_order == 2.0
    assert make_integrator("erb", jacobian="exact").deterministic_order == 2.0
    assert make_integrator("serb", jacobian="frozen").deterministic_order == 1.0
    with pytest.raises(ValueError, match="integrator must be one of"):
        make_integrator("rk4")
    with pytest.raises(ValueError, match="jacobian"):
        make_integrator("serb", jacobian="approx")


class _TimeDrift:
    """x' = t (+ u): the drift depends on t only, linearization 0."""

    sigma = 0.0

    def drift(self, t, x, u=None):
        return np.full_like(x, t) if u is None else np.full_like(x, t) + u

    def drift_and_linearization(self, t, x, u, kind):
        from agent_envs.dynamics.swarm import Linearization

        zero = np.zeros((*x.shape[:-2], x.shape[-2], x.shape[-2]))
        return self.drift(t, x, u), Linearization(zero, True, True)


@pytest.mark.parametrize(
    "name, expected",
    [("em", 0.3 * 0.1), ("heun", 0.1 * (0.3 + 0.4) / 2), ("erb", 0.3 * 0.1), ("serb", 0.03)],
)
def test_integrators_pass_the_time_to_the_drift(name, expected):
    # x' = t from t = 0.3 over dt = 0.1: EM/ERB/SERB use F(t_n); Heun averages F(t_n), F(t_n + dt).
    x = np.zeros((1, 3, 1))
    x1 = make_integrator(name).step(_TimeDrift(), x, None, 0.3, 0.1, np.zeros_like(x))
    np.testing.assert_allclose(x1, expected, rtol=1e-14)
