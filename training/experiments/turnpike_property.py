"""`agent-envs reproduce turnpike-property`: the turnpike theorem measured on optimal solutions.

Theorem `thm:turnpike_stochastic` says that the optimal solution (x*, u*) of the fully discrete
problem `eq:discrete_cost_functional` stays close to the static pair (x~, u~) of
`eq:stationary_solution` (x~_k = xbar, u~_k = 0: consensus at the target, no control) for most
of the horizon: an entry arc, a long stretch near (x~, u~), an exit arc. The paper proves it
but never computes x*; here `solve_optimal_control` does, for horizons T in {0.5, 1, 2, 4, 8}
at one tau (so m = T / tau grows with T), and the run reports, per setting:

- D_n = ||E x*^n - x~||^2 + ||u*^n - u~||^2 (sums over agents; E = mean over the K paths)
  for n = 0..m-1, plotted against t_n on a log scale, one line per T;
- the entry and exit rates: minus the slope of log D_n (least squares in t) from t = 0 to the
  first n with D_n <= delta, and the slope from the last n with D_n <= delta to t_{m-1}; next
  to the entry rate, the rate the swarm's slow mode predicts (`centre_mode_rate`: our own LQ
  analysis of the swarm's centre, not a statement of the paper, which has no rate);
- the share of the horizon with D_n <= delta (delta = 2e-4, the paper's threshold of
  `eq:tptime`, by default), and with delta / 10 and 10 delta (its sensitivity to delta);
- the per-path quantity the theorem is about when there is noise: Dp_n = E||x*^n - x~||^2 +
  ||u*^n - u~||^2 (the mean over the K paths of each path's squared distance, not the squared
  distance of the mean), its minimum and its share within delta. For every deterministic
  control E||x^n - x~||^2 >= d sigma^2 t_n (the centre's random walk, docs/cheap-control-bound.md),
  so Dp stays within delta at most until t = delta / (d sigma^2) (`path_exit_time_bound`);
- V against the cheap-control bound of Lemma `lem:cheap` (`eq:cheap`):
  V <= C0 E[gamma/(2N) ||x^0 - x~||^2], C0 = 2 tau (1 + gamma beta_p) / (gamma (1 - e^{-2 beta
  tau})), beta_p = 2((beta + M_p)^2 + M_p^2), M_p = sup p = max_l w_l / alpha^2 (Assumption
  `ass:bounded`), beta = 12 (the paper's); and the theorem's own inequality with lambda = 1/2:
  E sum_{n >= s} tau alpha(||x^n - x~|| + ||u^n - u~||) <= C1 E alpha(||x^0 - x~||),
  alpha(y) = gamma/(2N) y^2, s = floor((1 - lambda) m), C1 = C0^2 / (tau s).

Settings: the symmetric kernel (`eq:symmker`) with eps = 0.05 (stiff, the paper's) and eps = 1,
and the non-symmetric kernel (`eq:nonsymmker`) with eps_l from eps/5 to 2 eps (eps = 0.05 gives
the paper's [0.01, 0.1]); sigma in {0, 0.01, 0.1}; SERB with the frozen linearization; x^0
uniform on [-1, 1] from the seed (the same for every T); xbar = 0.7, gamma = 0.01, |u| <= 150.

Sizes: N = 20 agents, K = 10 paths (1 for sigma = 0), tau = 0.05 by default, so that the whole
run takes minutes on 2 cores; `--n-agents 100 --n-paths 20 --tau 0.02` is the paper's N, K, tau.
Each T is warm-started from the previous T's solution followed by zeros. `--n-seeds S` repeats
everything for the seeds seed .. seed + S - 1 and `--starts` for several kinds of x^0
(`START_KINDS`); `turnpike_property_seeds.md` then summarizes the rows across them (mean, min
and max of the shares and the entry rate). The figure shows the first seed and start.

Outputs in --out: `turnpike_property.png`, `turnpike_property.csv` / `.md` (one row per seed,
start, setting and T), `turnpike_property_seeds.md`, `curves.npz` (D_n per run) and
`meta.json`. Library use:
`reproduce(out, TurnpikePropertyConfig(...))`; the command line's options are the config's fields.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from agent_envs.baselines import DEFAULT_BETA, DEFAULT_DELTA
from agent_envs.training.config import option_field
from agent_envs.training.experiments import SolverOptions, check_sizes
from agent_envs.validation import (
    EPSILON_RANGE,
    HORIZON_RANGE,
    MAX_SEED,
    SIGMA_RANGE,
    check_int,
    check_positive,
    check_real,
)

#: the paper's decay rate of the cheap control and turnpike threshold (Section 5.2)
BETA = DEFAULT_BETA
DELTA = DEFAULT_DELTA
HORIZONS = (0.5, 1.0, 2.0, 4.0, 8.0)
SIGMAS = (0.0, 0.01, 0.1)
EPSILONS = (0.05, 1.0)
KERNELS = ("symmetric", "nonsymmetric")
#: kinds of initial state: uniform on [-1, 1] (the paper's), two clusters near -1 and +1, and a
#: swarm uniform on [2, 4], whose hull does not contain the target xbar = 0.7
START_KINDS = ("uniform", "bimodal", "far")


def initial_state(kind: str, rng: np.random.Generator, n_agents: int, dim: int = 1) -> np.ndarray:
    """x^0 of shape (N, d) of one of `START_KINDS`, drawn from `rng`."""
    if kind == "uniform":
        return rng.uniform(-1.0, 1.0, size=(n_agents, dim))
    if kind == "bimodal":
        sign = np.where(np.arange(n_agents) % 2 == 0, -1.0, 1.0)[:, None]
        return sign * rng.uniform(0.9, 1.0, size=(n_agents, dim))
    if kind == "far":
        return rng.uniform(2.0, 4.0, size=(n_agents, dim))
    raise ValueError(f"--starts must be among {START_KINDS}, got {kind!r}")


def path_curve(positions: np.ndarray, controls: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Dp_n = mean over paths of ||x^{n,j} - x~||^2, plus ||u^n||^2: (m+1, K, N, d), (m, N, d)."""
    m = controls.shape[0]
    state = np.mean(np.sum((positions[:m] - target) ** 2, axis=(-2, -1)), axis=1)
    return state + np.sum(controls**2, axis=(-2, -1))


@dataclass(frozen=True)
class ArcRates:
    """Fitted exponential rates (per unit time) of D_n, and the time share within delta."""

    entry_rate: float
    exit_rate: float
    share_within_delta: float
    plateau: float


def turnpike_curve(mean_positions: np.ndarray, controls: np.ndarray, target: np.ndarray):
    """D_n = ||E x^n - xbar||^2 + ||u^n||^2 for n = 0..m-1: inputs (m+1, N, d), (m, N, d)."""
    m = controls.shape[0]
    state = np.sum((mean_positions[:m] - target) ** 2, axis=(-2, -1))
    return state + np.sum(controls**2, axis=(-2, -1))


def _slope(times: np.ndarray, values: np.ndarray) -> float:
    if times.size < 2:
        return float("nan")
    logs = np.log(np.maximum(values, np.finfo(float).tiny))
    return float(np.polyfit(times, logs, 1)[0])


def arc_rates(times: np.ndarray, curve: np.ndarray, delta: float) -> ArcRates:
    """Entry/exit rates of log D (module docstring), share of n with D_n <= delta, plateau.

    Without any n within delta, the entry arc runs to the minimum of D and there is no exit arc
    (NaN); the plateau is the median of D within delta (NaN when none).
    """
    inside = np.flatnonzero(curve <= delta)
    if inside.size == 0:
        last = int(np.argmin(curve))
        entry = -_slope(times[: last + 1], curve[: last + 1])
        return ArcRates(entry, float("nan"), 0.0, float("nan"))
    first, last = int(inside[0]), int(inside[-1])
    entry = -_slope(times[: first + 1], curve[: first + 1])
    exit_ = _slope(times[last:], curve[last:]) if last < curve.size - 1 else float("nan")
    return ArcRates(entry, exit_, inside.size / curve.size, float(np.median(curve[inside])))


def centre_mode_rate(weights: Any, n_agents: int, gamma: float, dt: float) -> float:
    """The decay rate of D predicted by the swarm's slow mode (a derivation, not a fit).

    For p(x_k, x_l) = w_l g(|x_k - x_l|) the weighted centre c = sum_k w_k x_k / W, W = sum_k w_k,
    is not moved by the interaction (the double sum is antisymmetric), so c^{n+1} = c^n + tau v
    with v = sum_k w_k u_k / W; the cheapest control giving v is u_k = v W w_k / sum w^2, so near
    consensus the problem is the scalar LQ problem z+ = z + tau v, cost tau (z^2 + g v^2),
    g = gamma W^2 / (N sum w^2) (= gamma for the symmetric kernel). Its Riccati fixed point
    P = (tau + sqrt(tau^2 + 4 g)) / 2 gives the gain K = P / (g + tau P), the factor
    a = 1 - tau K per step and the rate -2 ln(a) / tau of z^2 (and of D).
    """
    w = np.broadcast_to(np.asarray(weights, dtype=float), (n_agents,))
    g = gamma * np.sum(w) ** 2 / (n_agents * np.sum(w**2))
    p = (dt + math.sqrt(dt**2 + 4.0 * g)) / 2.0
    factor = 1.0 - dt * p / (g + dt * p)
    return -2.0 * math.log(factor) / dt


def kernel_bound(params: Any) -> float:
    """M_p = sup p for the Cucker-Smale kernels: max_l w_l / alpha^2 (Assumption ass:bounded)."""
    from agent_envs.dynamics.swarm import kernel_from_params

    kernel = kernel_from_params(params)
    return float(np.max(kernel.weights)) / kernel.alpha**2


def cheap_constant(dt: float, gamma: float, kernel_sup: float, beta: float = BETA) -> float:
    """C0 of the proof of Lemma lem:cheap.

    C0 = 2 tau (1 + gamma beta_p) / (gamma (1 - e^{-2 beta tau})), beta_p = 2((beta + M_p)^2 +
    M_p^2), with M_p = `kernel_sup`.
    """
    beta_p = 2.0 * ((beta + kernel_sup) ** 2 + kernel_sup**2)
    return 2.0 * dt * (1.0 + gamma * beta_p) / (gamma * (1.0 - math.exp(-2.0 * beta * dt)))


def dissipation(values: np.ndarray, gamma: float, n_agents: int) -> np.ndarray:
    """alpha(y) = gamma / (2N) y^2 of Lemma lem:diss."""
    return gamma / (2.0 * n_agents) * values**2


def theorem_sides(positions, controls, target, gamma, dt, c0, lam=0.5) -> tuple[float, float]:
    """(LHS, RHS) of thm:turnpike_stochastic with lambda = `lam` on the K paths (module doc)."""
    m, n_agents = controls.shape[0], controls.shape[-2]
    s = max(math.floor((1.0 - lam) * m), 1)
    dist = np.sqrt(np.sum((positions[:m] - target) ** 2, axis=(-2, -1)))  # (m, K)
    unorm = np.sqrt(np.sum(controls**2, axis=(-2, -1)))[:, None]  # (m, 1)
    lhs = float(np.mean(np.sum(dt * dissipation(dist + unorm, gamma, n_agents)[s:], axis=0)))
    rhs = c0**2 / (dt * s) * float(np.mean(dissipation(dist[0], gamma, n_agents)))
    return lhs, rhs


@dataclass(frozen=True)
class Setting:
    """One kernel/stiffness/noise combination."""

    kernel: str
    epsilon: float
    sigma: float

    @property
    def label(self) -> str:
        return f"{self.kernel} eps={self.epsilon:g} sigma={self.sigma:g}"

    def params(self, n_agents: int, horizon: float) -> Any:
        from agent_envs.params import SwarmParams

        extra = (
            {"epsilon_min": self.epsilon / 5.0, "epsilon_max": 2.0 * self.epsilon}
            if self.kernel == "nonsymmetric"
            else {"epsilon": self.epsilon}
        )
        return SwarmParams(
            n_agents=n_agents, kernel=self.kernel, sigma=self.sigma, horizon=horizon, **extra
        )


@dataclass(frozen=True, kw_only=True)
class TurnpikePropertyConfig(SolverOptions):
    """Sizes and settings of the experiment (module docstring): the options of `agent-envs
    reproduce turnpike-property`; validated on construction."""

    out: Path = option_field(Path("reproduction_turnpike_property"), "output folder")
    n_agents: int = option_field(20, "N (paper: 100)")
    n_paths: int = option_field(10, "K for sigma > 0 (paper: 20)")
    tau: float = option_field(0.05, "time step (paper: 0.02); it must divide every horizon")
    horizons: tuple[float, ...] = option_field(HORIZONS, "horizons T")
    sigmas: tuple[float, ...] = option_field(SIGMAS, "noise levels sigma")
    epsilons: tuple[float, ...] = option_field(EPSILONS, "stiffness eps of the kernels")
    kernels: tuple[str, ...] = option_field(KERNELS, "interaction kernels", choices=KERNELS)
    delta: float = option_field(DELTA, "turnpike band (eq:tptime)")
    seed: int = option_field(0, "x^0 and the noise")
    n_seeds: int = option_field(1, "repeat for the seeds seed .. seed + n_seeds - 1")
    starts: tuple[str, ...] = option_field(
        ("uniform",), "kinds of initial state x^0", choices=START_KINDS
    )

    def __post_init__(self) -> None:
        object.__setattr__(self, "out", Path(self.out))
        for name in ("horizons", "sigmas", "epsilons", "kernels", "starts"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
        check_sizes(self.n_agents, self.n_paths, min_agents=2)
        check_int("--seed", self.seed, 0, MAX_SEED)
        check_int("--n-seeds", self.n_seeds, 1, 1000)
        check_int("--seed", self.seed + self.n_seeds - 1, 0, MAX_SEED)
        if not self.starts or sorted(set(self.starts) - set(START_KINDS)):
            raise ValueError(f"--starts must be among {START_KINDS}, got {list(self.starts)}")
        for horizon in self.horizons:
            check_positive("--horizons", horizon, HORIZON_RANGE)
        check_positive("--tau", self.tau, HORIZON_RANGE)
        for sigma in self.sigmas:
            check_real("--sigmas", sigma, SIGMA_RANGE)
        for epsilon in self.epsilons:
            check_positive("--epsilons", epsilon, EPSILON_RANGE)
        check_positive("--delta", self.delta)
        self.check_solver_options()
        for horizon in self.horizons:
            steps = horizon / self.tau
            if abs(steps - round(steps)) > 1e-9:
                raise ValueError(
                    f"--tau must divide every horizon (--horizons); {horizon} / {self.tau} = "
                    f"{steps:g}"
                )
        if sorted(set(self.kernels) - set(KERNELS)):
            raise ValueError(f"--kernels must be among {KERNELS}, got {list(self.kernels)}")
        if not all((self.horizons, self.sigmas, self.epsilons, self.kernels)):
            raise ValueError("--horizons, --sigmas, --epsilons and --kernels need a value each")

    @property
    def settings(self) -> list[Setting]:
        return [
            Setting(kernel, eps, sigma)
            for kernel in self.kernels
            for eps in self.epsilons
            for sigma in self.sigmas
        ]


def _solve_horizon(setting, config, x0, seed: int, horizon: float, previous) -> tuple:
    """(params, m, result) of the optimal solve at one horizon, warm-started from `previous`
    (the controls of the previous horizon, cut or padded with zeros to m steps)."""
    from agent_envs.baselines.optimal_control import solve_optimal_control

    n_steps = round(horizon / config.tau)
    params = setting.params(config.n_agents, horizon)
    warm = None
    if previous is not None:
        warm = np.zeros((n_steps, *previous.shape[1:]))
        warm[: min(n_steps, previous.shape[0])] = previous[:n_steps]
    res = solve_optimal_control(
        params,
        "serb",
        n_steps=n_steps,
        n_paths=1 if setting.sigma == 0.0 else config.n_paths,
        seed=seed,
        initial_positions=x0,
        max_control=config.max_control,
        initial_controls=warm,
        gtol=config.gtol,
        max_iterations=config.max_iterations,
    )
    return params, n_steps, res


def _horizon_row(setting, config, x0, params, n_steps: int, res) -> dict:
    """The measured quantities of one optimal solution: arcs and shares of D (and of the
    per-path quantity), our predicted entry rate, the lemma's bound and the theorem's sides."""
    from agent_envs.dynamics.swarm import kernel_from_params

    target = params.target_vector
    dt = params.horizon / n_steps
    times = res.times[:n_steps]
    curve = turnpike_curve(res.mean_positions, res.controls, target)
    rates = arc_rates(times, curve, config.delta)
    shares = {
        name: arc_rates(times, curve, band).share_within_delta
        for name, band in (("share_delta_over_10", config.delta / 10.0),
                           ("share_delta_times_10", config.delta * 10.0))
    }  # fmt: skip
    per_path = path_curve(res.positions, res.controls, target)
    path_rates = arc_rates(times, per_path, config.delta)
    c0 = cheap_constant(dt, params.gamma, kernel_bound(params))
    predicted = centre_mode_rate(
        kernel_from_params(params).weights, params.n_agents, params.gamma, dt
    )
    bound = c0 * params.gamma / (2.0 * params.n_agents) * float(np.sum((x0 - target) ** 2))
    lhs, rhs = theorem_sides(res.positions, res.controls, target, params.gamma, dt, c0)
    return {
        "kernel": setting.kernel,
        "epsilon": setting.epsilon,
        "sigma": setting.sigma,
        "T": params.horizon,
        "m": n_steps,
        "V": res.cost,
        "converged": res.converged,
        "iterations": res.iterations,
        "rel_grad": res.relative_gradient_norm,
        **asdict(rates),
        **shares,
        "predicted_entry_rate": predicted,
        "min_D": float(np.min(curve)),
        "min_D_path": float(np.min(per_path)),
        "share_path_within_delta": path_rates.share_within_delta,
        "path_exit_time_bound": (
            config.delta / (params.dim * setting.sigma**2) if setting.sigma > 0 else math.inf
        ),
        "cheap_bound": bound,
        "bound_over_V": bound / res.cost,
        "thm_lhs": lhs,
        "thm_rhs": rhs,
        "seconds": res.wall_time,
        "curve": curve,
        "path_curve": per_path,
        "times": times,
    }


def run_setting(
    setting: Setting,
    config: TurnpikePropertyConfig,
    x0: np.ndarray,
    seed: int | None = None,
    start_kind: str = "uniform",
) -> list[dict]:
    """Solve every horizon of one setting (warm-started), return one row per T."""
    seed = config.seed if seed is None else seed
    rows, previous = [], None
    for horizon in config.horizons:
        params, n_steps, res = _solve_horizon(setting, config, x0, seed, horizon, previous)
        previous = res.controls
        row = {"seed": seed, "start": start_kind}
        row.update(_horizon_row(setting, config, x0, params, n_steps, res))
        rows.append(row)
        if config.progress:
            print(
                f"  seed={seed} {start_kind:7s} {setting.label:40s} T={horizon:<4g} "
                f"m={n_steps:<4d} V={res.cost:.5f} it={res.iterations:<4d} conv={res.converged} "
                f"entry={row['entry_rate']:7.2f} (ours: {row['predicted_entry_rate']:.2f}) "
                f"exit={row['exit_rate']:7.2f} share={row['share_within_delta']:.2f} "
                f"path share={row['share_path_within_delta']:.2f} "
                f"({res.wall_time:.1f} s)",
                flush=True,
            )
    return rows


def plot(rows: list[dict], settings: list[Setting], delta: float, path: Path) -> None:
    """One panel per setting: log D_n against t_n, one line per T, the delta band dashed; with
    noise the per-path Dp_n dotted. The first seed and start only."""
    from matplotlib.figure import Figure

    kernels = sorted({(s.kernel, s.epsilon) for s in settings})
    sigmas = sorted({s.sigma for s in settings})
    fig = Figure(figsize=(4 * len(kernels), 3 * len(sigmas)))  # no pyplot: no backend switch
    axes = fig.subplots(len(sigmas), len(kernels), squeeze=False)
    for i, sigma in enumerate(sigmas):
        for j, (kernel, eps) in enumerate(kernels):
            ax = axes[i][j]
            for row in rows:
                if (row["kernel"], row["epsilon"], row["sigma"]) != (kernel, eps, sigma):
                    continue
                if (row["seed"], row["start"]) != (rows[0]["seed"], rows[0]["start"]):
                    continue
                (line,) = ax.semilogy(row["times"], row["curve"], label=f"T={row['T']:g}")
                if sigma > 0:
                    ax.semilogy(row["times"], row["path_curve"], ":", color=line.get_color())
            ax.axhline(delta, color="k", ls="--", lw=0.8)
            ax.set_title(f"{kernel} eps={eps:g}, sigma={sigma:g}", fontsize=9)
            ax.set_xlabel("t")
            if j == 0:
                ax.set_ylabel("||E x* - x~||^2 + ||u* - u~||^2")
            ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


COLUMNS = (
    "seed", "start", "kernel", "epsilon", "sigma", "T", "m", "V", "converged", "iterations",
    "rel_grad", "entry_rate", "predicted_entry_rate", "exit_rate", "share_within_delta",
    "share_delta_over_10", "share_delta_times_10", "plateau", "min_D", "min_D_path",
    "share_path_within_delta", "path_exit_time_bound", "cheap_bound", "bound_over_V", "thm_lhs",
    "thm_rhs", "seconds",
)  # fmt: skip
#: the quantities `seed_summary` gives mean, min and max of, across seeds and starts
SUMMARIZED = (
    "share_within_delta", "share_delta_over_10", "share_delta_times_10",
    "share_path_within_delta", "entry_rate", "V",
)  # fmt: skip


def seed_summary(rows: list[dict]) -> str:
    """Markdown: per setting and T, mean [min, max] of `SUMMARIZED` across seeds and starts."""
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        groups.setdefault((row["kernel"], row["epsilon"], row["sigma"], row["T"]), []).append(row)
    head = ["kernel", "epsilon", "sigma", "T", "runs", *SUMMARIZED]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for (kernel, eps, sigma, horizon), group in groups.items():
        cells = [kernel, f"{eps:g}", f"{sigma:g}", f"{horizon:g}", str(len(group))]
        for name in SUMMARIZED:
            values = np.array([r[name] for r in group], dtype=float)
            cells.append(f"{np.mean(values):.3g} [{np.min(values):.3g}, {np.max(values):.3g}]")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def write_tables(rows: list[dict], out: Path) -> None:
    """turnpike_property.csv and .md (COLUMNS), curves.npz."""
    import csv

    with open(out / "turnpike_property.csv", "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(COLUMNS)
        for row in rows:
            writer.writerow([row[c] for c in COLUMNS])

    def fmt(value: Any) -> str:
        if isinstance(value, float):
            return f"{value:.4g}"
        return str(value)

    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    lines += ["| " + " | ".join(fmt(row[c]) for c in COLUMNS) + " |" for row in rows]
    (out / "turnpike_property.md").write_text("\n".join(lines) + "\n")
    (out / "turnpike_property_seeds.md").write_text(seed_summary(rows))
    curves = {
        f"seed{r['seed']}_{r['start']}_{r['kernel']}_eps{r['epsilon']:g}_sigma{r['sigma']:g}"
        f"_T{r['T']:g}": r["curve"]
        for r in rows
    }
    np.savez(out / "curves.npz", **curves)


def reproduce(out: Path, config: TurnpikePropertyConfig) -> list[dict]:
    """Run every setting and horizon, write the figure, tables and meta.json into `out`."""
    from agent_envs.draws import uniform_positions

    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    rows: list[dict] = []
    for seed in range(config.seed, config.seed + config.n_seeds):
        for kind in config.starts:
            rng = np.random.default_rng(seed)
            # the paper's start draws exactly as before, so the default run is unchanged
            x0 = (
                uniform_positions(rng, config.n_agents, 1)
                if kind == "uniform"
                else initial_state(kind, rng, config.n_agents)
            )
            for setting in config.settings:
                rows += run_setting(setting, config, x0, seed, kind)
    write_tables(rows, out)
    plot(rows, config.settings, config.delta, out / "turnpike_property.png")
    meta = {**asdict(config), "seconds": time.perf_counter() - start}
    del meta["out"]  # the folder it is written into
    (out / "meta.json").write_text(json.dumps(meta, indent=2, default=str))
    return rows
