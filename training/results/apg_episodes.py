"""``benchmarks/bench_apg.py``'s per-episode file and the gaps it aggregates to.

One row per (part, N, training seed, test seed): the apg law's cost J, the optimum's V (the
open-loop plan solved from the episode's start; empty where the part solved none) and the
proportional law's cost P on the same test episode, in the columns ``part``, ``n_agents``,
``training_seed``, ``test_seed``, ``apg_cost``, ``optimal_cost``, ``proportional_cost``.

Per training seed of a part, over its test seeds s (sorted): the gap to optimal
(J_s - V_s) / V_s, its mean, min, max and worst seed (`gap_stats`), the mean over s of
J_s / P_s (``ratio_to_proportional``) and the mean cost; per part, the mean V and the
proportional law's gap (P_s - V_s) / V_s. `learned_figures` and `across_n_figures` compute
them; the script writes its ``results.json`` from the same functions of the same rows, and
`with_episodes` puts them back into a written ``results.json`` (whose training and evaluation
times are per run, not per episode), so docs/learners/apg.md's tables are recomputable from the
episodes bit for bit.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from agent_envs.training.results.episode_csv import Row

#: the per-episode file's name, written beside ``results.json``
EPISODES_FILE = "episodes.csv"
#: the part of the laws trained at N = 100 evaluated at other N
ACROSS_N = "across-n"


def gap_stats(costs: dict[int, float], reference: dict[int, float]) -> dict[str, Any]:
    """cost_s / reference_s - 1 over the seeds both have (sorted): mean, min, max, worst."""
    seeds = sorted(set(costs) & set(reference))
    gaps = np.array([costs[s] / reference[s] - 1.0 for s in seeds])
    return {
        "seeds": seeds,
        "mean": float(gaps.mean()),
        "min": float(gaps.min()),
        "max": float(gaps.max()),
        "worst_seed": int(seeds[int(np.argmax(gaps))]),
    }


def episode_rows(
    part: str,
    n_agents: int,
    training_seed: int,
    costs: dict[int, float],
    optimum: dict[int, float] | None,
    proportional: dict[int, float],
) -> list[Row]:
    """The rows of one law's evaluation: test seed -> cost of the law (`costs`), of the
    optimum (None: not solved) and of the proportional law."""
    return [
        {
            "part": part,
            "n_agents": n_agents,
            "training_seed": training_seed,
            "test_seed": seed,
            "apg_cost": float(cost),
            "optimal_cost": None if optimum is None else float(optimum[seed]),
            "proportional_cost": float(proportional[seed]),
        }
        for seed, cost in costs.items()
    ]


def _costs(rows: list[Row], column: str) -> dict[int, float]:
    return {int(r["test_seed"]): float(r[column]) for r in rows}


def law_figures(rows: list[Row]) -> dict[str, Any]:
    """One law's figures from its rows: ``ratio_to_proportional``, ``mean_cost`` and, where
    the optimum was solved, ``gap`` and the proportional law's ``proportional_gap``."""
    costs, proportional = _costs(rows, "apg_cost"), _costs(rows, "proportional_cost")
    figures: dict[str, Any] = {
        "ratio_to_proportional": gap_stats(costs, proportional)["mean"] + 1.0,
        "mean_cost": float(np.mean(list(costs.values()))),
    }
    if all(r["optimal_cost"] is not None for r in rows):
        optimum = _costs(rows, "optimal_cost")
        figures["gap"] = gap_stats(costs, optimum)
        figures["proportional_gap"] = gap_stats(proportional, optimum)
        figures["optimal_mean_cost"] = float(np.mean(list(optimum.values())))
    return figures


def _laws(rows: list[Row], part: str) -> dict[tuple[int, int], list[Row]]:
    """(n_agents, training seed) -> that law's rows of `part`, in the rows' order."""
    laws: dict[tuple[int, int], list[Row]] = {}
    for row in rows:
        if row["part"] == part:
            laws.setdefault((int(row["n_agents"]), int(row["training_seed"])), []).append(row)
    return laws


def learned_figures(rows: list[Row], part: str) -> dict[tuple[int, int], dict[str, Any]]:
    """(n_agents, training seed) -> `law_figures` of each law of a trained part."""
    return {key: law_figures(law) for key, law in _laws(rows, part).items()}


def with_episodes(results: dict[str, Any], rows: list[Row]) -> dict[str, Any]:
    """`results` (a written ``results.json``) with every gap, ratio and mean cost recomputed
    from the per-episode `rows`; its times and failed runs as written."""
    out = {part: dict(value) for part, value in results.items()}
    for part, value in out.items():
        laws = learned_figures(rows, part)
        if not laws:
            continue
        if part == ACROSS_N:
            value["rows"] = [
                {**row, **_across_n_cells(laws[(row["n_agents"], row["seed"])])}
                for row in value["rows"]
            ]
            continue
        runs = []
        for run in value["runs"]:
            found = [f for (_, seed), f in laws.items() if seed == run["seed"]]
            runs.append({**run, **_run_cells(found[0])} if found and "failed" not in run else run)
        first = next(iter(laws.values()))
        value["runs"] = runs
        value["optimal_mean_cost"] = first["optimal_mean_cost"]
        value["proportional_gap"] = first["proportional_gap"]
    return out


def _run_cells(figures: dict[str, Any]) -> dict[str, Any]:
    """The cells of a trained part's run in ``results.json``."""
    return {k: figures[k] for k in ("gap", "ratio_to_proportional", "mean_cost")}


def _across_n_cells(figures: dict[str, Any]) -> dict[str, Any]:
    """The cells of an across-N row in ``results.json`` (the gaps where the optimum was
    solved: the proportional law's as its mean)."""
    cells: dict[str, Any] = {"ratio_to_proportional": figures["ratio_to_proportional"]}
    if "gap" in figures:
        cells["gap"] = figures["gap"]
        cells["proportional_gap"] = figures["proportional_gap"]["mean"]
    return cells


__all__ = [
    "ACROSS_N",
    "EPISODES_FILE",
    "episode_rows",
    "gap_stats",
    "law_figures",
    "learned_figures",
    "with_episodes",
]
