"""The design figures the docs quote, recomputed from the committed outputs of their scripts."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _doc_rows(doc: str, first_cell: str) -> list[list[str]]:
    rows = []
    for line in (ROOT / doc).read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("| ") and cells[0].startswith(first_cell):
            rows.append(cells)
    return rows


def test_max_control_table_is_the_committed_output():
    """docs/envs/gymnasium.md's "Why max_control = 150" table = max_control.py's output."""
    out = (ROOT / "docs/results/max-control/max_control.txt").read_text()
    peaks = {}
    for kernel, xbar, integrator, paths, peak in re.findall(
        r"^\s*(\w+)\s+(-?[\d.]+)\s+(serb|em)\s+(\d+) \|\s+([\d.]+)", out, re.M
    ):
        peaks[(kernel, float(xbar), integrator, int(paths))] = float(peak)
    assert len(peaks) == 12
    columns = [("serb", 20), ("em", 20), ("serb", 1), ("em", 1)]
    settings = {
        "symmetric eps = 0.05, xbar = 0.7": ("symmetric", 0.7),
        "symmetric eps = 0.05, xbar = -1.7": ("symmetric", -1.7),
        "non-symmetric eps in [0.01, 0.1], xbar = 2.3": ("nonsymmetric", 2.3),
    }
    rows = {r[0]: r[1:] for r in _doc_rows("docs/envs/gymnasium.md", "") if r[0] in settings}
    assert set(rows) == set(settings)
    for label, (kernel, xbar) in settings.items():
        expected = [f"{peaks[(kernel, xbar, i, p)]:.1f}" for i, p in columns]
        assert rows[label] == expected, label
    largest = max(peaks.values())
    assert f"largest {largest:.1f} against 150" in (ROOT / "docs/envs/gymnasium.md").read_text()
    assert f"largest |u| = {largest:.2f}" in out and "never clipped" in out


def test_shared_design_table_is_its_runs_file():
    """docs/learners/shared.md's design table is rendered from the committed runs.csv; every run
    was validated on the validation seeds 1000-1004 (its proportional-law cost is the one
    env-options measured there) and every variant it names is defined."""
    import json

    import pytest

    from agent_envs.training.results.design_runs import (
        OPTIMUM_FILES,
        design_table,
        read_runs,
    )

    results = ROOT / "docs" / "results"
    runs = results / "shared-design" / "runs.csv"
    page = (ROOT / "docs" / "learners" / "shared.md").read_text()
    block = re.search(
        r"<!-- shared-design-table:start -->\n(.*?)\n<!-- shared-design-table:end -->", page, re.S
    )
    assert block is not None
    assert block.group(1) == design_table(runs, results / "env-options")
    variants = json.loads((results / "shared-design" / "variants.json").read_text())
    rows = read_runs(runs)
    assert {r["variant"] for r in rows} <= set(variants)
    laws = {
        task: json.loads((results / "env-options" / name).read_text())["results"]["proportional"]
        for task, name in OPTIMUM_FILES.items()
    }
    for row in rows:
        law = laws[row["task"]]["cost"]
        assert row["proportional_cost"] == pytest.approx(law, rel=1e-6), row


def test_shared_transfer_summary_is_its_episodes():
    """The transfer table's summary (docs/results/shared-across-n/issue41/across_n.csv) is the
    mean of its committed episodes, policy by policy and N by N; every run saw the same 10
    seeds."""
    import csv

    import numpy as np

    folder = ROOT / "docs" / "results" / "shared-across-n" / "issue41"
    with open(folder / "episodes.csv", newline="") as handle:
        episodes = list(csv.DictReader(handle))
    with open(folder / "across_n.csv", newline="") as handle:
        summary = list(csv.DictReader(handle))
    assert len(summary) == 16
    for row in summary:
        mine = [
            e for e in episodes if (e["policy"], e["n_agents"]) == (row["policy"], row["n_agents"])
        ]
        assert sorted(int(e["seed"]) for e in mine) == list(range(10_000, 10_010))
        costs = np.array([float(e["total_cost"]) for e in mine])
        assert abs(costs.mean() - float(row["mean_cost"])) <= 1e-15


def test_shared_results_table_is_the_leaderboard_file():
    """docs/learners/shared.md's results table (gap by training seed, and the laws' gaps) is the
    committed leaderboard episodes file's, digit for digit as printed."""
    from agent_envs.training.commands.leaderboard import read_episodes

    rows = read_episodes(ROOT / "docs" / "results" / "leaderboard" / "episodes.csv")
    tasks = ("agent_envs/StiffSwarm-v0", "agent_envs/WeakCouplingSwarm-v0")

    def gaps(policy: str, task: str) -> str:
        mine = [r for r in rows if r["policy"] == policy and r["task"] == task]
        seeds = sorted({r["training_seed"] for r in mine})
        means = [
            sum(r["gap"] for r in mine if r["training_seed"] == s)
            / sum(1 for r in mine if r["training_seed"] == s)
            for s in seeds
        ]
        return ", ".join(f"{100 * m:+.2f}%" for m in means)

    page = (ROOT / "docs" / "learners" / "shared.md").read_text()
    expected = {
        "`ppo-shared`": "ppo-shared",
        "`ppo-local`": "ppo-local",
        "centre law (one control for all)": "proportional-common",
        "proportional law (per agent, local)": "proportional",
    }
    for label, policy in expected.items():
        row = f"| {label} | " + " | ".join(gaps(policy, t) for t in tasks) + " |"
        assert row in page, row
