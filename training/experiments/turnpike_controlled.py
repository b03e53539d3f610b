"""Reproduction of the paper's turnpike-controlled experiments (Section 5.2, Figs. 5-6).

    agent-envs reproduce turnpike --out DIR [--seeds 0-2]

Setting (paper): N = 100 agents uniform on [-1, 1], T = 1, m = 50, 20 Brownian paths,
sigma = 0.01, alpha = 0.1, beta = 12, delta = 2e-4; tbar from `eq:tptime` per run.

Runs:
- ``em_sym_0.7``:      symmetric kernel eps = 0.05, xbar = 0.7, Euler-Maruyama (Fig. 5 top);
- ``serb_sym_0.7``:    same, SERB (frozen Jacobian, the core's default) (Fig. 5 centre);
- ``serb_sym_-1.7``:   xbar = -1.7, SERB (Fig. 5 bottom; its caption says -1.6, the text and
  tbar = 0.6 say -1.7);
- ``serb_nonsym_2.3``: non-symmetric kernel, eps_l from 1e-2 to 1e-1, xbar = 2.3, SERB (Fig. 6);
- ``serb-exact_sym_0.7``: SERB with the exact Jacobian, for comparison (not in the paper).

Each run is done in two modes, from the same initial positions (the env's seeded draw):

- ``env``: the public API. ``gym.make("agent_envs/Swarm-v0", n_paths=20, ...)`` driven by
  `TurnpikeController`: the cheap control `eq:cheap_ctr` (path means), held constant
  over each step (zero-order hold, as every RL policy acts), until tbar, then u = 0.
- ``closed-loop``: the paper's procedure (Section 5.2): in [0, tbar] the closed loop
  `eq:dyn_mean` is integrated with the run's scheme (`CheapClosedLoopModel`: the
  cheap control cancels each path's interaction, dx = beta (xbar - x) dt + sigma dW; for SERB the
  mean follows `eq:expint_mean`, exact), then the uncontrolled swarm (static control u = 0,
  `eq:stationary_solution`) with the same scheme. Uses the core's integrators and its Brownian
  increments; the cost uses the per-path control u(x^n) at each step's start.

Per run: tbar, the Lyapunov value L = ||E x - xbar||^2 (`eq:tptime`'s quantity) at tbar and at
T, the RMS distance sqrt(mean_k |E x_k(T) - xbar|^2) at T and its maximum after tbar, the total
cost tau sum_n c(x^n, u^n) (`eq:discrete_cost_functional`), max |u|, and whether a path diverged
(non-finite or |x| > 1e4). Outputs: results.md / results.csv / results.json, one PNG of the mean
trajectories per mode (one panel per run, tbar marked), and lyapunov.png (L^n against t).
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from agent_envs.baselines import CheapClosedLoopModel, TurnpikeController, turnpike_time
from agent_envs.training.config import option_field
from agent_envs.training.defaults import DEFAULT_BETA, DEFAULT_DELTA, GYM_ENV_ID, parse_seeds
from agent_envs.training.experiments import check_sizes
from agent_envs.training.results.tables import Episode

#: The paper's stiffness of the symmetric kernel (Section 5.2).
EPSILON = 0.05
#: `env`: the Gymnasium env and the TurnpikeController; `closed-loop`: the paper's procedure.
MODES = ("env", "closed-loop")


@dataclass(frozen=True, kw_only=True)
class TurnpikeReproductionConfig:
    """The options of `agent-envs reproduce turnpike`; validated on construction.

    `seeds` may be given as ints or as seed-list strings (`defaults.parse_seeds`); they are
    stored as a tuple of ints.
    """

    out: Path = option_field(Path("reproduction_turnpike"), "output folder")
    seeds: tuple[int, ...] = option_field(
        (0,),
        "seeds of the initial positions and noise: '0 1 2', '0-2', '0:3' or '0,1,2' (default: 0)",
        nargs="+",
        type=str,
    )
    modes: tuple[str, ...] = option_field(
        MODES,
        "env (public API, zero-order hold) and/or closed-loop (paper)",
        choices=MODES,
    )
    n_agents: int = option_field(100, "number of agents N (the paper's)")
    n_paths: int = option_field(20, "Brownian paths (the paper's)")
    n_steps: int = option_field(50, "time steps m (the paper's)")
    progress: bool = option_field(
        True, "no progress bar", flags=("--no-progress",), action="store_false"
    )

    def __post_init__(self) -> None:
        object.__setattr__(self, "out", Path(self.out))
        object.__setattr__(self, "seeds", tuple(parse_seeds(self.seeds, "--seeds", (0,))))
        object.__setattr__(self, "modes", tuple(self.modes))
        check_sizes(self.n_agents, self.n_paths, self.n_steps)
        unknown = [mode for mode in self.modes if mode not in MODES]
        if unknown or not self.modes:
            raise ValueError(f"--modes must be among {', '.join(MODES)}, got {list(self.modes)}")


@dataclass(frozen=True)
class TurnpikeRun:
    """One controlled experiment of Section 5.2."""

    name: str
    integrator: str
    target: float
    kernel: str = "symmetric"
    jacobian: str = "frozen"
    figure: str = ""

    def env_kwargs(self, n_agents: int, n_steps: int, n_paths: int) -> dict[str, Any]:
        return {
            "n_agents": n_agents,
            "n_steps": n_steps,
            "n_paths": n_paths,
            "epsilon": EPSILON,
            "epsilon_min": 1e-2,
            "epsilon_max": 1e-1,
            "alpha": 0.1,
            "sigma": 0.01,
            "horizon": 1.0,
            "kernel": self.kernel,
            "target": self.target,
            "integrator": self.integrator,
            "jacobian": self.jacobian,
        }


PAPER_RUNS: tuple[TurnpikeRun, ...] = (
    TurnpikeRun("em_sym_0.7", "em", 0.7, figure="Fig. 5 top"),
    TurnpikeRun("serb_sym_0.7", "serb", 0.7, figure="Fig. 5 centre"),
    TurnpikeRun("serb_sym_-1.7", "serb", -1.7, figure="Fig. 5 bottom"),
    TurnpikeRun("serb_nonsym_2.3", "serb", 2.3, kernel="nonsymmetric", figure="Fig. 6"),
    TurnpikeRun("serb-exact_sym_0.7", "serb", 0.7, jacobian="exact", figure="(comparison)"),
)


def run_env_mode(run: TurnpikeRun, seed: int, n_agents: int, n_steps: int, n_paths: int):
    """The run through `agent_envs/Swarm-v0` and the TurnpikeController (public API)."""
    import gymnasium as gym

    import agent_envs  # noqa: F401
    from agent_envs.training.results.rollout import rollout

    env = gym.make(GYM_ENV_ID, **run.env_kwargs(n_agents, n_steps, n_paths))
    try:
        ctrl = TurnpikeController(env, beta=DEFAULT_BETA, delta=DEFAULT_DELTA)
        ep = rollout(ctrl, env, seed)
    finally:
        env.close()
    return ep, ep.mean_positions[0]


def run_closed_loop_mode(
    run: TurnpikeRun, seed: int, x0: np.ndarray, n_steps: int, n_paths: int
) -> Episode:
    """The paper's procedure: closed-loop `eq:dyn_mean` on [0, tbar], then u = 0 (core API).

    One `simulate` call on `CheapClosedLoopModel(..., until=tbar)`, whose drift carries the
    per-path cheap feedback while t < tbar and is the open-loop swarm afterwards; the controls
    and costs are then read off the trajectory at each step's start.
    """
    from agent_envs.costs import running_cost
    from agent_envs.draws import brownian_increments
    from agent_envs.dynamics.swarm import SwarmModel
    from agent_envs.integrators import make_integrator
    from agent_envs.params import SwarmParams
    from agent_envs.simulator import simulate

    kw = run.env_kwargs(x0.shape[0], n_steps, n_paths)
    params = SwarmParams(**{k: kw[k] for k in SwarmParams.field_names() if k in kw})
    target = params.target_vector
    tbar = turnpike_time(x0, target, DEFAULT_BETA, DEFAULT_DELTA, params.horizon)
    closed = CheapClosedLoopModel(SwarmModel(params), target, DEFAULT_BETA, until=tbar)
    dt = params.horizon / n_steps
    n, d = params.n_agents, params.dim
    rng = np.random.default_rng(np.random.SeedSequence([seed, 5, 2]))
    start = time.perf_counter()
    traj = simulate(
        params,
        make_integrator(run.integrator, jacobian=run.jacobian),
        n_steps=n_steps,
        n_paths=n_paths,
        initial_positions=x0,
        model=closed,
        increments=brownian_increments(rng, (n_steps, n_paths, n, d), dt),
    )
    wall = time.perf_counter() - start
    controls = np.zeros((n_steps, n, d))
    costs = np.zeros(n_steps)
    max_u = 0.0
    for step in range(traj.divergence_step or n_steps):
        x = traj.positions[step]
        on = closed.feedback_on(float(traj.times[step]))
        u = closed.control(x) if on else np.zeros_like(x)  # per path (n_paths, N, d)
        controls[step] = u.mean(axis=0)
        max_u = max(max_u, float(np.max(np.abs(u))))
        costs[step] = float(np.mean(running_cost(x, u, target, params.gamma)))
    return Episode(
        seed=seed,
        times=np.asarray(traj.times),
        mean_positions=np.asarray(traj.mean_positions),
        controls=controls,
        running_cost=costs,
        rewards=-dt * costs,
        target=np.asarray(target, dtype=float),
        dt=dt,
        max_control=float("inf"),  # the closed loop's feedback is not bounded
        diverged=traj.diverged,
        divergence_step=traj.divergence_step,
        n_steps_run=traj.divergence_step if traj.diverged else n_steps,
        turnpike_time=float(tbar),
        wall_time=wall,
        max_abs_control=max_u,
    )


def summarize_record(run: TurnpikeRun, mode: str, seed: int, rec: Episode) -> dict[str, Any]:
    """The table row of one run."""
    err = rec.mean_positions - rec.target  # (m+1, N, d)
    lyap = np.sum(err**2, axis=(-2, -1))  # L^n
    rms = np.sqrt(np.mean(np.sum(err**2, axis=-1), axis=-1))
    nbar = min(int(np.ceil(rec.turnpike_time / rec.dt - 1e-9)), len(rec.times) - 1)
    finite = np.isfinite(rms)
    after = rms[nbar:][finite[nbar:]]
    return {
        "run": run.name,
        "mode": mode,
        "seed": seed,
        "figure": run.figure,
        "integrator": run.integrator.upper() + (" (exact J)" if run.jacobian == "exact" else ""),
        "kernel": run.kernel,
        "target": run.target,
        "tbar": rec.turnpike_time,
        "L_at_tbar": float(lyap[nbar]),
        "L_at_T": float(lyap[-1]),
        "rms_distance_at_T": float(rms[-1]),
        "max_rms_after_tbar": float(after.max()) if after.size else float("nan"),
        "total_cost": float(rec.dt * np.sum(rec.running_cost)),
        "max_abs_u": float(
            np.max(np.abs(rec.controls)) if rec.max_abs_control is None else rec.max_abs_control
        ),
        "diverged": bool(rec.diverged),
        "wall_time_s": rec.wall_time,
    }


def plot_runs(path: Path, panels: list[tuple[dict, Episode]], title: str) -> None:
    """One panel per run: every agent's path-mean position against time, tbar marked."""
    ncols = 2
    nrows = int(np.ceil(len(panels) / ncols))
    fig = Figure(figsize=(11, 3.1 * nrows))
    axes = fig.subplots(nrows, ncols, squeeze=False)
    for ax in axes.flat[len(panels) :]:
        ax.set_visible(False)
    for ax, (row, rec) in zip(axes.flat, panels, strict=False):
        ax.plot(rec.times, rec.mean_positions[..., 0], lw=0.5, color="tab:blue", alpha=0.6)
        ax.axhline(rec.target[0], color="k", ls="--", lw=1)
        ax.axvline(rec.turnpike_time, color="tab:red", ls=":", lw=1.3)
        status = (
            "DIVERGED" if row["diverged"] else f"RMS dist. at T = {row['rms_distance_at_T']:.2g}"
        )
        ax.set_title(
            f"{row['integrator']}, {row['kernel']}, xbar = {row['target']:g}, "
            f"tbar = {row['tbar']:.2f}\n[{status}]",
            fontsize=9,
        )
        ax.set_xlabel("t")
        ax.set_ylabel("E x_k(t)")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def plot_lyapunov(path: Path, by_mode: dict[str, list[tuple[dict, Episode]]]) -> None:
    """L^n = ||E x^n - xbar||^2 against t, one panel per mode, one curve per run."""
    fig = Figure(figsize=(6 * len(by_mode), 4))
    axes = fig.subplots(1, len(by_mode), squeeze=False)
    for ax, (mode, panels) in zip(axes[0], by_mode.items(), strict=True):
        for i, (row, rec) in enumerate(panels):
            lyap = np.sum((rec.mean_positions - rec.target) ** 2, axis=(-2, -1))
            ax.plot(rec.times, lyap, color=f"C{i}", lw=1.4, label=row["run"])
            ax.axvline(rec.turnpike_time, color=f"C{i}", ls=":", lw=0.9)
        ax.axhline(DEFAULT_DELTA, color="k", ls="--", lw=0.8, label="delta")
        ax.set_yscale("log")
        ax.set_xlabel("t")
        ax.set_ylabel("||E x^n - xbar||^2")
        ax.set_title(f"mode: {mode} (dotted: tbar)", fontsize=10)
        ax.grid(True, which="both", alpha=0.25)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


TABLE_COLUMNS = (
    "run",
    "mode",
    "seed",
    "integrator",
    "kernel",
    "target",
    "tbar",
    "L_at_tbar",
    "L_at_T",
    "rms_distance_at_T",
    "max_rms_after_tbar",
    "total_cost",
    "max_abs_u",
    "diverged",
)


def _markdown_table(df: pd.DataFrame) -> str:
    def fmt(v):
        if isinstance(v, (bool, np.bool_)):
            return "yes" if v else "no"
        if isinstance(v, (float, np.floating)):
            return f"{v:.3g}" if np.isfinite(v) else "n/a"
        return str(v)

    cols = [c for c in TABLE_COLUMNS if c in df.columns]
    lines = ["| " + " | ".join(cols) + " |", "|" + "|".join("---" for _ in cols) + "|"]
    lines += ["| " + " | ".join(fmt(r[c]) for c in cols) + " |" for _, r in df.iterrows()]
    return "\n".join(lines)


def _run_all(
    seeds: tuple[int, ...],
    runs: tuple[TurnpikeRun, ...],
    modes: tuple[str, ...],
    sizes: tuple[int, int, int],
    progress: bool,
) -> tuple[list[dict[str, Any]], dict[str, list[tuple[dict, Episode]]]]:
    """Every (seed, run, mode): the table rows, and the first seed's (row, episode) per mode.

    `sizes` is (n_agents, n_steps, n_paths).
    """
    from tqdm.auto import tqdm

    n_agents, n_steps, n_paths = sizes
    rows: list[dict[str, Any]] = []
    panels: dict[str, list[tuple[dict, Episode]]] = {m: [] for m in modes}
    bar = tqdm(total=len(runs) * len(seeds), desc="reproduce turnpike", disable=not progress)
    for seed in seeds:
        for run in runs:
            bar.set_postfix_str(f"{run.name} seed={seed}")
            env_rec, x0 = run_env_mode(run, seed, n_agents, n_steps, n_paths)
            records = {"env": env_rec}
            if "closed-loop" in modes:
                records["closed-loop"] = run_closed_loop_mode(run, seed, x0, n_steps, n_paths)
            for mode in modes:
                row = summarize_record(run, mode, seed, records[mode])
                rows.append(row)
                if seed == seeds[0]:
                    panels[mode].append((row, records[mode]))
            bar.update(1)
    bar.close()
    return rows, panels


def _settings(
    seeds: tuple[int, ...], runs: tuple[TurnpikeRun, ...], sizes: tuple[int, int, int]
) -> dict[str, Any]:
    """The setting written into results.json."""
    n_agents, n_steps, n_paths = sizes
    return {
        "n_agents": n_agents,
        "n_steps": n_steps,
        "n_paths": n_paths,
        "beta": DEFAULT_BETA,
        "delta": DEFAULT_DELTA,
        "epsilon": EPSILON,
        "sigma": 0.01,
        "alpha": 0.1,
        "seeds": list(seeds),
        "runs": [asdict(r) for r in runs],
    }


def _write_figures(
    out: Path,
    panels: dict[str, list[tuple[dict, Episode]]],
    seed: int,
    sizes: tuple[int, int, int],
) -> list[str]:
    """One PNG of the mean trajectories per mode and lyapunov.png; returns their names."""
    n_agents, n_steps, n_paths = sizes
    figures = []
    for mode, mode_panels in panels.items():
        fname = f"turnpike_{mode.replace('-', '_')}.png"
        plot_runs(
            out / fname,
            mode_panels,
            f"Turnpike control, mode '{mode}', seed {seed}: path-mean positions "
            f"(N = {n_agents}, m = {n_steps}, {n_paths} paths); dotted red: tbar",
        )
        figures.append(fname)
    plot_lyapunov(out / "lyapunov.png", panels)
    figures.append("lyapunov.png")
    return figures


def _markdown(
    table: pd.DataFrame, figures: list[str], seeds: tuple[int, ...], sizes: tuple[int, int, int]
) -> str:
    """results.md: the setting, the modes, the table and the figures."""
    n_agents, n_steps, n_paths = sizes
    md = [
        "# Turnpike-controlled experiments (paper Section 5.2)",
        "",
        f"N = {n_agents}, m = {n_steps}, {n_paths} paths, eps = {EPSILON} (non-symmetric: "
        f"1e-2..1e-1), sigma = 0.01, alpha = 0.1, beta = {DEFAULT_BETA:g}, "
        f"delta = {DEFAULT_DELTA:g}; "
        f"seeds {list(seeds)}. L = ||E x - xbar||^2 (sum over agents); rms = "
        "sqrt(mean_k (E x_k - xbar)^2); cost = tau sum_n c(x^n, u^n).",
        "",
        "Modes: `env` = agent_envs/Swarm-v0 + TurnpikeController (control held over each step); "
        "`closed-loop` = the paper's procedure (closed loop eq:dyn_mean integrated on [0, tbar], "
        "then u = 0).",
        "",
        _markdown_table(table),
        "",
        *[f"![{f}]({f})" for f in figures],
        "",
    ]
    return "\n".join(md)


def reproduce(
    out_dir: str | Path,
    seeds: tuple[int, ...] = TurnpikeReproductionConfig.seeds,
    *,
    runs: tuple[TurnpikeRun, ...] = PAPER_RUNS,
    modes: tuple[str, ...] = MODES,
    n_agents: int = TurnpikeReproductionConfig.n_agents,
    n_steps: int = TurnpikeReproductionConfig.n_steps,
    n_paths: int = TurnpikeReproductionConfig.n_paths,
    progress: bool = True,
) -> pd.DataFrame:
    """Run every (run, mode, seed), write the table and figures into `out_dir`; return the table.

    The defaults are `TurnpikeReproductionConfig`'s (the paper's sizes). Figures show the first
    seed.
    """
    out = Path(out_dir)
    for mode in modes:
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    out.mkdir(parents=True, exist_ok=True)
    sizes = (n_agents, n_steps, n_paths)
    rows, panels = _run_all(tuple(seeds), runs, tuple(modes), sizes, progress)
    table = pd.DataFrame(rows)
    table.to_csv(out / "results.csv", index=False)
    records = json.loads(table.to_json(orient="records"))
    (out / "results.json").write_text(
        json.dumps({"settings": _settings(seeds, runs, sizes), "rows": records}, indent=1)
    )
    figures = _write_figures(out, panels, seeds[0], sizes)
    (out / "results.md").write_text(_markdown(table, figures, seeds, sizes))
    return table
