"""The measurements of `agent-envs reproduce cheap-control-bound`: one row per solved case.

`measure` solves the sample-average optimal control problem (K = --n-paths paths,
`solve_optimal_control`) for one (N, T, sigma, eps, x^0), evaluates the control on fresh paths
and returns the row of the run's table (V_K, V_fresh and its standard error, F, F_K, the lemma's
and the theorem's sides, U, the crossing horizons); `random_start_rows` measures V against
T Var(c^0) for random starts without noise (the centre control's cost as V's upper bracket);
`contraction_rows` follows the proof's Lyapunov function L^n = ||E x^n - x~||^2 under four
controls, split into its centre and disagreement parts. Every draw comes from generators seeded
by (--seed, the case's key) (`case_rng`).
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np

from agent_envs.training.experiments.cheap_control_config import CheapControlBoundConfig
from agent_envs.training.experiments.cheap_control_formulas import (
    LAMBDA,
    StartStatistics,
    centre_control,
    corrected_upper_bound,
    crossings,
    fiedler_bound,
    noise_floor,
    paper_rhs,
    sample_floor,
    theorem_terms,
)
from agent_envs.training.experiments.turnpike_property import cheap_constant, kernel_bound

# ------------------------------------------------------------------------------ measurements


def case_params(n_agents: int, horizon: float, sigma: float, epsilon: float) -> Any:
    from agent_envs.params import SwarmParams

    return SwarmParams(
        n_agents=n_agents, kernel="symmetric", epsilon=epsilon, sigma=sigma, horizon=horizon
    )


def case_rng(config: CheapControlBoundConfig, *key: int) -> np.random.Generator:
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
    params = case_params(n_agents, horizon, sigma, epsilon)
    m = round(horizon / config.tau)
    dt = horizon / m
    target, gamma, dim = params.target_vector, params.gamma, params.dim
    noisy = sigma > 0.0
    res = _solve(params, config, m, x0, warm, noisy)
    paths = config.eval_paths if noisy else 1
    key = (m, n_agents, round(1e6 * sigma), round(1e6 * epsilon))
    costs, positions = _evaluate(params, m, x0, res.controls, paths, case_rng(config, 1, *key))
    v_fresh, se = _mean_se(costs)
    start = StartStatistics.of(np.asarray(x0, float)[None], target)
    c0 = cheap_constant(dt, gamma, kernel_bound(params), config.beta)
    floor = noise_floor(sigma, dt, m, n_agents, dim, start.var_c0)
    floor_k = sample_floor(res.positions, dt)
    rhs = paper_rhs(c0, gamma, start.sq_dist0, n_agents)
    mu = 0.0 if noisy else fiedler_bound(epsilon, params.alpha, start.diameter)
    cert = centre_control(np.mean(x0, axis=0), target, config.beta, dt, m, n_agents)
    cert_costs, cert_positions = _evaluate(params, m, x0, cert, paths, case_rng(config, 2, *key))
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
    from agent_envs.draws import uniform_positions

    n_agents, longest = config.n_agents, max(config.horizons)
    params = case_params(n_agents, longest, 0.0, config.epsilon)
    target, gamma, dim = params.target_vector, params.gamma, params.dim
    rng = case_rng(config, 3)
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
        params = case_params(n_agents, horizon, sigma, config.epsilon)
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
                params, "serb", n_steps=m, n_paths=paths,
                seed=case_rng(config, 4, round(1e6 * sigma)),
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


def short_name(name: str) -> str:
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
