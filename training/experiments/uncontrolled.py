"""Reproduction of the paper's uncontrolled experiments (Section 5.1, Figs. 1-4).

`agent-envs reproduce uncontrolled --out DIR` runs, with N = 100 agents drawn uniform on
[-1, 1] (one seeded draw shared by every run), T = 1, alpha = 0.1 and 20 Brownian paths:

- Fig. 1/2: eps = 0.05, sigma = 0.01: EM with m = 25, 150, 1500; SERB with m = 25 (frozen and
  exact Jacobian);
- Fig. 3:   eps = 1, sigma = 0.01: EM and SERB with m = 50;
- Fig. 4/5: eps = 0.05, sigma = 0: EE, Heun, ERB (frozen and exact) with m = 25; EE, Heun with
  m = 1500;
- a Jacobian study (not in the paper): ERB with the exact vs frozen Jacobian from evenly spaced
  positions, sigma = 0, m = 10 ... 400.

It writes one PNG per figure (the path-mean trajectory of every agent against time), a
`results.md` table, `results.json` and `results.csv` (one row per run, `COLUMNS`; `read_rows`
reads it back typed, and `csv_table` renders docs/paper.md's table from the committed copy,
docs/results/uncontrolled/results.csv). Without control the agents should reach consensus at the
mean of the initial positions; the table's "spread at T" (max_k - min_k of E x_k(T)) measures
that, and "max |E x|" flags oscillation/blow-up.
"""

from __future__ import annotations

import csv
import json
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from agent_envs.params import SwarmParams
from agent_envs.simulator import Trajectory, simulate
from agent_envs.training.config import option_field
from agent_envs.training.experiments import check_sizes
from agent_envs.validation import MAX_SEED, check_int


@dataclass(frozen=True, kw_only=True)
class UncontrolledConfig:
    """The options of `agent-envs reproduce uncontrolled`; validated on construction."""

    out: Path = option_field(Path("out/uncontrolled"), "output folder")
    n_agents: int = option_field(100, "number of agents N")
    n_paths: int = option_field(20, "Brownian paths (for the runs with sigma > 0)")
    seed: int = option_field(0, "seed of the start and noise")

    def __post_init__(self) -> None:
        object.__setattr__(self, "out", Path(self.out))
        check_sizes(self.n_agents, self.n_paths)
        check_int("--seed", self.seed, 0, MAX_SEED)


@dataclass(frozen=True)
class Run:
    """One uncontrolled run: integrator, steps, stiffness, noise and Jacobian choice."""

    figure: str
    integrator: str
    n_steps: int
    epsilon: float
    sigma: float
    jacobian: str | None = None
    evenly_spaced: bool = False


PAPER_RUNS: tuple[Run, ...] = (
    Run("fig1_stiff_m25", "em", 25, 0.05, 0.01),
    Run("fig1_stiff_m25", "serb", 25, 0.05, 0.01, "frozen"),
    Run("fig1_stiff_m25", "serb", 25, 0.05, 0.01, "exact"),
    Run("fig2_stiff_em", "em", 150, 0.05, 0.01),
    Run("fig2_stiff_em", "em", 1500, 0.05, 0.01),
    Run("fig3_nonstiff_m50", "em", 50, 1.0, 0.01),
    Run("fig3_nonstiff_m50", "serb", 50, 1.0, 0.01, "frozen"),
    Run("fig3_nonstiff_m50", "serb", 50, 1.0, 0.01, "exact"),
    Run("fig4_deterministic_m25", "ee", 25, 0.05, 0.0),
    Run("fig4_deterministic_m25", "heun", 25, 0.05, 0.0),
    Run("fig4_deterministic_m25", "erb", 25, 0.05, 0.0, "frozen"),
    Run("fig4_deterministic_m25", "erb", 25, 0.05, 0.0, "exact"),
    Run("fig5_deterministic_m1500", "ee", 1500, 0.05, 0.0),
    Run("fig5_deterministic_m1500", "heun", 1500, 0.05, 0.0),
)

JACOBIAN_STUDY: tuple[Run, ...] = tuple(
    Run("jacobian_study", "erb", m, 0.05, 0.0, jac, evenly_spaced=True)
    for jac in ("exact", "frozen")
    for m in (10, 25, 50, 100, 200, 400)
)


def run_one(run: Run, n_agents: int, n_paths: int, seed: int) -> tuple[dict, Trajectory]:
    """Simulate `run` and summarize it as a table row."""
    params = SwarmParams(n_agents=n_agents, alpha=0.1, epsilon=run.epsilon, sigma=run.sigma)
    x0 = np.linspace(-1.0, 1.0, n_agents) if run.evenly_spaced else None
    paths = 1 if run.sigma == 0.0 else n_paths
    traj = simulate(
        params,
        run.integrator,
        jacobian=run.jacobian or "frozen",
        n_steps=run.n_steps,
        n_paths=paths,
        seed=seed,
        initial_positions=x0,
    )
    mean = traj.mean_positions[..., 0]  # (m+1, N)
    finite_rows = mean[np.all(np.isfinite(mean), axis=1)]
    final = finite_rows[-1]
    row = {
        **asdict(run),
        "n_paths": paths,
        "spread_at_T": float(final.max() - final.min()),
        "max_abs_mean_x": float(np.max(np.abs(finite_rows))),
        "consensus_error_at_T": float(np.max(np.abs(final - mean[0].mean()))),
        "diverged": bool(traj.diverged),
        "wall_time_s": float(traj.wall_time),
    }
    return row, traj


#: results.csv's columns: a run's fields, then its measurements (`run_one`'s row keys)
COLUMNS: tuple[str, ...] = (
    *(f.name for f in fields(Run)),
    "n_paths",
    "spread_at_T",
    "max_abs_mean_x",
    "consensus_error_at_T",
    "diverged",
    "wall_time_s",
)
_INTS = ("n_steps", "n_paths")
_BOOLS = ("evenly_spaced", "diverged")


def write_csv(rows: list[dict], path: Path) -> None:
    """`rows` as a CSV of `COLUMNS`, one line per run (floats in repr, so they read back
    bit for bit; a run without a Jacobian choice has an empty ``jacobian`` cell)."""
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=COLUMNS)
        writer.writeheader()
        writer.writerows({c: row[c] for c in COLUMNS} for row in rows)


def _typed(column: str, text: str) -> object:
    """One cell of results.csv back as `run_one` made it."""
    if column in _INTS:
        return int(text)
    if column in _BOOLS:
        return text == "True"
    if column in ("figure", "integrator"):
        return text
    if column == "jacobian":
        return text or None
    return float(text)


def read_rows(path: Path) -> list[dict]:
    """The rows of a written results.csv, typed back (`run_one`'s dicts, in run order)."""
    with open(path, newline="") as handle:
        return [{c: _typed(c, v) for c, v in row.items()} for row in csv.DictReader(handle)]


def _label(row: dict) -> str:
    name = row["integrator"].upper()
    if row["jacobian"]:
        name += f" ({row['jacobian']} J)"
    return f"{name}, m = {row['n_steps']}, eps = {row['epsilon']:g}, sigma = {row['sigma']:g}"


def plot_figure(path: Path, panels: list[tuple[dict, Trajectory]]) -> None:
    """One panel per run: every agent's path-mean position against time."""
    fig = Figure(figsize=(7, 2.6 * len(panels)))
    axes = fig.subplots(len(panels), 1, squeeze=False)
    for ax, (row, traj) in zip(axes[:, 0], panels, strict=True):
        mean = traj.mean_positions[..., 0]
        ax.plot(traj.times, mean, lw=0.6, color="tab:blue", alpha=0.6)
        status = "DIVERGED" if row["diverged"] else f"spread at T = {row['spread_at_T']:.2e}"
        ax.set_title(f"{_label(row)}  [{status}]", fontsize=9)
        ax.set_xlabel("t")
        ax.set_ylabel("E x_k(t)")
        lim = max(1.2, min(row["max_abs_mean_x"] * 1.05, 50.0))
        ax.set_ylim(-lim, lim)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def plot_jacobian_study(path: Path, rows: list[dict]) -> None:
    """Spread of the agents at T against m for ERB with the exact and the frozen Jacobian."""
    fig = Figure(figsize=(6, 3.5))
    ax = fig.subplots()
    for jac, marker in (("exact", "o"), ("frozen", "s")):
        sel = [r for r in rows if r["jacobian"] == jac]
        spreads = [max(r["spread_at_T"], 1e-17) for r in sel]
        ax.loglog([r["n_steps"] for r in sel], spreads, marker=marker, label=f"ERB, {jac} J")
    ax.set_xlabel("number of steps m")
    ax.set_ylabel("spread of agents at T (floored at 1e-17)")
    ax.set_title("eps = 0.05, sigma = 0, evenly spaced start on [-1, 1]", fontsize=9)
    ax.legend()
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def markdown_table(rows: list[dict]) -> str:
    """The results as a Markdown table."""
    head = (
        "| figure | method | m | eps | sigma | Jacobian | paths | spread of E x at T "
        "| max abs E x | diverged | wall time [s] |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|\n"
    )
    lines = [
        f"| {r['figure']} | {r['integrator'].upper()} | {r['n_steps']} | {r['epsilon']:g} | "
        f"{r['sigma']:g} | {r['jacobian'] or '-'} | {r['n_paths']} | {r['spread_at_T']:.3g} | "
        f"{r['max_abs_mean_x']:.3g} | {'yes' if r['diverged'] else 'no'} | "
        f"{r['wall_time_s']:.3f} |"
        for r in rows
    ]
    return head + "\n".join(lines) + "\n"


def csv_table(path: Path) -> str:
    """`markdown_table` of a written results.csv: docs/paper.md's table (`agent-envs tables`)."""
    return markdown_table(read_rows(path))


def _progress(runs: tuple[Run, ...]):
    """`runs` with a tqdm bar when tqdm (the ``train`` extra) is installed, else plainly.

    This reproduction needs only the core, so it runs on the minimal install too.
    """
    try:
        from tqdm import tqdm
    except ImportError:
        return runs
    return tqdm(runs, desc="uncontrolled runs", unit="run")


def reproduce(
    out: Path,
    n_agents: int = UncontrolledConfig.n_agents,
    n_paths: int = UncontrolledConfig.n_paths,
    seed: int = UncontrolledConfig.seed,
) -> list[dict]:
    """Run every experiment, write figures, results.md, results.json and results.csv into `out`.

    The defaults are `UncontrolledConfig`'s (the paper's N = 100 and 20 paths, seed 0).
    """
    out.mkdir(parents=True, exist_ok=True)
    runs = PAPER_RUNS + JACOBIAN_STUDY
    results: list[tuple[dict, Trajectory]] = []
    for run in _progress(runs):
        results.append(run_one(run, n_agents, n_paths, seed))
    rows = [row for row, _ in results]
    for figure in dict.fromkeys(r.figure for r in PAPER_RUNS):
        panels = [(row, traj) for row, traj in results if row["figure"] == figure]
        plot_figure(out / f"{figure}.png", panels)
    plot_jacobian_study(
        out / "jacobian_study.png", [r for r in rows if r["figure"] == "jacobian_study"]
    )
    (out / "results.json").write_text(json.dumps(rows, indent=2))
    write_csv(rows, out / "results.csv")
    text = (
        "# Uncontrolled experiments (paper Section 5.1)\n\n"
        f"N = {n_agents} agents uniform on [-1, 1] (seed {seed}), T = 1, alpha = 0.1, "
        f"{n_paths} Brownian paths when sigma > 0. Spread = max_k E x_k(T) - min_k E x_k(T) "
        "(0 = consensus). The Jacobian study starts from evenly spaced positions.\n\n"
        + markdown_table(rows)
    )
    (out / "results.md").write_text(text)
    return rows
