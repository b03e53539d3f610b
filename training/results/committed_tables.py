"""Markdown tables of the committed outputs of the scripts under benchmarks/.

Each function reads one committed file and returns the table the docs publish, digit for digit
(`agent-envs tables` puts it between the page's markers; tests/test_published_tables.py checks
it):

- `env_options_table`: ``benchmarks/env_options.py``'s ``results.json`` (docs/env-options.md):
  per controller (optimal, proportional) the mean cost over the episodes, the largest |u_k^n|
  and |mean_k u_k^n| in action units (u / max_control), the common mode's share of the control
  energy sum |mean_k u|^2 / sum |u|^2, the R^2 of the common control on the centre offset, and
  the cost (and per-episode ratio) of the common mode alone; from the per-episode and per-step
  files beside it (``results_episodes.csv``, ``results_steps.csv``) when they are there;
- `shared_transfer_table`: ``benchmarks/shared_across_n.py``'s ``across_n.csv``
  (docs/learners/shared.md): per swarm size N, each shared policy's mean cost over the test
  seeds with its ratio to the proportional controller's, then the proportional and zero
  controllers' mean costs;
- `max_control_table`: ``benchmarks/max_control.py``'s printed output (docs/envs/gymnasium.md):
  the largest |u_k^n| over the seeds, per (kernel, target) x (integrator, paths); printed from
  its per-seed ``episodes.csv`` when it is there;
- `design_table`: ``benchmarks/task_design.py``'s ``task-design.json`` (docs/tasks.md): per
  task and validation seed the largest |u| of the optimum and of the proportional law, and
  MPC's cost over the open-loop plan's where the task has MPC;
- `apg_paper_table`, `apg_quick_table`, `apg_across_n_table`: ``benchmarks/bench_apg.py``'s
  ``apg/results.json`` (docs/learners/apg.md): per apg run the gap to optimal over the test
  seeds, the cost ratio to the proportional law and the training time; across N, the laws
  trained at N = 100 evaluated at other N; recomputed from its per-episode ``apg/episodes.csv``
  when it is there;
- `mean_field_table`: ``benchmarks/bench_large_swarms.py``'s mean-field rows
  (docs/large-swarms.md): per N, W1 of the empirical distribution at t = 0, T/2, T to the
  largest N's;
- `convergence_orders_table`: ``benchmarks/convergence_orders.py``'s printed table
  (docs/core.md): the measured deterministic and strong orders per scheme.

The outputs of `agent-envs` commands (reproductions, evaluations) have theirs in
`command_tables`.
"""

from __future__ import annotations

import csv
import json
import math
import re
from pathlib import Path

from agent_envs.training.results.apg_episodes import with_episodes
from agent_envs.training.results.env_options_episodes import read_summary
from agent_envs.training.results.episode_csv import read_rows
from agent_envs.training.results.max_control_seeds import setting_lines

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


def env_options_table(
    path: Path, *per_episode: Path, first_cell: str = "figure", r2: bool = True
) -> str:
    """The env-options design table of one ``results.json`` (`r2`: include the R^2 row);
    recomputed from its per-episode and per-step files (`per_episode`, written beside it:
    `env_options_episodes.episode_files`) when both exist."""
    data = json.loads(Path(path).read_text())
    if per_episode and all(Path(p).is_file() for p in per_episode):
        data["seeds"], data["results"] = read_summary(*per_episode)
    episodes = len(data["seeds"])
    lines = [f"| {first_cell} | optimal control | proportional law |", "|---|---|---|"]
    for label, key, fmt in ENV_OPTIONS_ROWS:
        if key == "common_linear_r2" and not r2:
            continue
        cells = [fmt.format(data["results"][p][key]) for p in ENV_OPTIONS_POLICIES]
        cells = [c.replace("%", " %") for c in cells]  # the page's "99.7 %"
        lines.append(f"| {label.format(episodes=episodes)} | {' | '.join(cells)} |")
    return "\n".join(lines)


def _size_rows(rows: list[dict[str, str]], runs: list[str]) -> list[str]:
    """One Markdown row per N of an across_n.csv: each run's mean cost with its ratio to the
    proportional controller, then the proportional and zero controllers' costs."""
    data = {(r["policy"], int(r["n_agents"])): r for r in rows}
    out = []
    for n in sorted({int(r["n_agents"]) for r in rows}):
        cells = [str(n)]
        for run in runs:
            r = data[(run, n)]
            cells.append(f"{float(r['mean_cost']):.4g} ({float(r['ratio_to_proportional']):.2f}x)")
        cells += [f"{float(data[(p, n)]['mean_cost']):.4g}" for p in ("proportional", "zero")]
        out.append("| " + " | ".join(cells) + " |")
    return out


def shared_transfer_table(path: Path) -> str:
    """The parameter-shared learners of the leaderboard (trained at N = 100) at other N, from
    ``across_n.csv`` of `benchmarks/shared_across_n.py --model best` (policies named
    ``shared (TASK__LEARNER__SEED)``): one row per N, each run's mean cost with its ratio to the
    proportional controller, then the proportional and zero controllers."""
    with open(path, newline="") as handle:
        rows = list(csv.DictReader(handle))
    runs = [r["policy"] for r in rows if r["policy"].startswith("shared")]
    runs = list(dict.fromkeys(runs))
    names = [run[run.index("(") + 1 : -1].split("__", 1)[1] for run in runs]
    heads = " | ".join(name.replace("__", " seed ") for name in names)
    lines = [f"| N | {heads} | proportional | zero |", "|" + "---|" * (len(runs) + 3)]
    return "\n".join(lines + _size_rows(rows, runs))


#: (kernel, xbar) -> the row label of the max_control table, in page order
MAX_CONTROL_SETTINGS: dict[tuple[str, float], str] = {
    ("symmetric", 0.7): "symmetric eps = 0.05, xbar = 0.7",
    ("symmetric", -1.7): "symmetric eps = 0.05, xbar = -1.7",
    ("nonsymmetric", 2.3): "non-symmetric eps in [0.01, 0.1], xbar = 2.3",
}
#: the max_control table's columns: (integrator, paths)
MAX_CONTROL_COLUMNS = (("serb", 20), ("em", 20), ("serb", 1), ("em", 1))
_MAX_CONTROL_LINE = re.compile(r"^\s*(\w+)\s+(-?[\d.]+)\s+(serb|em)\s+(\d+) \|\s+([\d.]+)", re.M)


def max_control_peaks(path: Path, *per_seed: Path) -> dict[tuple[str, float, str, int], float]:
    """(kernel, xbar, integrator, paths) -> the largest |u_k^n| of max_control.py's output
    (`path`), or of the output printed from its per-seed file (`per_seed`) when it exists: the
    peaks as printed (2 decimals), so both give the same table."""
    if per_seed and all(Path(p).is_file() for p in per_seed):
        text = "\n".join(setting_lines(read_rows(per_seed[0])))
    else:
        text = Path(path).read_text()
    return {
        (kernel, float(xbar), integrator, int(paths)): float(peak)
        for kernel, xbar, integrator, paths, peak in _MAX_CONTROL_LINE.findall(text)
    }


def max_control_table(path: Path, *per_seed: Path) -> str:
    """The "Why max_control = 150" table: peaks to one decimal (`max_control_peaks`)."""
    peaks = max_control_peaks(path, *per_seed)
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


def apg_results(path: Path, *per_episode: Path) -> dict:
    """``apg/results.json``, its gaps and ratios recomputed from the per-episode file
    (`per_episode`: ``apg/episodes.csv``, `apg_episodes.with_episodes`) when it exists."""
    data = json.loads(Path(path).read_text())
    if per_episode and all(Path(p).is_file() for p in per_episode):
        data = with_episodes(data, read_rows(per_episode[0]))
    return data


def apg_quick_table(path: Path, *per_episode: Path) -> str:
    """docs/learners/apg.md's quick-setting table from ``apg/results.json`` (part ``quick``):
    per training seed the gap to optimal, mean over the test seeds of (J - V) / V with its
    min and max, the paired cost ratio to the proportional law, and CPU (wall) training time."""
    runs = apg_results(path, *per_episode)["quick"]["runs"]
    lines = [
        "| training seed | gap to optimal [min, max] | cost / proportional's | "
        "training time, CPU (wall) |",
        "|---|---|---|---|",
    ]
    lines += [f"| {run['seed']} | {_apg_run_cells(run, minutes=False)} |" for run in runs]
    return "\n".join(lines)


def apg_paper_table(path: Path, *per_episode: Path) -> str:
    """docs/learners/apg.md's paper-setting table from ``apg/results.json`` (parts ``paper``
    and ``paper-linear``, the law without its MLP): the quick table's columns, one row per
    run, then the proportional law's gap (beta = 12) over the same test seeds."""
    data = apg_results(path, *per_episode)
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


#: row labels of apg's across-N table beyond the plain N
APG_N_LABELS = {100: "100 (trained here)", 10_000: '10 000 (`linear_operator = "matrix_free"`)'}


def apg_across_n_table(path: Path, *per_episode: Path) -> str:
    """docs/learners/apg.md's across-N table from ``apg/results.json`` (``across-n`` rows and,
    at the training size N = 100, the ``paper`` runs): per N the gap to optimal of each
    training seed's law, mean [worst] over the test seeds, the proportional law's gap, and
    each law's cost ratio to the proportional law; "not solved" where no optimum was solved."""
    data = apg_results(path, *per_episode)
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


#: docs/learners/apg.md's contrasts: bench_apg.py part -> row label
APG_CONTRASTS = {
    "eps1": "eps = 1 (non-stiff), SERB",
    "em-serb": "train on EM, evaluate on SERB (eps = 0.05)",
    "em-serb-eps1": "train on EM, evaluate on SERB (eps = 1)",
}


def apg_contrasts_table(path: Path, *per_episode: Path) -> str:
    """docs/learners/apg.md's contrasts from ``apg/results.json`` (parts of `APG_CONTRASTS`,
    recomputed from the per-episode file): per training seed the gap to optimal, mean over the
    test seeds (worst test episode), the proportional law's gap and the optimum's mean cost V
    of the evaluation env, and the CPU training time per seed."""
    data = apg_results(path, *per_episode)
    lines = [
        "| contrast | gap to optimal per training seed, mean over 20 test seeds (worst) | "
        "proportional's gap | V | training time, CPU per seed |",
        "|---|---|---|---|---|",
    ]
    for part, label in APG_CONTRASTS.items():
        value = data[part]
        runs = value["runs"]
        gaps = ", ".join(f"{r['gap']['mean']:+.2%} ({r['gap']['max']:+.2%})" for r in runs)
        cpu = ", ".join(f"{r['cpu_time_s'] / 60:.1f}" for r in runs)
        lines.append(
            f"| {label} | {gaps} | {value['proportional_gap']['mean']:+.2%} | "
            f"{value['optimal_mean_cost']:.4g} | {cpu} min |"
        )
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


def _short_exponent(value: float) -> str:
    """3 significant digits in the page's "1.55e-2" form (no exponent padding)."""
    mantissa, exponent = f"{value:.2e}".split("e")
    return f"{mantissa}e{int(exponent)}"


def mean_field_table(path: Path) -> str:
    """docs/large-swarms.md's mean-field check from ``benchmarks/bench_large_swarms.py
    --parts mean-field --mean-field-csv``'s rows: per N below the reference, the
    Wasserstein-1 distance of the empirical distribution at t = 0, T/2 and T to the
    reference N's, 3 significant digits."""
    with open(path, newline="") as handle:
        rows = list(csv.DictReader(handle))
    reference = {r["reference_n"] for r in rows}
    if len(reference) != 1:
        raise ValueError(f"{path}: rows of more than one reference N: {sorted(reference)}")
    w1 = {(int(r["n_agents"]), r["time"]): float(r["w1_to_reference"]) for r in rows}
    largest = int(reference.pop())
    sizes = sorted({n for n, _ in w1 if n != largest})
    lines = ["| N | W1 at t = 0 | W1 at T/2 | W1 at T |", "|---|---|---|---|"]
    for n in sizes:
        cells = " | ".join(_short_exponent(w1[(n, t)]) for t in ("0", "T/2", "T"))
        lines.append(f"| 10^{round(math.log10(n))} | {cells} |")
    return "\n".join(lines)
