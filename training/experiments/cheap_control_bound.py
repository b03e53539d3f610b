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

Modules: the closed forms are in `cheap_control_formulas`, the options in
`cheap_control_config`, the solves and their rows in `cheap_control_measurements`; this module
runs the parts (`reproduce`) and writes the tables, the fitted exponents and the figure.
"""

from __future__ import annotations

import csv
import json
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from agent_envs.training.experiments.cheap_control_config import CheapControlBoundConfig
from agent_envs.training.experiments.cheap_control_formulas import fit_exponent
from agent_envs.training.experiments.cheap_control_measurements import (
    case_params,
    case_rng,
    contraction_rows,
    measure,
    random_start_rows,
    short_name,
)

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


def _typed(text: str) -> Any:
    """A CSV cell back as `reproduce` wrote it: a bool, an int, a float or a string."""
    if text in ("True", "False"):
        return text == "True"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def read_rows(path: str | Path) -> list[dict]:
    """The rows of a written ``cheap_control_bound.csv`` or ``contraction.csv``, typed back, so
    that `markdown` prints them as the run printed them (the published tables are rendered from
    the committed CSVs, docs/results/cheap-control-bound/)."""
    with open(path, newline="") as fh:
        return [{k: _typed(v) for k, v in row.items()} for row in csv.DictReader(fh)]


#: the rows' columns of the turnpike page's selection, and their headers there
SELECTED = {
    "case": "case", "sigma": "sigma", "N": "N", "T": "T", "V": "V",
    "V_fresh": "V on fresh paths", "floor": "floor F", "lemma_rhs": "lemma's bound",
    "upper": "corrected U", "corrected_holds": "corrected holds",
}  # fmt: skip


def selected_table(rows: list[dict]) -> str:
    """docs/turnpike-theory.md's selection of the summary: the V(T) sweep and x^0 = xbar rows,
    and the N-scaling rows at an N other than the sweep's (its row is the sweep's T row)."""
    base_n = {r["N"] for r in rows if r["case"] == "V(T)"}
    chosen = [
        r
        for r in rows
        if r["case"] in ("V(T)", "x0=xbar") or (r["case"] == "N-scaling" and r["N"] not in base_n)
    ]
    lines = ["| " + " | ".join(SELECTED.values()) + " |", "|" + "---|" * len(SELECTED)]
    lines += ["| " + " | ".join(_fmt(r[c]) for c in SELECTED) + " |" for r in chosen]
    return "\n".join(lines)


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
            ax.semilogy(
                times, row["lyapunov"] / row["lyapunov"][0], label=short_name(row["control"])
            )
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
    from agent_envs.draws import uniform_positions

    out.mkdir(parents=True, exist_ok=True)
    began = time.perf_counter()
    n, sigma, eps = config.n_agents, config.sigma, config.epsilon
    x0 = uniform_positions(case_rng(config, 0, n), n, 1)
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
    params = case_params(n, 1.0, sigma, eps)
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
        start = uniform_positions(case_rng(config, 0, n_agents), n_agents, 1)
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
