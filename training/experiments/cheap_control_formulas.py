"""The closed forms of `agent-envs reproduce cheap-control-bound` (docs/cheap-control-bound.md).

Pure functions of numbers and arrays, no solver and no randomness: phi1(z) = (e^z - 1) / z; the
noise floor F(T) = T Var(c^0) + d sigma^2 tau^2 m (m - 1) / (2N) (`noise_floor`) and its
sample-average twin F_K (`sample_floor`, from positions of shape (m + 1, K, N, d)); the lemma's
right side C_0 E alpha(||x^0 - x~||) (`paper_rhs`); a lower bound mu of the Fiedler value of
-L(x) for a swarm of diameter D (`fiedler_bound`); the corrected upper bound U(T) of the centre
control (`centre_gain`, `noise_term`, `disagreement_sums`, `corrected_upper_bound`) and that
control itself (`centre_control`); both sides of `thm:turnpike_stochastic` (`theorem_terms`,
lambda = `LAMBDA`); the horizons where the floor crosses a bound (`crossing_horizon`,
`crossings`); log-log exponents (`fit_exponent`). The notation is the one of
`cheap_control_bound`'s docstring.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

#: lambda of thm:turnpike_stochastic (the fraction of the horizon whose sum is bounded)
LAMBDA = 0.5


# ------------------------------------------------------------------------------ the formulas


def phi1(z: float) -> float:
    """phi1(z) = (e^z - 1) / z, phi1(0) = 1."""
    return 1.0 if z == 0.0 else math.expm1(z) / z


def noise_floor(sigma: float, dt: float, m: int, n_agents: int, dim: int, var_c0: float = 0.0):
    """F(T) = T Var(c^0) + d sigma^2 tau^2 m (m - 1) / (2N), T = m tau: V(T) >= F(T)."""
    return m * dt * var_c0 + dim * sigma**2 * dt**2 * m * (m - 1) / (2.0 * n_agents)


def sample_floor(positions: np.ndarray, dt: float) -> float:
    """F_K = tau sum_{n<m} (1/K) sum_j |c^{n,j} - mean_j c^{n,j}|^2 from positions (m+1, K, N, d).

    c^{n,j} is path j's centre; for every deterministic control and the symmetric kernel the
    sample-average cost of the same K paths is >= F_K (module docstring).
    """
    centre = np.asarray(positions, dtype=float).mean(axis=2)  # (m+1, K, d)
    spread = np.sum((centre - centre.mean(axis=1, keepdims=True)) ** 2, axis=-1).mean(axis=1)
    return float(dt * np.sum(spread[:-1]))


def paper_rhs(c0: float, gamma: float, sq_dist0: float, n_agents: int) -> float:
    """The lemma's right side C_0 E alpha(||x^0 - x~||) = C_0 gamma / (2N) E||x^0 - x~||^2."""
    return c0 * gamma / (2.0 * n_agents) * sq_dist0


def fiedler_bound(epsilon: float, alpha: float, diameter: float) -> float:
    """mu = 1 / (eps (alpha^2 + D^2)) <= lambda_2(-L(x)) when every |x_k - x_l| <= D.

    -L(x) is the Laplacian of the complete graph with weights p(x_k, x_l) / N >= p_min / N, whose
    second eigenvalue is >= N p_min / N = p_min (Laplacians are monotone in the weights).
    """
    return 1.0 / (epsilon * (alpha**2 + diameter**2))


def disagreement_sums(m: int, dt: float, mu: float) -> tuple[float, float]:
    """(tau sum_{n<m} rho^n, tau^2 sum_{n<m} sum_{j=1..n} rho^j), rho = e^{-2 mu tau}.

    With mu = 0: (T, tau^2 m (m - 1) / 2). They multiply Y_0 and (N - 1) d sigma^2 in U(T).
    """
    rho = math.exp(-2.0 * mu * dt)
    if rho == 1.0:
        return m * dt, dt**2 * m * (m - 1) / 2.0
    n = np.arange(m)
    geometric = rho**n  # (m,)
    inner = rho * (1.0 - geometric) / (1.0 - rho)  # sum_{j=1..n} rho^j
    return float(dt * np.sum(geometric)), float(dt**2 * np.sum(inner))


@dataclass(frozen=True)
class StartStatistics:
    """What the bounds need of the (possibly random) initial state x^0 (module docstring).

    centre_bias2 = |E c^0 - xbar|^2, var_c0 = Var(c^0), y0 = E||y^0||^2, sq_dist0 =
    E||x^0 - x~||^2 (= N centre_bias2 + N var_c0 + y0), diameter = the largest |x_k - x_l|.
    """

    centre_bias2: float
    var_c0: float
    y0: float
    sq_dist0: float
    diameter: float

    @classmethod
    def of(cls, x0: np.ndarray, target: np.ndarray) -> StartStatistics:
        """From realizations x0 of shape (R, N, d) (R = 1 for a deterministic start)."""
        x = np.asarray(x0, dtype=float)
        centre = x.mean(axis=1)  # (R, d)
        y = x - centre[:, None, :]
        diffs = x[:, :, None, :] - x[:, None, :, :]
        return cls(
            centre_bias2=float(np.sum((centre.mean(axis=0) - target) ** 2)),
            var_c0=float(np.mean(np.sum((centre - centre.mean(axis=0)) ** 2, axis=-1))),
            y0=float(np.mean(np.sum(y**2, axis=(-2, -1)))),
            sq_dist0=float(np.mean(np.sum((x - target) ** 2, axis=(-2, -1)))),
            diameter=float(np.sqrt(np.max(np.sum(diffs**2, axis=-1)))),
        )


def centre_gain(beta: float, dt: float, gamma: float) -> float:
    """K_beta = tau (1 + gamma beta^2 phi1(-beta tau)^2) / (1 - e^{-2 beta tau})."""
    return dt * (1.0 + gamma * (beta * phi1(-beta * dt)) ** 2) / (-math.expm1(-2.0 * beta * dt))


def noise_term(sigma: float, dt: float, m: int, n_agents: int, dim: int, mu: float) -> float:
    """noise_mu(T) = d sigma^2 [tau^2 m (m-1) / (2N) + (N-1)/N tau^2 sum_n sum_{j<=n} rho^j]."""
    _, inner = disagreement_sums(m, dt, mu)
    return noise_floor(sigma, dt, m, n_agents, dim) + (n_agents - 1) * dim * sigma**2 * inner / (
        n_agents
    )


def corrected_upper_bound(
    start: StartStatistics,
    *,
    sigma: float,
    dt: float,
    m: int,
    n_agents: int,
    dim: int,
    gamma: float,
    beta: float,
    mu: float,
) -> float:
    """U(T) of the module docstring: E[cost of the centre control] <= U(T), hence V(T) <= U(T)."""
    geometric, _ = disagreement_sums(m, dt, mu)
    centre = centre_gain(beta, dt, gamma) * -math.expm1(-2.0 * beta * m * dt) * start.centre_bias2
    return (
        centre
        + m * dt * start.var_c0
        + geometric * start.y0 / n_agents
        + noise_term(sigma, dt, m, n_agents, dim, mu)
    )


def centre_control(
    mean_centre0: np.ndarray, target: np.ndarray, beta: float, dt: float, m: int, n_agents: int
) -> np.ndarray:
    """u_k^n = v^n = beta phi1(-beta tau) e^{-beta n tau} (xbar - E c^0): shape (m, N, d).

    Under SERB with the frozen L (L 1 = 0, so phi1(tau L) 1 = 1) it moves the centre by tau v^n
    and leaves the disagreement to the interaction: E c^{n+1} - xbar = e^{-beta tau}
    (E c^n - xbar), the proof's `eq:expint_mean` for the centre.
    """
    gain = beta * phi1(-beta * dt)
    decay = np.exp(-beta * dt * np.arange(m))[:, None, None]
    v = gain * decay * (np.asarray(target, float) - np.asarray(mean_centre0, float))
    return np.broadcast_to(v, (m, n_agents, v.shape[-1])).copy()


def theorem_terms(
    start: StartStatistics, *, c0: float, sigma: float, dt: float, m: int, n_agents: int,
    dim: int, gamma: float, beta: float, mu: float, lam: float = LAMBDA,
) -> dict[str, float]:  # fmt: skip
    """The right sides of thm:turnpike_stochastic: the paper's and the corrected one (docs).

    paper: C_0^2 / (tau s) E alpha_0, s = floor((1 - lambda) m).
    corrected: (2 A / gamma) B / (tau s) + T Var(c^0) + d sigma^2 T^2 / (4N) + noise_mu(T),
    B = (2 A / gamma) E alpha_0 + T Var(c^0) + noise_mu(T), A = max(K_beta, N tau sum rho^n / N)
    = max(K_beta, tau sum_{n<m} rho^n); lower: (gamma / 2) sum_{n>=s} tau (Var(c^0) +
    d sigma^2 t_n / N), a lower bound of the left side for every deterministic control.
    """
    s = max(math.floor((1.0 - lam) * m), 1)
    horizon = m * dt
    alpha0 = gamma / (2.0 * n_agents) * start.sq_dist0
    geometric, _ = disagreement_sums(m, dt, mu)
    a = max(centre_gain(beta, dt, gamma), geometric)
    noise = noise_term(sigma, dt, m, n_agents, dim, mu)
    b = 2.0 * a / gamma * alpha0 + horizon * start.var_c0 + noise
    corrected = (
        2.0 * a / gamma * b / (dt * s)
        + horizon * start.var_c0
        + dim * sigma**2 * horizon**2 / (4.0 * n_agents)
        + noise
    )
    n = np.arange(s, m)
    lower = gamma / 2.0 * float(np.sum(dt * (start.var_c0 + dim * sigma**2 * n * dt / n_agents)))
    return {
        "thm_rhs_paper": c0**2 / (dt * s) * alpha0,
        "thm_rhs_corrected": corrected,
        "thm_lhs_lower": lower,
    }


def crossing_horizon(gap: Callable[[int], float], limit: int = 10**12) -> float:
    """tau-free helper: the smallest m >= 1 with gap(m) > 0 (gap non-decreasing), or inf."""
    if gap(1) > 0:
        return 1
    high = 2
    while gap(high) <= 0:
        high *= 2
        if high > limit:
            return math.inf
    low = high // 2
    while high - low > 1:
        mid = (low + high) // 2
        if gap(mid) > 0:
            high = mid
        else:
            low = mid
    return high


def crossings(
    start: StartStatistics, *, c0: float, sigma: float, dt: float, n_agents: int, dim: int,
    gamma: float, lam: float = LAMBDA,
) -> tuple[float, float]:  # fmt: skip
    """(T_cross_lemma, T_cross_theorem): the smallest T = m tau at which the floor F(T) exceeds
    the lemma's right side, and the lower bound of the theorem's left side exceeds its right side
    (inf if never: sigma = 0 and Var(c^0) = 0)."""
    rhs = paper_rhs(c0, gamma, start.sq_dist0, n_agents)
    alpha0 = gamma / (2.0 * n_agents) * start.sq_dist0

    def lemma_gap(m: int) -> float:
        return noise_floor(sigma, dt, m, n_agents, dim, start.var_c0) - rhs

    def theorem_gap(m: int) -> float:
        s = max(math.floor((1.0 - lam) * m), 1)
        # sum_{n=s}^{m-1} n in closed form
        total_n = (m - 1) * m / 2.0 - (s - 1) * s / 2.0
        noise = dim * sigma**2 * dt * total_n / n_agents
        lower = gamma / 2.0 * dt * ((m - s) * start.var_c0 + noise)
        return lower - c0**2 / (dt * s) * alpha0

    return crossing_horizon(lemma_gap) * dt, crossing_horizon(theorem_gap) * dt


def fit_exponent(x: Any, y: Any) -> float:
    """The least-squares slope of log y against log x (positive entries only; NaN if < 2)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    keep = (x > 0) & (y > 0) & np.isfinite(y)
    if np.count_nonzero(keep) < 2:
        return float("nan")
    return float(np.polyfit(np.log(x[keep]), np.log(y[keep]), 1)[0])
