"""Markdown tables of the committed outputs of `agent-envs` commands, as the docs publish them.

Each function reads one committed file under docs/results/ and returns the page's table digit
for digit (`agent-envs tables` puts it between the page's markers;
tests/test_published_tables.py checks it):

- `turnpike_table`: ``agent-envs reproduce turnpike``'s ``results.csv`` (docs/paper.md): one
  seed's runs and modes (tbar, L = ||E x - xbar||^2 at tbar and at T, RMS distance, cost,
  max |u|, diverged);
- `turnpike_property_table`: ``agent-envs reproduce turnpike-property``'s
  ``turnpike_property.csv`` (docs/turnpike-theory.md): per setting the entry rate, the share of
  the horizon within delta, V and the lemma's bound over V;
- `evaluation_table`: ``agent-envs evaluate``'s ``episodes.csv`` files (docs/evaluate.md): per
  env and policy the mean cost with its 95% t-interval, the ratio to the turnpike controller's
  mean cost, the mean final RMS distance and control energy;
- `optimum_table`: one ``agent-envs evaluate`` episodes file with the optimum evaluated
  (docs/optimum.md): per policy the mean cost and the per-seed gap to optimal (cost - V) / V,
  each with its 95% t-interval, the mean final RMS distance and control energy;
- `em_transfer_table`: ``agent-envs compare``'s EM-trained runs evaluated on EM and on SERB
  (docs/results.md): per policy the mean cost and the paired ratio to the proportional
  controller on each integrator, by training seed, beside the SERB-trained quick runs.

The benchmark scripts' outputs have theirs in `committed_tables`.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

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


#: the EM-to-SERB table's rows: (policy, label), in page order
EM_TRANSFER_ROWS = (
    ("ppo", "ppo (trained on EM)"),
    ("ppo-shared", "ppo-shared (trained on EM)"),
    ("proportional-common", "proportional-common"),
    ("proportional", "proportional"),
    ("zero", "zero"),
    ("turnpike", "turnpike"),
    ("optimal", "optimal (open-loop plan; on EM the solver stalls at u = 0)"),
)


def _paired_ratio(costs: Any, policy: str, base: str = "proportional") -> float:
    """The mean over the seeds of `policy`'s cost over `base`'s on the same seed."""
    return float((costs[policy] / costs[base]).mean())


def em_transfer_table(*files: Path) -> str:
    """docs/results.md's train-on-EM, deploy-on-SERB table from ``agent-envs compare
    --env-kwargs '{"integrator": "em"}' --eval-env-kwargs '{"integrator": "serb"}'``'s
    episodes files: `files` = for each training seed its ``evaluation/episodes.csv`` (EM) and
    ``evaluation_transfer/episodes.csv`` (SERB), then the SERB-trained quick runs'
    ``episodes.csv``, one per training seed in the same order. Per policy the mean cost on EM
    and on SERB and the mean paired ratio to the proportional controller on each; a learner's
    cells are its training seeds' ("a / b / c"), a reference's are one value (they do not
    train; the table checks that every run agrees)."""
    import pandas as pd

    if len(files) % 3 or not files:
        raise ValueError(
            f"files: expected 3 per training seed (EM, SERB, SERB-trained), got {len(files)}"
        )
    n_seeds = len(files) // 3
    costs = [
        pd.read_csv(path).pivot(index="seed", columns="policy", values="total_cost")
        for path in files
    ]
    runs = list(zip(costs[0 : 2 * n_seeds : 2], costs[1 : 2 * n_seeds : 2], strict=True))
    serb_trained = costs[2 * n_seeds :]
    lines = [
        "| policy | cost on EM | paired ratio to proportional on EM | cost on SERB | "
        "paired ratio to proportional on SERB | SERB-trained policy on SERB |",
        "|---|---|---|---|---|---|",
    ]
    for policy, label in EM_TRANSFER_ROWS:
        learner = policy in ("ppo", "ppo-shared")
        cells = []
        for index in (0, 1):
            means = [f"{run[index][policy].mean():.4g}" for run in runs]
            ratios = [f"{_paired_ratio(run[index], policy):.3f}" for run in runs]
            if not learner and (len(set(means)) > 1 or len(set(ratios)) > 1):
                raise ValueError(f"{policy}: the runs disagree on a reference ({means})")
            cells += [" / ".join(means if learner else means[:1])]
            cells += [" / ".join(ratios if learner else ratios[:1])]
        trained = " / ".join(f"{run[policy].mean():.4g}" for run in serb_trained) if learner else ""
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {trained} |")
    return "\n".join(lines)
