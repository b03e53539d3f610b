"""The design and apg benchmarks write per-episode files that recompute their summaries.

docs/env-options.md, docs/envs/gymnasium.md and docs/learners/apg.md publish means and extremes
over episodes. Each script writes one row per episode beside its summary; each test runs the
script on a tiny setting (a few agents, steps and seeds: seconds) into tmp_path and checks that
the per-episode file, read back, aggregates to the summary the script wrote, digit for digit,
and that the published table's renderer, given both, renders the same table from either: the
table of the next real run will be recomputable from its committed episodes.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from scripts import load_script

from agent_envs.training.results import committed_tables
from agent_envs.training.results.env_options_episodes import episode_files, read_summary

ROOT = Path(__file__).resolve().parents[1]
TINY_ENV = {"n_agents": 4, "n_steps": 5, "n_paths": 2}


def _load(name: str):
    return load_script(ROOT / "benchmarks" / name)


def test_env_options_episodes_recompute_its_summary(monkeypatch, tmp_path):
    module = _load("env_options.py")
    out = tmp_path / "results.json"
    argv = ["env_options.py", "--seeds", "2", "--out", str(out)]
    monkeypatch.setattr(sys, "argv", [*argv, "--env-kwargs", json.dumps(TINY_ENV)])
    module.main()
    summary = json.loads(out.read_text())
    episodes, steps = episode_files(out)
    seeds, results = read_summary(episodes, steps)
    assert seeds == summary["seeds"] == [1000, 1001]
    assert results == summary["results"]  # every figure, bit for bit
    assert len(steps.read_text().splitlines()) == 1 + 2 * 2 * TINY_ENV["n_steps"]
    for r2 in (True, False):
        from_episodes = committed_tables.env_options_table(out, episodes, steps, r2=r2)
        assert from_episodes == committed_tables.env_options_table(out, r2=r2)


def test_max_control_episodes_reprint_its_output(monkeypatch, tmp_path):
    from agent_envs.training.results.episode_csv import read_rows
    from agent_envs.training.results.max_control_seeds import largest_peak, setting_lines

    module = _load("max_control.py")
    argv = ["max_control.py", "--seeds", "2", "--n-agents", "4", "--out", str(tmp_path)]
    monkeypatch.setattr(sys, "argv", argv)
    assert module.main() == 0
    printed = (tmp_path / "max_control.txt").read_text().splitlines()
    rows = read_rows(tmp_path / "episodes.csv")
    assert len(rows) == 12 * 2  # (kernel, xbar) x integrator x paths, 2 seeds each
    assert printed[1:-1] == setting_lines(rows)  # character for character
    assert f"largest |u| = {largest_peak(rows):.2f};" in printed[-1]
    summary = tmp_path / "max_control.txt"
    from_seeds = committed_tables.max_control_table(summary, tmp_path / "episodes.csv")
    assert from_seeds == committed_tables.max_control_table(summary)


def test_apg_episodes_recompute_its_results(monkeypatch, tmp_path):
    from agent_envs.training.results.apg_episodes import with_episodes
    from agent_envs.training.results.episode_csv import read_rows

    module = _load("bench_apg.py")
    monkeypatch.setattr(module, "PAPER_ENV", {**module.PAPER_ENV, **TINY_ENV})
    monkeypatch.setattr(module, "QUICK_ENV", {**module.PAPER_ENV, **TINY_ENV, "n_agents": 3})
    argv = ["--out", str(tmp_path), "--seeds", "0", "--iterations", "1", "--test-seeds", "2"]
    argv += ["--across-n", "5", "--across-n-seeds", "2", "--optimal-at", "5"]
    assert module.main([*argv, "--parts", "paper", "quick", "across-n", "paper-linear"]) == 0
    results = json.loads((tmp_path / "results.json").read_text())
    rows = read_rows(tmp_path / "episodes.csv")
    assert len(rows) == 4 * 2  # (paper, quick, N = 5, linear) x 2 test seeds, 1 training seed
    assert with_episodes(results, rows) == results  # every gap and ratio, bit for bit
    moved = [{**r, "apg_cost": 2 * r["apg_cost"]} for r in rows]
    for part in ("paper", "quick", "across-n", "paper-linear"):  # each part read from its rows
        assert with_episodes(results, moved)[part] != results[part], part
    for name in ("apg_paper_table", "apg_quick_table", "apg_across_n_table"):
        table = getattr(committed_tables, name)
        summary = tmp_path / "results.json"
        assert table(summary, tmp_path / "episodes.csv") == table(summary), name


def test_registered_per_episode_files_are_the_files_the_scripts_write():
    """`agent-envs tables` looks for each script's per-episode file under the name the script
    gives it, beside the summary it renders today."""
    from agent_envs.training.commands.published import PUBLISHED
    from agent_envs.training.results.apg_episodes import EPISODES_FILE
    from agent_envs.training.results.max_control_seeds import SEEDS_FILE

    tables = {t.marker: t for t in PUBLISHED}
    for marker in ("env-options-table", "env-options-eps1-table"):
        table = tables[marker]
        assert table.per_episode == tuple(str(p) for p in episode_files(table.sources[0]))
    for marker, name in [("max-control-table", SEEDS_FILE)] + [
        (m, EPISODES_FILE) for m in ("apg-paper-table", "apg-quick-table", "apg-across-n-table")
    ]:
        table = tables[marker]
        assert table.per_episode == (str(Path(table.sources[0]).with_name(name)),), marker
