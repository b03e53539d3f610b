"""Markdown tables of the committed outputs of the design scripts under benchmarks/.

Each function reads one committed file and returns the table the docs publish, digit for digit
(`agent-envs tables` puts it between the page's markers; tests/test_published_tables.py checks
it):

- `env_options_table`: ``benchmarks/env_options.py``'s ``results.json`` (docs/env-options.md):
  per controller (optimal, proportional) the mean cost over the episodes, the largest |u_k^n|
  and |mean_k u_k^n| in action units (u / max_control), the common mode's share of the control
  energy sum |mean_k u|^2 / sum |u|^2, the R^2 of the common control on the centre offset, and
  the cost (and per-episode ratio) of the common mode alone;
- `across_n_table`: ``benchmarks/shared_across_n.py``'s ``across_n.csv`` (docs/results.md):
  per swarm size N, each shared policy's mean cost over the test seeds with its ratio to the
  proportional controller's, then the proportional and zero controllers' mean costs;
- `max_control_table`: ``benchmarks/max_control.py``'s printed output (docs/envs/gymnasium.md):
  the largest |u_k^n| over the seeds, per (kernel, target) x (integrator, paths);
- `design_table`: ``benchmarks/task_design.py``'s ``task-design.json`` (docs/tasks.md): per
  task and validation seed the largest |u| of the optimum and of the proportional law, and
  MPC's cost over the open-loop plan's where the task has MPC;
- `apg_paper_table`, `apg_quick_table`, `apg_across_n_table`: ``benchmarks/bench_apg.py``'s
  ``apg/results.json`` (docs/learners/apg.md): per apg run the gap to optimal over the test
  seeds, the cost ratio to the proportional law and the training time; across N, the laws
  trained at N = 100 evaluated at other N;
- `turnpike_table`: ``agent-envs reproduce turnpike``'s ``results.csv`` (docs/paper.md): one
  seed's runs and modes (tbar, L = ||E x - xbar||^2 at tbar and at T, RMS distance, cost,
  max |u|, diverged);
- `evaluation_table`: ``agent-envs evaluate``'s ``episodes.csv`` files (docs/evaluate.md): per
  env and policy the mean cost with its 95% t-interval, the ratio to the turnpike controller's
  mean cost, the mean final RMS distance and control energy;
- `turnpike_property_table`: ``agent-envs reproduce turnpike-property``'s
  ``turnpike_property.csv`` (docs/turnpike-theory.md): per setting the entry rate, the share of
  the horizon within delta, V and the lemma's bound over V;
- `optimum_table`: one ``agent-envs evaluate`` episodes file with the optimum evaluated
  (docs/optimum.md): per policy the mean cost and the per-seed gap to optimal, each with its
  95% t-interval, the mean final RMS distance and control energy;
- `convergence_orders_table`: ``benchmarks/convergence_orders.py``'s printed table
  (docs/core.md): the measured deterministic and strong orders per scheme.
"""

from __future__ import annotations

import csv
import json
import math
import re
from collections.abc import Sequence
from pathlib import Path

#: (label, key in results.json, format) of the env-options table's rows, in page order
ENV_OPTIONS_ROWS: tuple[tuple[str, str, str], ...] = (
    ("mean cost ({episodes} episodes)", "cost", "{:.4g}"),
    ("largest \\|u_k^n\\| / max_control", "max_abs_u_action_units", "{:.3f}"),
    ("largest \\|mean_k u_k^n\\| / max_control", "max_abs_common_u_action_units", "{:.3f}"),
    ("common mode's share of the control energy", "common_energy_share", "{:.1%}"),
    ("R^2 of the common control on xbar - c^n, one gain per step", "common_linear_r2", "{:.3f}"),
    ('cost with the common mode alone (`action_basis="common"`)', "common_only_cost", "{:.4g}"),
    ("... per episode, against the controller itself", "common_only_ratio", "{:.3f}"),
)
#: the env-options table's columns: the controllers of results.json
ENV_OPTIONS_POLICIES = ("optimal", "proportional")


def env_options_table(path: Path, first_cell: str = "figure", r2: bool = True) -> str:
    """The env-options design table of one ``results.json`` (`r2`: include the R^2 row)."""
    data = json.loads(Path(path).read_text())
    episodes = len(data["seeds"])
    lines = [f"| {first_cell} | optimal control | proportional law |", "|---|---|---|"]
    for label, key, fmt in ENV_OPTIONS_ROWS:
        if key == "common_linear_r2" and not r2:
            continue
        cells = [fmt.format(data["results"][p][key]) for p in ENV_OPTIONS_POLICIES]
        cells = [c.replace("%", " %") for c in cells]  # the page's "99.7 %"
        lines.append(f"| {label.format(episodes=episodes)} | {' | '.join(cells)} |")
    return "\n".join(lines)


def across_n_table(path: Path) -> str:
    """The shared policy across swarm sizes, from ``across_n.csv`` (columns policy, n_agents,
    mean_cost, ratio_to_proportional, ...): costs to 4 significant digits, ratios to 2
    decimals."""
    with open(path, newline="") as handle:
        rows = list(csv.DictReader(handle))
    shared = sorted({r["policy"] for r in rows if r["policy"].startswith("shared")})
    sizes = sorted({int(r["n_agents"]) for r in rows})
    data = {(r["policy"], int(r["n_agents"])): r for r in rows}
    seeds = " | ".join(f"seed {i}" for i in range(1, len(shared)))
    lines = [
        f"| N | ppo-shared seed 0 | {seeds} | proportional | zero |",
        "|" + "---|" * (len(shared) + 3),
    ]
    for n in sizes:
        cells = [str(n)]
        for policy in shared:
            r = data[(policy, n)]
            cells.append(f"{float(r['mean_cost']):.4g} ({float(r['ratio_to_proportional']):.2f}x)")
        cells += [f"{float(data[(p, n)]['mean_cost']):.4g}" for p in ("proportional", "zero")]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


#: (kernel, xbar) -> the row label of the max_control table, in page order
MAX_CONTROL_SETTINGS: dict[tuple[str, float], str] = {
    ("symmetric", 0.7): "symmetric eps = 0.05, xbar = 0.7",
    ("symmetric", -1.7): "symmetric eps = 0.05, xbar = -1.7",
    ("nonsymmetric", 2.3): "non-symmetric eps in [0.01, 0.1], xbar = 2.3",
}
#: the max_control table's columns: (integrator, paths)
MAX_CONTROL_COLUMNS = (("serb", 20), ("em", 20), ("serb", 1), ("em", 1))
_MAX_CONTROL_LINE = re.compile(r"^\s*(\w+)\s+(-?[\d.]+)\s+(serb|em)\s+(\d+) \|\s+([\d.]+)", re.M)


def max_control_peaks(path: Path) -> dict[tuple[str, float, str, int], float]:
    """(kernel, xbar, integrator, paths) -> the largest |u_k^n| of max_control.py's output."""
    return {
        (kernel, float(xbar), integrator, int(paths)): float(peak)
        for kernel, xbar, integrator, paths, peak in _MAX_CONTROL_LINE.findall(
            Path(path).read_text()
        )
    }


def max_control_table(path: Path) -> str:
    """The "Why max_control = 150" table: peaks to one decimal."""
    peaks = max_control_peaks(path)
    header = " | ".join(
        f"{integrator.upper()}, {paths} path{'s' if paths > 1 else ''}"
        for integrator, paths in MAX_CONTROL_COLUMNS
    )
    lines = [f"| setting | {header} |", "|" + "---|" * (len(MAX_CONTROL_COLUMNS) + 1)]
    for (kernel, xbar), label in MAX_CONTROL_SETTINGS.items():
        cells = [f"{peaks[(kernel, xbar, i, p)]:.1f}" for i, p in MAX_CONTROL_COLUMNS]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def design_table(rows: list[dict]) -> str:
    """The task-design table of ``task-design.json``'s rows: max |u| to 2 decimals, the
    MPC / open loop cost ratio to 3 ("-" where the task has no MPC reference)."""
    lines = [
        "| task | seed | optimal max \\|u\\| | proportional max \\|u\\| | MPC / open loop |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        ratio = f"{r['mpc_cost'] / r['optimal_cost']:.3f}" if "mpc_cost" in r else "-"
        lines.append(
            f"| `{r['task']}` | {r['seed']} | {r['optimal_max_u']:.2f} | "
            f"{r['proportional_max_u']:.2f} | {ratio} |"
        )
    return "\n".join(lines)


def _apg_run_cells(run: dict, minutes: bool) -> str:
    """gap [min, max] | cost / proportional's | CPU (wall) training time of one apg run."""
    gap = run["gap"]
    if minutes:
        time = f"{run['cpu_time_s'] / 60:.1f} min ({run['wall_time_s'] / 60:.1f} min)"
    else:
        time = f"{run['cpu_time_s']:.1f} s ({run['wall_time_s']:.0f} s)"
    return (
        f"{gap['mean']:+.3%} [{gap['min']:+.3%}, {gap['max']:+.3%}] | "
        f"{run['ratio_to_proportional']:.4f} | {time}"
    )


def apg_quick_table(path: Path) -> str:
    """docs/learners/apg.md's quick-setting table from ``apg/results.json`` (part ``quick``):
    per training seed the gap to optimal, mean over the test seeds of (J - V) / V with its
    min and max, the paired cost ratio to the proportional law, and CPU (wall) training time."""
    runs = json.loads(Path(path).read_text())["quick"]["runs"]
    lines = [
        "| training seed | gap to optimal [min, max] | cost / proportional's | "
        "training time, CPU (wall) |",
        "|---|---|---|---|",
    ]
    lines += [f"| {run['seed']} | {_apg_run_cells(run, minutes=False)} |" for run in runs]
    return "\n".join(lines)


def apg_paper_table(path: Path) -> str:
    """docs/learners/apg.md's paper-setting table from ``apg/results.json`` (parts ``paper``
    and ``paper-linear``, the law without its MLP): the quick table's columns, one row per
    run, then the proportional law's gap (beta = 12) over the same test seeds."""
    data = json.loads(Path(path).read_text())
    lines = [
        "| policy | gap to optimal, mean over 20 test seeds [min, max] | cost / proportional's | "
        "training time, CPU (wall) |",
        "|---|---|---|---|",
    ]
    for run in data["paper"]["runs"]:
        lines.append(f"| apg, seed {run['seed']} | {_apg_run_cells(run, minutes=True)} |")
    for run in data["paper-linear"]["runs"]:
        cells = _apg_run_cells(run, minutes=True)
        lines.append(f"| apg without its MLP (`hidden = 0`), seed {run['seed']} | {cells} |")
    gap = data["paper"]["proportional_gap"]
    lines.append(
        f"| proportional (beta = 12) | {gap['mean']:+.2%} [{gap['min']:+.2%}, "
        f"{gap['max']:+.2%}] | 1 | - |"
    )
    return "\n".join(lines)


#: the turnpike table's columns after run and mode: (header, results.csv column)
TURNPIKE_COLUMNS = (
    ("tbar", "tbar"),
    ("L at tbar", "L_at_tbar"),
    ("L at T", "L_at_T"),
    ("RMS dist. at T", "rms_distance_at_T"),
    ("cost", "total_cost"),
    ("max abs u", "max_abs_u"),
)
_KERNELS = {"symmetric": "sym.", "nonsymmetric": "non-sym."}


def turnpike_table(path: Path, seed: int = 0) -> str:
    """docs/paper.md's Section 5.2 table: `seed`'s rows of ``agent-envs reproduce turnpike``'s
    ``results.csv`` (one row per run and mode), every figure to 3 significant digits."""
    with open(path, newline="") as handle:
        rows = [r for r in csv.DictReader(handle) if int(r["seed"]) == seed]
    header = " | ".join(h for h, _ in TURNPIKE_COLUMNS)
    lines = [f"| run | mode | {header} | diverged |", "|" + "---|" * (len(TURNPIKE_COLUMNS) + 3)]
    for r in rows:
        scheme = r["integrator"].replace(" (exact J)", " exact J")
        run = f"{scheme}, {_KERNELS[r['kernel']]}, xbar = {float(r['target']):g}"
        cells = [f"{float(r[column]):.3g}" for _, column in TURNPIKE_COLUMNS]
        diverged = "yes" if r["diverged"] == "True" else "no"
        lines.append(f"| {run} | {r['mode']} | " + " | ".join(cells) + f" | {diverged} |")
    return "\n".join(lines)


def _digits(value: float, significant: int, decimals: int) -> str:
    """`value` with at least `significant` significant digits and at least `decimals`
    decimals ("0" for zero): 7.371, 0.340, 0.0763 (3, 3); 731.9, 4.50 (3, 1)."""
    if value == 0:
        return "0"
    exponent = math.floor(math.log10(abs(value)))
    return f"{value:.{max(decimals, significant - 1 - exponent, 0)}f}"


def evaluation_table(files: Sequence[tuple[str, Path]], reference: str = "turnpike") -> str:
    """docs/evaluate.md's table from ``agent-envs evaluate``'s ``episodes.csv`` files, one per
    env (label, path): per policy (in file order) the mean total cost with its 95% t-interval
    over the episodes, the ratio of its mean cost to `reference`'s, the mean final RMS
    distance to the target and the mean control energy."""
    import pandas as pd

    from agent_envs.training.results.tables import mean_confidence_interval

    lines = [
        f"| env | policy | mean cost [95% CI] | ratio to {reference} | final RMS distance | "
        "control energy |",
        "|---|---|---|---|---|---|",
    ]
    for label, path in files:
        episodes = pd.read_csv(path)
        by_policy = episodes.groupby("policy", sort=False)
        base = by_policy["total_cost"].mean()[reference]
        for policy, rows in by_policy:
            mean, low, high = mean_confidence_interval(rows["total_cost"])
            cost = " ".join(
                (_digits(mean, 3, 3), f"[{_digits(low, 3, 3)},", f"{_digits(high, 3, 3)}]")
            )
            ratio = "1" if policy == reference else f"{mean / base:#.3g}"
            distance = f"{rows['final_distance'].mean():#.3g}"
            energy = _digits(float(rows["control_energy"].mean()), 3, 1)
            lines.append(f"| {label} | {policy} | {cost} | {ratio} | {distance} | {energy} |")
    return "\n".join(lines)


#: the turnpike-property table's rows: (kernel, epsilon, sigma), in page order
TURNPIKE_PROPERTY_SETTINGS = (
    ("symmetric", 0.05, 0.0),
    ("symmetric", 0.05, 0.01),
    ("symmetric", 0.05, 0.1),
    ("symmetric", 1.0, 0.0),
    ("symmetric", 1.0, 0.1),
    ("nonsymmetric", 0.05, 0.0),
    ("nonsymmetric", 0.05, 0.01),
    ("nonsymmetric", 0.05, 0.1),
    ("nonsymmetric", 1.0, 0.1),
)
#: the horizons of the share column
TURNPIKE_SHARE_HORIZONS = (1.0, 2.0, 4.0, 8.0)


def _ratio_text(value: float) -> str:
    """3 significant digits below 1000 (270, 251), else 2 in the page's "1.2e5" form."""
    if value < 1000:
        return f"{value:.3g}"
    mantissa, exponent = f"{value:.1e}".split("e")
    return f"{mantissa}e{int(exponent)}"


def turnpike_property_table(path: Path) -> str:
    """docs/turnpike-theory.md's findings from ``agent-envs reproduce turnpike-property``'s
    ``turnpike_property.csv`` (seed 0): per setting the entry arc's fitted rate and the lemma's
    bound over V at the longest horizon, the share of the horizon with D_n <= delta per T, and
    V at the shortest and the longest horizon."""
    with open(path, newline="") as handle:
        rows = [r for r in csv.DictReader(handle) if r["seed"] == "0"]
    lines = [
        "| setting | entry rate | share within delta, T = "
        + " / ".join(f"{t:g}" for t in TURNPIKE_SHARE_HORIZONS)
        + " | V, T = 0.5 -> 8 | bound / V |",
        "|---|---|---|---|---|",
    ]
    for kernel, epsilon, sigma in TURNPIKE_PROPERTY_SETTINGS:
        by_t = {
            float(r["T"]): r
            for r in rows
            if (r["kernel"], float(r["epsilon"]), float(r["sigma"])) == (kernel, epsilon, sigma)
        }
        first, last = by_t[min(by_t)], by_t[max(by_t)]
        name = "non-symmetric" if kernel == "nonsymmetric" else kernel
        shares = " / ".join(
            f"{float(by_t[t]['share_within_delta']):.2f}" for t in TURNPIKE_SHARE_HORIZONS
        )
        lines.append(
            f"| {name} eps = {epsilon:g}, sigma = {sigma:g} | {float(last['entry_rate']):.3g} | "
            f"{shares} | {float(first['V']):.5f} -> {float(last['V']):.5f} | "
            f"{_ratio_text(float(last['bound_over_V']))} |"
        )
    return "\n".join(lines)


#: row labels of apg's across-N table beyond the plain N
APG_N_LABELS = {100: "100 (trained here)", 10_000: '10 000 (`linear_operator = "matrix_free"`)'}


def apg_across_n_table(path: Path) -> str:
    """docs/learners/apg.md's across-N table from ``apg/results.json`` (``across-n`` rows and,
    at the training size N = 100, the ``paper`` runs): per N the gap to optimal of each
    training seed's law, mean [worst] over the test seeds, the proportional law's gap, and
    each law's cost ratio to the proportional law; "not solved" where no optimum was solved."""
    data = json.loads(Path(path).read_text())
    trained = data["paper"]
    by_n: dict[int, list[dict]] = {
        100: [
            {**run, "proportional_gap": trained["proportional_gap"]["mean"]}
            for run in trained["runs"]
        ]
    }
    for row in data["across-n"]["rows"]:
        by_n.setdefault(row["n_agents"], []).append(row)
    lines = [
        "| N | gap to optimal, per training seed: mean [worst] over 20 test seeds | "
        "proportional's gap | cost / proportional's, per training seed |",
        "|---|---|---|---|",
    ]
    unsolved = 0
    for n in sorted(by_n):
        runs = sorted(by_n[n], key=lambda r: r["seed"])
        ratios = ", ".join(f"{r['ratio_to_proportional']:.4f}" for r in runs)
        if all("gap" in r for r in runs):
            gaps = ", ".join(f"{r['gap']['mean']:+.2%} [{r['gap']['max']:+.2%}]" for r in runs)
            proportional = f"{runs[0]['proportional_gap']:+.2%}"
        else:
            gaps = "not solved (below)" if unsolved == 0 else "not solved"
            proportional, unsolved = "not solved", unsolved + 1
        lines.append(f"| {APG_N_LABELS.get(n, n)} | {gaps} | {proportional} | {ratios} |")
    return "\n".join(lines)


def _gap_text(percent: float) -> str:
    """A gap in percent: 2 decimals below 1% (-0.00%), else 3 significant digits (+33.3%,
    +558%) and no decimals from 1000% on (+4671%)."""
    text = f"{percent:+.2f}" if abs(percent) < 1 else _digits(percent, 3, 0)
    return (text if text[0] in "+-" else "+" + text) + "%"


def optimum_table(path: Path, optimum: str = "optimal") -> str:
    """docs/optimum.md's gap-to-optimal table from one ``agent-envs evaluate`` episodes file:
    per policy the mean cost with its 95% t-interval, the gap to optimal (the mean over the
    seeds of (cost - V) / V, V = `optimum`'s cost on the same seed, with its t-interval; "0"
    for the optimum itself), the mean final RMS distance and control energy."""
    import pandas as pd

    from agent_envs.training.results.tables import mean_confidence_interval

    episodes = pd.read_csv(path)
    costs = episodes.pivot(index="seed", columns="policy", values="total_cost")
    lines = [
        "| policy | mean cost [95% CI] | gap to optimal [95% CI] | final RMS distance | "
        "control energy |",
        "|---|---|---|---|---|",
    ]
    for policy, rows in episodes.groupby("policy", sort=False):
        mean, low, high = (f"{v:.4g}" for v in mean_confidence_interval(rows["total_cost"]))
        gaps = 100 * (costs[policy] - costs[optimum]) / costs[optimum]
        g, lo, hi = (_gap_text(v) for v in mean_confidence_interval(gaps))
        gap_text = "0" if policy == optimum else f"{g} [{lo}, {hi}]"
        distance = _digits(float(rows["final_distance"].mean()), 3, 4)
        energy = f"{rows['control_energy'].mean():.4g}"
        lines.append(f"| {policy} | {mean} [{low}, {high}] | {gap_text} | {distance} | {energy} |")
    return "\n".join(lines)


#: the core page's names of the convergence script's schemes (EM without noise is explicit Euler)
SCHEME_LABELS = {"em": "em / ee"}


def convergence_orders_table(path: Path) -> str:
    """docs/core.md's measured orders from ``benchmarks/convergence_orders.py``'s printed table
    (fitted slopes of log error against log tau): its rows, the schemes named as the page names
    them."""
    lines = [line for line in Path(path).read_text().splitlines() if line.startswith("|")]
    out = lines[:2]
    for line in lines[2:]:
        cells = line.strip("|").split("|")
        scheme = cells[0].strip()
        cells[0] = f" {SCHEME_LABELS.get(scheme, scheme)} "
        out.append("|" + "|".join(cells) + "|")
    return "\n".join(out)
