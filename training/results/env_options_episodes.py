"""``benchmarks/env_options.py``'s per-episode and per-step files and the figures they give.

Per controller and validation seed s (episode e), with the applied controls u_k^n (m steps n,
N agents k), the common control cbar^n = mean_k u_k^n and the centre's offset o^n = xbar - c^n:

- ``{stem}_episodes.csv``, one row per (policy, seed): ``cost`` J_e, ``common_only_cost`` (the
  same controller's mean control broadcast to every agent, ``action_basis="common"``),
  ``max_abs_u_action_units`` max_{n,k} |u_k^n| / max_control, ``max_abs_common_u_action_units``
  max_n |cbar^n| / max_control, ``control_energy`` sum_{n,k} |u_k^n|^2 and ``n_agents`` N;
- ``{stem}_steps.csv``, one row per (policy, seed, step n): ``common_u`` cbar^n and
  ``centre_offset`` o^n (the R^2 pools steps over the seeds, so it needs them).

`controller_figures` aggregates them into the summary the script writes to ``{stem}.json``
(docs/env-options.md's table): mean J, the largest |u| and |cbar| over the episodes, the common
mode's energy share N sum_{e,n} |cbar|^2 / sum_e energy_e, the R^2 of cbar on o with one gain
per step (`linear_fit_r2`), the mean common-only cost and the mean per-episode ratio of the
common-only cost to J. The script computes its summary with the same function from the same
rows, so the files reproduce it bit for bit.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from agent_envs.training.results.episode_csv import Row, read_rows


def episode_files(summary: str | Path) -> tuple[Path, Path]:
    """The per-episode and per-step files written beside the summary ``DIR/STEM.json``:
    ``DIR/STEM_episodes.csv`` and ``DIR/STEM_steps.csv``."""
    summary = Path(summary)
    return (
        summary.with_name(f"{summary.stem}_episodes.csv"),
        summary.with_name(f"{summary.stem}_steps.csv"),
    )


def episode_rows(
    policy: str,
    seed: int,
    run: dict[str, np.ndarray | float],
    common_only_cost: float,
    max_control: float,
) -> tuple[Row, list[Row]]:
    """The episode row and step rows of one episode: `run` holds its ``cost``, its ``controls``
    (m, N) and ``offsets`` (m,)."""
    controls = np.asarray(run["controls"])
    common = controls.mean(axis=-1)
    episode: Row = {
        "policy": policy,
        "seed": seed,
        "n_agents": controls.shape[-1],
        "cost": float(run["cost"]),
        "common_only_cost": float(common_only_cost),
        "max_abs_u_action_units": float(np.abs(controls).max() / max_control),
        "max_abs_common_u_action_units": float(np.abs(common).max() / max_control),
        "control_energy": float((controls**2).sum()),
    }
    steps: list[Row] = [
        {"policy": policy, "seed": seed, "step": n, "common_u": float(c), "centre_offset": float(o)}
        for n, (c, o) in enumerate(zip(common, np.asarray(run["offsets"]), strict=True))
    ]
    return episode, steps


def linear_fit_r2(common: np.ndarray, offsets: np.ndarray) -> float:
    """R^2 of common (S, m) on offsets (S, m) with one gain per step (no intercept):
    g^n = sum_s c_s^n o_s^n / sum_s (o_s^n)^2, 1 - sum (c - g o)^2 / sum (c - mean c)^2."""
    gains = (common * offsets).sum(axis=0) / np.maximum((offsets**2).sum(axis=0), 1e-300)
    residual = ((common - gains * offsets) ** 2).sum()
    total = ((common - common.mean()) ** 2).sum()
    return float(1.0 - residual / total)


def controller_figures(episodes: list[Row], steps: list[Row]) -> dict[str, float]:
    """One controller's summary figures (module docstring) from its episode rows (in seed
    order) and step rows (grouped by seed in that order, steps ascending)."""
    seeds = [e["seed"] for e in episodes]
    per_seed: dict[object, list[Row]] = {s: [] for s in seeds}
    for row in steps:
        per_seed[row["seed"]].append(row)
    common = np.array([[float(r["common_u"]) for r in per_seed[s]] for s in seeds])  # (S, m)
    offsets = np.array([[float(r["centre_offset"]) for r in per_seed[s]] for s in seeds])
    costs = np.array([float(e["cost"]) for e in episodes])
    common_costs = np.array([float(e["common_only_cost"]) for e in episodes])
    energy = np.array([float(e["control_energy"]) for e in episodes])
    n = int(episodes[0]["n_agents"])
    return {
        "cost": float(costs.mean()),
        "max_abs_u_action_units": max(float(e["max_abs_u_action_units"]) for e in episodes),
        "max_abs_common_u_action_units": max(
            float(e["max_abs_common_u_action_units"]) for e in episodes
        ),
        "common_energy_share": float(n * (common**2).sum() / energy.sum()),
        "common_linear_r2": linear_fit_r2(common, offsets),
        "common_only_cost": float(common_costs.mean()),
        "common_only_ratio": float((common_costs / costs).mean()),
    }


def summary_from_rows(episodes: list[Row], steps: list[Row]) -> dict[str, dict[str, float]]:
    """policy -> `controller_figures`, the policies in the rows' order."""
    policies = list(dict.fromkeys(str(e["policy"]) for e in episodes))
    return {
        p: controller_figures(
            [e for e in episodes if e["policy"] == p], [s for s in steps if s["policy"] == p]
        )
        for p in policies
    }


def read_summary(
    episodes_path: str | Path, steps_path: str | Path
) -> tuple[list[int], dict[str, dict[str, float]]]:
    """(seeds, policy -> figures) recomputed from a written per-episode and per-step file."""
    episodes = read_rows(episodes_path)
    seeds = list(dict.fromkeys(int(e["seed"]) for e in episodes))
    return seeds, summary_from_rows(episodes, read_rows(steps_path))


__all__ = [
    "controller_figures",
    "episode_files",
    "episode_rows",
    "linear_fit_r2",
    "read_summary",
    "summary_from_rows",
]
