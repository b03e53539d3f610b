"""`agent-envs reproduce cheap-control-bound`: Lemma `lem:cheap` measured, and a corrected bound.

Paper: Cassini & Segala, "The turnpike control in stochastic multi-agent dynamics: a discrete-time
approach with exponential integrators", arXiv 2503.09549. docs/cheap-control-bound.md has the
derivations; this module computes every quantity of them on the symmetric kernel `eq:symmker`
with SERB (`eq:exp_int_discr`, the frozen linearization L(x) = (P(x) - diag(P(x) 1)) / N).

Notation (all sums over agents k and coordinates; E = expectation, estimated by path means):
c = (1/N) sum_k x_k the swarm's centre, y = x - c 1 the disagreement, Var(c^0) = E|c^0 - E c^0|^2,
Y_0 = E||y^0||^2, alpha(r) = gamma / (2N) r^2 (`lem:diss`), C_0 the paper's constant of the proof
of `lem:cheap`, m = T / tau, d the dimension.

- The lemma claims V(T) <= C_0 E alpha(||x^0 - x~||) for all x^0 and T.
- Noise floor (any deterministic control, any scheme with 1^T J_n = 0, e.g. SERB, EM):
  V(T) >= F(T) = T Var(c^0) + d sigma^2 tau^2 m (m - 1) / (2N): the interaction does not move c,
  a deterministic control moves it by a deterministic amount, so Var(c^n) = Var(c^0) +
  d sigma^2 t_n / N, and (1/N) ||x - x~||^2 >= |c - xbar|^2. On the K sampled paths of the
  solver the same argument gives the exact floor of the sample-average problem,
  F_K = tau sum_n (1/K) sum_j |c^{n,j} - mean_j c^{n,j}|^2 <= V_K (`sample_floor`).
- Corrected upper bound (the cost of the centre control u_k^n = v^n = beta phi1(-beta tau)
  (xbar - E c^n), the same for every agent, under SERB; `corrected_upper_bound`):
  V(T) <= U(T) = K_beta (1 - e^{-2 beta T}) |E c^0 - xbar|^2 + F(T)
                 + (tau / N) sum_{n<m} [rho^n Y_0 + (N - 1) d sigma^2 tau sum_{j=1..n} rho^j],
  K_beta = tau (1 + gamma beta^2 phi1(-beta tau)^2) / (1 - e^{-2 beta tau}), rho = e^{-2 mu tau},
  mu a lower bound of the Fiedler value of -L(x^n) along the paths: mu = 1 / (eps (alpha^2 +
  D^2)) while the swarm's diameter is <= D. For sigma = 0 the diameter does not grow (D =
  diam x^0, rigorous); for sigma > 0 mu = 0 is the assumption-free bound (`upper`) and `upper_a4`
  uses D = the largest diameter seen on the evaluation paths (assumption A4 of the docs).

Parts of the run (one table, `cheap_control_bound.csv` / `.md`, one figure):

1. `V(T)`: x^0 uniform on [-1, 1] (seed), sigma in {0, --sigma}, T in --horizons: the optimum V_K
   of the sample-average problem (K = --n-paths, `solve_optimal_control`), its control's cost on
   --eval-paths fresh paths (`V_fresh`, with its standard error), F, F_K, the removable part
   V_fresh - F, the lemma's right side, U, and both sides of `thm:turnpike_stochastic` as the
   paper states it and as corrected (docs), with lambda = 1/2.
2. `x0=xbar`: the same at x^0 = xbar (every agent at the target) with sigma > 0: the lemma's
   right side is 0, V >= F > 0 for m >= 2.
3. `random x0`: sigma = 0, x^0 iid uniform on [-1, 1] per realization (--eval-paths of them):
   V >= T Var(c^0) against the lemma's bound; V's upper bracket is the centre control's cost.
4. `N-scaling`: the noise part V_fresh(sigma) - V(sigma = 0) at T = --scaling-horizon for N in
   --scaling-agents, against F (~ 1/N).
5. `eps-scaling`: C_0 and V(sigma = 0) at T = 1 for eps in --scaling-epsilons (C_0 ~ 1/eps^2).

Beside the table, `contraction.csv` / `.md`: the Lyapunov function L^n = ||E x^n - x~||^2 of the
proof under four controls (SERB): the paper's cheap control `eq:cheap_ctr` held over each step
with the frozen and with the exact Jacobian (what `eq:exp_int_discr` does with it), the closed
loop of Section 5.2 (`CheapClosedLoopModel`: the mean ODE `eq:dyn_mean` integrated by ERB, i.e.
`eq:expint_mean`), and the centre control; the per-step factor L^{n+1} / L^n against the proof's
e^{-2 beta tau}, split into the centre part N |E c - xbar|^2 and the disagreement part ||E y||^2.

The horizons beyond which the floor alone exceeds the lemma's (the theorem's) right side,
`T_cross_lemma` (`T_cross_theorem`), are computed in closed form per row: past them the paper's
statement is false whatever the optimum does.
"""

from __future__ import annotations

import csv
import json
import math
import time
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from agent_envs.baselines import DEFAULT_BETA
from agent_envs.training.config import option_field
from agent_envs.training.experiments import SolverOptions, check_sizes
from agent_envs.training.experiments.turnpike_property import cheap_constant, kernel_bound
from agent_envs.validation import (
    EPSILON_RANGE,
    HORIZON_RANGE,
    MAX_BATCH_SIZE,
    MAX_SEED,
    SIGMA_RANGE,
    check_int,
    check_positive,
    check_real,
)

HORIZONS = (0.5, 1.0, 2.0, 4.0, 8.0)
SCALING_AGENTS = (5, 10, 20, 40)
SCALING_EPSILONS = (0.05, 0.1, 0.2, 0.5, 1.0)
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


# ------------------------------------------------------------------------------ the config


@dataclass(frozen=True, kw_only=True)
class CheapControlBoundConfig(SolverOptions):
    """Sizes and settings of the run (module docstring): the options of `agent-envs reproduce
    cheap-control-bound`; validated on construction."""

    out: Path = option_field(Path("reproduction_cheap_control_bound"), "output folder")
    n_agents: int = option_field(10, "N of the V(T), x0=xbar, random-x0 and eps rows (paper: 100)")
    n_paths: int = option_field(10, "K: Brownian paths of the sample-average solves (paper: 20)")
    eval_paths: int = option_field(200, "fresh paths (and x^0 draws) each control is evaluated on")
    tau: float = option_field(0.05, "time step (paper: 0.02); it must divide every horizon")
    horizons: tuple[float, ...] = option_field(HORIZONS, "horizons T of the V(T) rows")
    sigma: float = option_field(0.1, "noise level of the sigma > 0 rows (paper: 0.01)")
    epsilon: float = option_field(0.05, "stiffness eps of the symmetric kernel (paper: 0.05)")
    beta: float = option_field(DEFAULT_BETA, "beta of the cheap control and of C_0 (paper: 12)")
    scaling_agents: tuple[int, ...] = option_field(
        SCALING_AGENTS, "N of the noise-floor scaling rows"
    )
    scaling_horizon: float = option_field(
        2.0, "T of the N-scaling rows and of the contraction check"
    )
    scaling_epsilons: tuple[float, ...] = option_field(
        SCALING_EPSILONS, "eps of the C_0 scaling rows"
    )
    seed: int = option_field(0, "x^0, the solver's paths and the evaluation paths")

    def __post_init__(self) -> None:
        from agent_envs.validation import Range

        object.__setattr__(self, "out", Path(self.out))
        for name in ("horizons", "scaling_agents", "scaling_epsilons"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
        check_sizes(self.n_agents, self.n_paths, min_agents=2)
        check_int("--eval-paths", self.eval_paths, 2, 100_000)
        if self.n_agents * self.eval_paths > MAX_BATCH_SIZE:
            raise ValueError(
                f"--n-agents times --eval-paths must be <= {MAX_BATCH_SIZE}, got "
                f"{self.n_agents} x {self.eval_paths}"
            )
        check_positive("--tau", self.tau, HORIZON_RANGE)
        for horizon in self.horizons:
            check_positive("--horizons", horizon, HORIZON_RANGE)
        check_real("--sigma", self.sigma, Range(0.0, SIGMA_RANGE.high, low_open=True))
        check_positive("--epsilon", self.epsilon, EPSILON_RANGE)
        check_positive("--beta", self.beta, Range(0.0, 1e6, low_open=True))
        for n_agents in self.scaling_agents:
            check_int("--scaling-agents", n_agents, 2, 1000)
        check_positive("--scaling-horizon", self.scaling_horizon, HORIZON_RANGE)
        for epsilon in self.scaling_epsilons:
            check_positive("--scaling-epsilons", epsilon, EPSILON_RANGE)
        check_int("--seed", self.seed, 0, MAX_SEED)
        self.check_solver_options()
        if not all((self.horizons, self.scaling_agents, self.scaling_epsilons)):
            raise ValueError(
                "--horizons, --scaling-agents and --scaling-epsilons need a value each"
            )
        for option, horizon in [("--horizons", h) for h in self.horizons] + [
            ("--scaling-horizon", self.scaling_horizon)
        ]:
            steps = horizon / self.tau
            if abs(steps - round(steps)) > 1e-9 or round(steps) < 2:
                raise ValueError(
                    f"--tau must divide {option} into m >= 2 steps; {horizon} / {self.tau} = "
                    f"{steps:g}"
                )


# ------------------------------------------------------------------------------ measurements


def _params(n_agents: int, horizon: float, sigma: float, epsilon: float) -> Any:
    from agent_envs.params import SwarmParams

    return SwarmParams(
        n_agents=n_agents, kernel="symmetric", epsilon=epsilon, sigma=sigma, horizon=horizon
    )


def _rng(config: CheapControlBoundConfig, *key: int) -> np.random.Generator:
    """A generator for one named draw of the run, from --seed (independent across keys)."""
    return np.random.default_rng([config.seed, *key])


def _evaluate(params: Any, m: int, x0: np.ndarray, controls: np.ndarray, n_paths: int, rng):
    """Per-path costs (P,) and positions (m+1, P, N, d) of an open-loop control under SERB."""
    from agent_envs.costs import discrete_cost
    from agent_envs.simulator import simulate

    traj = simulate(
        params, "serb", n_steps=m, n_paths=n_paths, seed=rng, initial_positions=x0,
        control=controls,
    )  # fmt: skip
    dt = params.horizon / m
    costs = discrete_cost(traj.positions, traj.controls, params.target_vector, params.gamma, dt)
    return np.asarray(costs, dtype=float), np.asarray(traj.positions)


def _theorem_lhs(positions, controls, target, gamma: float, dt: float, lam: float = LAMBDA):
    """Per-path sum_{n >= s} tau alpha(||x^n - x~|| + ||u^n||): positions (m+1, P, N, d)."""
    m, n_agents = controls.shape[0], controls.shape[-2]
    s = max(math.floor((1.0 - lam) * m), 1)
    dist = np.sqrt(np.sum((positions[:m] - target) ** 2, axis=(-2, -1)))  # (m, P)
    unorm = np.sqrt(np.sum(controls**2, axis=(-2, -1)))[:, None]  # (m, 1)
    return np.sum(dt * gamma / (2.0 * n_agents) * (dist + unorm)[s:] ** 2, axis=0)


def _mean_se(values: np.ndarray) -> tuple[float, float]:
    values = np.asarray(values, dtype=float)
    se = float(np.std(values, ddof=1) / math.sqrt(values.size)) if values.size > 1 else 0.0
    return float(np.mean(values)), se


def measure(
    case: str,
    config: CheapControlBoundConfig,
    *,
    n_agents: int,
    horizon: float,
    sigma: float,
    epsilon: float,
    x0: np.ndarray,
    warm: np.ndarray | None = None,
) -> tuple[dict, np.ndarray]:
    """One row (the optimum, its fresh-path cost, the floors, the bounds, the theorem's sides)
    from a deterministic x0 (N, d); returns (row, the optimal controls (m, N, d))."""
    params = _params(n_agents, horizon, sigma, epsilon)
    m = round(horizon / config.tau)
    dt = horizon / m
    target, gamma, dim = params.target_vector, params.gamma, params.dim
    noisy = sigma > 0.0
    res = _solve(params, config, m, x0, warm, noisy)
    paths = config.eval_paths if noisy else 1
    key = (m, n_agents, round(1e6 * sigma), round(1e6 * epsilon))
    costs, positions = _evaluate(params, m, x0, res.controls, paths, _rng(config, 1, *key))
    v_fresh, se = _mean_se(costs)
    start = StartStatistics.of(np.asarray(x0, float)[None], target)
    c0 = cheap_constant(dt, gamma, kernel_bound(params), config.beta)
    floor = noise_floor(sigma, dt, m, n_agents, dim, start.var_c0)
    floor_k = sample_floor(res.positions, dt)
    rhs = paper_rhs(c0, gamma, start.sq_dist0, n_agents)
    mu = 0.0 if noisy else fiedler_bound(epsilon, params.alpha, start.diameter)
    cert = centre_control(np.mean(x0, axis=0), target, config.beta, dt, m, n_agents)
    cert_costs, cert_positions = _evaluate(params, m, x0, cert, paths, _rng(config, 2, *key))
    cert_cost, cert_se = _mean_se(cert_costs)
    seen = max(_max_diameter(positions), _max_diameter(cert_positions), start.diameter)
    mu_a4 = fiedler_bound(epsilon, params.alpha, seen)
    sizes = {"sigma": sigma, "dt": dt, "m": m, "n_agents": n_agents, "dim": dim}
    upper = corrected_upper_bound(start, gamma=gamma, beta=config.beta, mu=mu, **sizes)
    upper_a4 = corrected_upper_bound(start, gamma=gamma, beta=config.beta, mu=mu_a4, **sizes)
    theorem = _theorem_columns(start, positions, res.controls, target, c0, gamma, config, mu, sizes)
    tol = 1e-9 * max(res.cost, 1e-300)  # floor_K <= V up to round-off
    row = {
        "case": case,
        "epsilon": epsilon,
        "sigma": sigma,
        "N": n_agents,
        "T": horizon,
        "m": m,
        "V": res.cost,
        "V_fresh": v_fresh,
        "V_fresh_se": se,
        "floor": floor,
        "floor_K": floor_k,
        "removable": v_fresh - floor,
        "noise_part": float("nan"),
        "lemma_rhs": rhs,
        "lemma_holds": bool(v_fresh <= rhs),
        "centre_control_cost": cert_cost,
        "upper": upper,
        "upper_a4": upper_a4,
        "mu": mu,
        "mu_a4": mu_a4,
        "corrected_holds": bool(
            floor_k <= res.cost + tol
            and floor <= v_fresh + 3.0 * se
            and v_fresh - 3.0 * se <= upper
            and cert_cost - 3.0 * cert_se <= upper
        ),
        **theorem,
        "C0": c0,
        "converged": res.converged,
        "seconds": res.wall_time,
    }
    if config.progress:
        print(
            f"  {case:12s} eps={epsilon:<5g} sigma={sigma:<5g} N={n_agents:<3d} T={horizon:<4g} "
            f"V={res.cost:.5g} V_fresh={v_fresh:.5g} floor={floor:.3g} upper={upper:.3g} "
            f"lemma={rhs:.3g} conv={res.converged} ({res.wall_time:.1f} s)",
            flush=True,
        )
    return row, res.controls


def _theorem_columns(start, positions, controls, target, c0, gamma, config, mu, sizes) -> dict:
    """The theorem's columns of a row: its left side on fresh paths (with its standard error),
    the paper's and the corrected right sides, whether each holds, and the horizons past which
    the floor crosses the lemma's and the theorem's bounds."""
    dt, n_agents, dim, sigma = sizes["dt"], sizes["n_agents"], sizes["dim"], sizes["sigma"]
    lhs, lhs_se = _mean_se(_theorem_lhs(positions, controls, target, gamma, dt))
    thm = theorem_terms(start, c0=c0, gamma=gamma, beta=config.beta, mu=mu, **sizes)
    cross_lemma, cross_theorem = crossings(
        start, c0=c0, sigma=sigma, dt=dt, n_agents=n_agents, dim=dim, gamma=gamma
    )
    return {
        "thm_lhs": lhs,
        "thm_lhs_lower": thm["thm_lhs_lower"],
        "thm_rhs_paper": thm["thm_rhs_paper"],
        "thm_rhs_corrected": thm["thm_rhs_corrected"],
        "theorem_holds": bool(lhs <= thm["thm_rhs_paper"]),
        "corrected_theorem_holds": bool(
            thm["thm_lhs_lower"] <= lhs + 3.0 * lhs_se and lhs <= thm["thm_rhs_corrected"]
        ),
        "T_cross_lemma": cross_lemma,
        "T_cross_theorem": cross_theorem,
    }


def _solve(params, config: CheapControlBoundConfig, m: int, x0, warm, noisy: bool):
    """The optimal solve of one row (K solver paths with noise, one without), its
    non-convergence reported in the row's `converged` column rather than warned."""
    from agent_envs.baselines.optimal_control import solve_optimal_control

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return solve_optimal_control(
            params, "serb", n_steps=m, n_paths=config.n_paths if noisy else 1, seed=config.seed,
            initial_positions=x0, max_control=config.max_control, initial_controls=warm,
            gtol=config.gtol, max_iterations=config.max_iterations,
        )  # fmt: skip


def _max_diameter(positions: np.ndarray) -> float:
    """The largest |x_k - x_l| over all steps and paths of positions (..., N, d)."""
    x = np.asarray(positions, dtype=float)
    spread = np.max(x, axis=-2) - np.min(x, axis=-2)  # (..., d): exact for d = 1
    if x.shape[-1] == 1:
        return float(np.nanmax(spread))
    diffs = x[..., :, None, :] - x[..., None, :, :]
    return float(np.sqrt(np.nanmax(np.sum(diffs**2, axis=-1))))


def _centre_control_costs(params, config: CheapControlBoundConfig, x0s, m_max: int):
    """Cumulative costs dt sum_{n < k} c(x^n, u^n), k = 1..m_max, of the centre control from
    each noise-free start of `x0s` (R, N, d) under SERB (frozen): shape (m_max, R)."""
    from agent_envs.costs import running_cost
    from agent_envs.dynamics.swarm import SwarmModel
    from agent_envs.integrators import make_integrator

    target, dt = params.target_vector, config.tau
    cert = centre_control(np.zeros(params.dim) + x0s.mean(axis=(0, 1)), target, config.beta,
                          dt, m_max, params.n_agents)  # fmt: skip
    model, scheme = SwarmModel(params), make_integrator("serb", jacobian="frozen")
    x, zeros = x0s.copy(), np.zeros_like(x0s)
    step_costs = []
    for n in range(m_max):
        u = np.broadcast_to(cert[n], x.shape)
        step_costs.append(running_cost(x, u, target, params.gamma))  # (R,)
        x = scheme.step(model, x, u, n * dt, dt, zeros)
    return dt * np.cumsum(np.stack(step_costs), axis=0)


def random_start_rows(config: CheapControlBoundConfig) -> list[dict]:
    """Part 3: sigma = 0, x^0 iid uniform on [-1, 1] per realization, every T in --horizons.

    The R = --eval-paths realizations are integrated together (they are independent
    deterministic runs) under the centre control, whose cost bounds V from above; T Var(c^0)
    bounds it from below (module docstring). The centre control does not depend on T, so one run
    over the longest horizon gives every T (prefix sums).
    """
    from agent_envs.simulator import uniform_positions

    n_agents, longest = config.n_agents, max(config.horizons)
    params = _params(n_agents, longest, 0.0, config.epsilon)
    target, gamma, dim = params.target_vector, params.gamma, params.dim
    rng = _rng(config, 3)
    x0s = np.stack([uniform_positions(rng, n_agents, dim) for _ in range(config.eval_paths)])
    start = StartStatistics.of(x0s, target)
    dt = config.tau
    cumulative = _centre_control_costs(params, config, x0s, round(longest / dt))  # (m_max, R)
    c0 = cheap_constant(dt, gamma, kernel_bound(params), config.beta)
    rhs = paper_rhs(c0, gamma, start.sq_dist0, n_agents)
    mu = fiedler_bound(config.epsilon, params.alpha, start.diameter)
    cross_lemma, cross_theorem = crossings(
        start, c0=c0, sigma=0.0, dt=dt, n_agents=n_agents, dim=dim, gamma=gamma
    )
    rows = []
    for horizon in config.horizons:
        m = round(horizon / dt)
        cert_cost, cert_se = _mean_se(cumulative[m - 1])
        floor = noise_floor(0.0, dt, m, n_agents, dim, start.var_c0)
        sizes = {"sigma": 0.0, "dt": dt, "m": m, "n_agents": n_agents, "dim": dim}
        upper = corrected_upper_bound(start, gamma=gamma, beta=config.beta, mu=mu, **sizes)
        thm = theorem_terms(start, c0=c0, gamma=gamma, beta=config.beta, mu=mu, **sizes)
        rows.append(
            {
                "case": "random x0",
                "epsilon": config.epsilon,
                "sigma": 0.0,
                "N": n_agents,
                "T": horizon,
                "m": m,
                "V": float("nan"),
                "V_fresh": float("nan"),
                "V_fresh_se": float("nan"),
                "floor": floor,
                "floor_K": floor,
                "removable": float("nan"),
                "noise_part": float("nan"),
                "lemma_rhs": rhs,
                # V <= centre_control_cost <= rhs: holds; V >= floor > rhs: fails
                "lemma_holds": bool(floor <= rhs and cert_cost <= rhs),
                "centre_control_cost": cert_cost,
                "upper": upper,
                "upper_a4": upper,
                "mu": mu,
                "mu_a4": mu,
                "corrected_holds": bool(floor <= cert_cost and cert_cost - 3.0 * cert_se <= upper),
                "thm_lhs": float("nan"),
                "thm_lhs_lower": thm["thm_lhs_lower"],
                "thm_rhs_paper": thm["thm_rhs_paper"],
                "thm_rhs_corrected": thm["thm_rhs_corrected"],
                "theorem_holds": bool(thm["thm_lhs_lower"] <= thm["thm_rhs_paper"]),
                "corrected_theorem_holds": bool(thm["thm_lhs_lower"] <= thm["thm_rhs_corrected"]),
                "T_cross_lemma": cross_lemma,
                "T_cross_theorem": cross_theorem,
                "C0": c0,
                "converged": True,
                "seconds": 0.0,
            }
        )
    if config.progress:
        print(
            f"  random x0    Var(c^0)={start.var_c0:.4g} lemma={rhs:.4g} "
            f"T_cross_lemma={cross_lemma:.4g}",
            flush=True,
        )
    return rows


def _contraction_parts(traj, closed, params, dt: float) -> tuple[float, np.ndarray, np.ndarray]:
    """(cost, centre part N |E c^n - xbar|^2, disagreement part ||E y^n||^2) of a trajectory;
    with `closed` (the closed loop, whose feedback is inside the drift) the controls are
    recovered from it for the cost. A diverged run costs NaN."""
    from agent_envs.costs import discrete_cost

    positions = np.asarray(traj.positions)
    controls = np.asarray(traj.controls)
    target, n_agents = params.target_vector, positions.shape[-2]
    if closed is not None:
        controls = np.stack([closed.control(positions[n]) for n in range(controls.shape[0])])
    cost = float(
        np.mean(discrete_cost(positions, controls, target, params.gamma, dt))
    ) if not traj.diverged else float("nan")  # fmt: skip
    mean = positions.mean(axis=1)  # (m+1, N, d)
    centre = n_agents * np.sum((mean.mean(axis=1) - target) ** 2, axis=-1)
    disagreement = np.sum((mean - mean.mean(axis=1, keepdims=True)) ** 2, axis=(-2, -1))
    return cost, centre, disagreement


def contraction_rows(config: CheapControlBoundConfig, x0: np.ndarray) -> list[dict]:
    """L^n = ||E x^n - x~||^2 under four controls (module docstring), sigma in {0, --sigma}.

    Per-step factors L^{n+1} / L^n (medians over the steps with L^n > 1e-14), split into the
    centre part N |E c^n - xbar|^2 and the disagreement part ||E y^n||^2, against the proof's
    e^{-2 beta tau}; the controls' costs against the lemma's right side.
    """
    from agent_envs.baselines.closed_loop import CheapClosedLoopModel
    from agent_envs.baselines.turnpike import cheap_control_from_model
    from agent_envs.dynamics.swarm import SwarmModel
    from agent_envs.simulator import simulate

    rows = []
    n_agents, horizon = x0.shape[0], config.scaling_horizon
    m = round(horizon / config.tau)
    dt = horizon / m
    for sigma in (0.0, config.sigma):
        params = _params(n_agents, horizon, sigma, config.epsilon)
        target, beta = params.target_vector, config.beta
        model = SwarmModel(params)
        paths = config.n_paths if sigma > 0 else 1
        c0 = cheap_constant(dt, params.gamma, kernel_bound(params), beta)
        start = StartStatistics.of(x0[None], target)
        rhs = paper_rhs(c0, params.gamma, start.sq_dist0, n_agents)

        def held(t: float, x: np.ndarray, model=model, target=target, beta=beta) -> np.ndarray:
            return cheap_control_from_model(model, x, target, beta)

        closed = CheapClosedLoopModel(model, target, beta)
        runs = {
            "eq:cheap_ctr held, SERB frozen J": {"control": held},
            "eq:cheap_ctr held, SERB exact J": {"control": held, "jacobian": "exact"},
            "closed loop eq:dyn_mean (Sec. 5.2)": {"model": closed},
            "centre control (ours)": {
                "control": centre_control(x0.mean(axis=0), target, beta, dt, m, n_agents)
            },
        }
        for name, kwargs in runs.items():
            traj = simulate(
                params, "serb", n_steps=m, n_paths=paths, seed=_rng(config, 4, round(1e6 * sigma)),
                initial_positions=x0, divergence_threshold=1e6, **kwargs,
            )  # fmt: skip
            cost, centre, disagreement = _contraction_parts(
                traj, closed if "model" in kwargs else None, params, dt
            )
            lyap = centre + disagreement
            rows.append(
                {
                    "control": name,
                    "sigma": sigma,
                    "N": n_agents,
                    "T": horizon,
                    "m": m,
                    "paper_factor": math.exp(-2.0 * beta * dt),
                    "factor_median": _median_factor(lyap),
                    "centre_factor_median": _median_factor(centre),
                    "disagreement_factor_median": _median_factor(disagreement),
                    "L_T_over_L_0": float(lyap[-1] / lyap[0]),
                    "paper_L_T_over_L_0": math.exp(-2.0 * beta * horizon),
                    "cost": cost,
                    "lemma_rhs": rhs,
                    "diverged": traj.diverged,
                    "lyapunov": lyap,
                    "dt": dt,
                    "beta": beta,
                }
            )
            if config.progress:
                row = rows[-1]
                print(
                    f"  contraction  {name:36s} sigma={sigma:<5g} factor={row['factor_median']:.4f}"
                    f" (paper {row['paper_factor']:.4f}) L_T/L_0={row['L_T_over_L_0']:.3g} "
                    f"cost={cost:.4g}",
                    flush=True,
                )
    return rows


def _short(name: str) -> str:
    """A legend label for a contraction row's control."""
    return name.replace("eq:cheap_ctr held, SERB ", "eq:cheap_ctr held, ").replace(
        "closed loop eq:dyn_mean (Sec. 5.2)", "closed loop (Sec. 5.2)"
    )


def _median_factor(values: np.ndarray) -> float:
    values = np.asarray(values, dtype=float)
    keep = values[:-1] > 1e-14
    if not np.any(keep):
        return float("nan")
    return float(np.median(values[1:][keep] / values[:-1][keep]))


# ------------------------------------------------------------------------------ outputs

COLUMNS = (
    "case", "epsilon", "sigma", "N", "T", "m", "V", "V_fresh", "V_fresh_se", "floor", "floor_K",
    "removable", "noise_part", "lemma_rhs", "lemma_holds", "centre_control_cost", "upper",
    "upper_a4", "mu", "mu_a4", "corrected_holds", "thm_lhs", "thm_lhs_lower", "thm_rhs_paper",
    "thm_rhs_corrected", "theorem_holds", "corrected_theorem_holds", "T_cross_lemma",
    "T_cross_theorem", "C0", "converged", "seconds",
)  # fmt: skip
#: the columns of the printed / markdown summary table (the CSV has all of COLUMNS)
SUMMARY = (
    "case", "epsilon", "sigma", "N", "T", "V", "V_fresh", "floor", "removable", "noise_part",
    "lemma_rhs", "lemma_holds", "upper", "corrected_holds", "thm_lhs", "thm_rhs_paper",
    "thm_rhs_corrected", "corrected_theorem_holds", "T_cross_lemma",
)  # fmt: skip
CONTRACTION_COLUMNS = (
    "control", "sigma", "N", "T", "m", "paper_factor", "factor_median", "centre_factor_median",
    "disagreement_factor_median", "L_T_over_L_0", "paper_L_T_over_L_0", "cost", "lemma_rhs",
    "diverged",
)  # fmt: skip


def _fmt(value: Any) -> str:
    if isinstance(value, bool):
        return "yes" if value else "NO"
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def markdown(rows: list[dict], columns: tuple[str, ...]) -> str:
    """A markdown table of `columns` of `rows`."""
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(_fmt(row[c]) for c in columns) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def _write_csv(rows: list[dict], columns: tuple[str, ...], path: Path) -> None:
    with open(path, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(columns)
        for row in rows:
            writer.writerow([row[c] for c in columns])


def exponents(rows: list[dict], sigma: float) -> dict[str, float]:
    """Fitted log-log slopes: V, its noise part, the floor and the removable part against T;
    the noise part and the floor against N; C_0 and the lemma's bound over V against eps."""
    noisy = [r for r in rows if r["case"] == "V(T)" and r["sigma"] == sigma]
    calm = [r for r in rows if r["case"] == "V(T)" and r["sigma"] == 0.0]
    scaling = [r for r in rows if r["case"] == "N-scaling"]
    eps = [r for r in rows if r["case"] == "eps-scaling"]

    def fit(sel: list[dict], x: str, y: str) -> float:
        return fit_exponent([r[x] for r in sel], [r[y] for r in sel])

    return {
        "V_fresh vs T (sigma > 0)": fit(noisy, "T", "V_fresh"),
        "V vs T (sigma = 0)": fit(calm, "T", "V"),
        "noise part vs T": fit(noisy, "T", "noise_part"),
        "floor vs T": fit(noisy, "T", "floor"),
        "removable part vs T (sigma > 0)": fit(noisy, "T", "removable"),
        "noise part vs N": fit(scaling, "N", "noise_part"),
        "floor vs N": fit(scaling, "N", "floor"),
        "C0 vs eps": fit(eps, "epsilon", "C0"),
        "lemma_rhs / V vs eps": fit_exponent(
            [r["epsilon"] for r in eps], [r["lemma_rhs"] / r["V"] for r in eps]
        ),
    }


def plot(rows: list[dict], contraction: list[dict], sigma: float, path: Path) -> None:
    """Six panels: V(T) with floor / bounds; x^0 = xbar; random x^0; N; eps; L^n factors."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(15, 8))  # no pyplot: no backend switch
    axes = fig.subplots(2, 3).ravel()

    def sel(case: str, sig: float | None = None) -> list[dict]:
        return [r for r in rows if r["case"] == case and (sig is None or r["sigma"] == sig)]

    ax = axes[0]
    noisy, calm = sel("V(T)", sigma), sel("V(T)", 0.0)
    t = [r["T"] for r in noisy]
    ax.loglog(t, [r["V_fresh"] for r in noisy], "o-", label=f"V (sigma={sigma:g}, fresh paths)")
    ax.loglog(t, [r["V"] for r in calm], "s-", label="V (sigma=0)")
    ax.loglog(t, [r["noise_part"] for r in noisy], "^-", label="noise part V(sigma) - V(0)")
    ax.loglog(t, [r["floor"] for r in noisy], "k--", label="floor F(T)")
    ax.loglog(t, [r["upper"] for r in noisy], "r:", label="corrected upper U(T)")
    ax.loglog(t, [r["lemma_rhs"] for r in noisy], "m-.", label="lemma: C0 E alpha(|x0 - x~|)")
    ax.set_title("V(T), symmetric kernel", fontsize=9)
    ax.set_xlabel("T")
    ax.legend(fontsize=6, loc="center right")

    ax = axes[1]
    start = sel("x0=xbar")
    t = [r["T"] for r in start]
    ax.loglog(t, [r["V_fresh"] for r in start], "o-", label="V (fresh paths)")
    ax.loglog(t, [r["V"] for r in start], "s-", label="V_K (solver's paths)")
    ax.loglog(t, [r["floor"] for r in start], "k--", label="floor F(T)")
    ax.loglog(t, [r["upper"] for r in start], "r:", label="corrected upper U(T)")
    ax.set_title("x0 = xbar, sigma > 0: the lemma's right side is 0", fontsize=9)
    ax.set_xlabel("T")
    ax.legend(fontsize=6)

    ax = axes[2]
    rand = sel("random x0")
    t = [r["T"] for r in rand]
    ax.loglog(t, [r["floor"] for r in rand], "k--", label="floor T Var(c0) <= V")
    ax.loglog(t, [r["centre_control_cost"] for r in rand], "o-", label="centre control >= V")
    ax.loglog(t, [r["lemma_rhs"] for r in rand], "m-.", label="lemma's bound")
    cross = rand[0]["T_cross_lemma"] if rand else float("nan")
    ax.set_title(f"sigma = 0, random x0: lemma fails beyond T = {cross:.3g}", fontsize=9)
    ax.set_xlabel("T")
    ax.legend(fontsize=6)

    ax = axes[3]
    scaling = sel("N-scaling")
    n = [r["N"] for r in scaling]
    ax.loglog(n, [r["noise_part"] for r in scaling], "o-", label="noise part V(sigma) - V(0)")
    ax.loglog(n, [r["floor"] for r in scaling], "k--", label="floor d sigma^2 tau^2 m(m-1)/(2N)")
    ax.set_title(f"noise part against N (T = {scaling[0]['T'] if scaling else ''})", fontsize=9)
    ax.set_xlabel("N")
    ax.legend(fontsize=6)

    ax = axes[4]
    eps = sel("eps-scaling")
    e = [r["epsilon"] for r in eps]
    ax.loglog(e, [r["C0"] for r in eps], "o-", label="C0")
    ax.loglog(e, [r["lemma_rhs"] / r["V"] for r in eps], "s-", label="lemma bound / V")
    ax.set_title("C0 against eps (sigma = 0)", fontsize=9)
    ax.set_xlabel("eps")
    ax.legend(fontsize=6)

    ax = axes[5]
    for row in contraction:
        if row["sigma"] == 0.0:
            times = row["dt"] * np.arange(row["lyapunov"].size)
            ax.semilogy(times, row["lyapunov"] / row["lyapunov"][0], label=_short(row["control"]))
    if contraction:
        times = contraction[0]["dt"] * np.arange(contraction[0]["lyapunov"].size)
        ax.semilogy(times, np.exp(-2.0 * contraction[0]["beta"] * times), "k--", lw=0.8,
                    label="proof: e^{-2 beta t}")  # fmt: skip
    ax.set_title("L^n / L^0 under SERB, sigma = 0", fontsize=9)
    ax.set_xlabel("t")
    ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def reproduce(out: Path, config: CheapControlBoundConfig) -> tuple[list[dict], list[dict]]:
    """Run every part, write the table, the contraction table, the figure and meta.json."""
    from agent_envs.simulator import uniform_positions

    out.mkdir(parents=True, exist_ok=True)
    began = time.perf_counter()
    n, sigma, eps = config.n_agents, config.sigma, config.epsilon
    x0 = uniform_positions(_rng(config, 0, n), n, 1)
    rows: list[dict] = []
    # 1. V(T), sigma in {0, sigma}, warm-started along T
    by_sigma: dict[float, dict[float, dict]] = {}
    for sig in (0.0, sigma):
        warm = None
        for horizon in config.horizons:
            row, controls = measure(
                "V(T)", config, n_agents=n, horizon=horizon, sigma=sig, epsilon=eps, x0=x0,
                warm=_extend(warm, round(horizon / config.tau)),
            )  # fmt: skip
            warm = controls
            by_sigma.setdefault(sig, {})[horizon] = row
            rows.append(row)
    for horizon, row in by_sigma[sigma].items():
        row["noise_part"] = row["V_fresh"] - by_sigma[0.0][horizon]["V"]
    for row in by_sigma[0.0].values():
        row["noise_part"] = 0.0
    # 2. x0 = xbar with noise
    params = _params(n, 1.0, sigma, eps)
    at_target = np.broadcast_to(params.target_vector, (n, params.dim)).copy()
    for horizon in config.horizons:
        row, _ = measure(
            "x0=xbar", config, n_agents=n, horizon=horizon, sigma=sigma, epsilon=eps,
            x0=at_target,
        )  # fmt: skip
        row["noise_part"] = row["V_fresh"]
        rows.append(row)
    # 3. random x0 without noise
    rows += random_start_rows(config)
    # 4. the noise part against N
    for n_agents in config.scaling_agents:
        start = uniform_positions(_rng(config, 0, n_agents), n_agents, 1)
        common = {"n_agents": n_agents, "horizon": config.scaling_horizon, "epsilon": eps}
        calm, _ = measure("N-scaling (sigma=0)", config, sigma=0.0, x0=start, **common)
        row, _ = measure("N-scaling", config, sigma=sigma, x0=start, **common)
        row["noise_part"] = row["V_fresh"] - calm["V"]
        rows.append(row)
    # 5. C_0 against eps
    for epsilon in config.scaling_epsilons:
        row, _ = measure(
            "eps-scaling", config, n_agents=n, horizon=1.0 if 1.0 in config.horizons else
            config.horizons[0], sigma=0.0, epsilon=epsilon, x0=x0,
        )  # fmt: skip
        row["noise_part"] = 0.0
        rows.append(row)
    contraction = contraction_rows(config, x0)
    fits = exponents(rows, sigma)
    _write_csv(rows, COLUMNS, out / "cheap_control_bound.csv")
    _write_csv(contraction, CONTRACTION_COLUMNS, out / "contraction.csv")
    text = (
        markdown(rows, SUMMARY)
        + "\nFitted log-log exponents:\n\n"
        + "".join(f"- {name}: {value:.3f}\n" for name, value in fits.items())
    )
    (out / "cheap_control_bound.md").write_text(text)
    (out / "contraction.md").write_text(markdown(contraction, CONTRACTION_COLUMNS))
    plot(rows, contraction, sigma, out / "cheap_control_bound.png")
    meta = {**asdict(config), "exponents": fits, "seconds": time.perf_counter() - began}
    del meta["out"]  # the folder it is written into
    (out / "meta.json").write_text(json.dumps(meta, indent=2, default=str))
    return rows, contraction


def _extend(previous: np.ndarray | None, m: int) -> np.ndarray | None:
    """The previous horizon's controls followed by zeros (a warm start of length m)."""
    if previous is None:
        return None
    warm = np.zeros((m, *previous.shape[1:]))
    warm[: min(m, previous.shape[0])] = previous[:m]
    return warm
