"""The throughput benchmarks run: each script's `--quick` mode in a fresh process.

The figures in docs/benchmarks.md come from these scripts (`benchmarks/bench_*.py`, one
question each, public APIs of `agent_envs` only). Their quick modes take seconds each (the
cold-start one about half a minute: it starts fresh processes), so the test is `slow`. It
checks that a script exits 0 and prints its table, not its figures (they move with the load).
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"

#: script -> a header cell its quick table prints
QUICK_TABLES = {
    "bench_cold_start.py": "cold/warm",
    "bench_step_floor.py": "ratio (same process)",
    "bench_kernel_pass.py": "in-place numpy / compiled pass",
    "bench_phi_actions.py": "step / EM step",
    "bench_vector_batching.py": "native / loop",
    "bench_threads.py": "",  # (a table only where numba allows two threads or more)
    "bench_step_breakdown.py": "call (share of the step)",
    "bench_device.py": "",  # (without CUDA: says so and exits 0)
    "bench_vector_env.py": "native / sync",
    "bench_user_step.py": "native per-env step",
}
#: the benchmarks' own helper modules (public names of agent_envs only, like the scripts)
HELPERS = ("_timing.py", "_ppo_timing.py")


def test_every_throughput_benchmark_is_listed():
    """A new benchmark script gets its quick run here (and a row in docs/benchmarks.md)."""
    scripts = {p.name for p in BENCHMARKS.glob("bench_*.py")}
    timed_elsewhere = {
        "bench_apg.py",  # training runs (docs/learners/apg.md)
        "bench_scoring.py",
        "bench_integrators.py",
        "bench_gradient.py",
        "bench_env_step.py",
        "bench_blas_threads.py",
        "bench_large_swarms.py",
        "bench_optimal.py",
    }
    assert scripts - timed_elsewhere == set(QUICK_TABLES)


def test_benchmarks_use_public_names_of_agent_envs_only():
    """No `module._private` access into agent_envs from the benchmark scripts (the helpers
    `_timing` and `_ppo_timing` are the benchmarks' own modules)."""
    for name in QUICK_TABLES:
        text = (BENCHMARKS / name).read_text()
        assert not re.findall(r"\b(?!_timing\b)[a-z]\w*\._[a-z]\w*", text), name
    for name in HELPERS:
        text = (BENCHMARKS / name).read_text()
        assert not re.findall(r"\b[a-z]\w*\._[a-z]\w*", text), name


@pytest.mark.slow
@pytest.mark.parametrize("script", sorted(QUICK_TABLES))
def test_quick_mode_runs(script):
    done = subprocess.run(
        [sys.executable, str(BENCHMARKS / script), "--quick"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:] + done.stdout[-2000:]
    assert QUICK_TABLES[script] in done.stdout


@pytest.mark.slow
def test_user_step_ab_mode_writes_its_figures(tmp_path):
    """`bench_user_step.py --baseline-python` runs both interpreters and adds the A/B column
    (here the same interpreter twice: the column is there, its values near 1)."""
    out = tmp_path / "figures.json"
    done = subprocess.run(
        [sys.executable, str(BENCHMARKS / "bench_user_step.py"), "--quick", "--skip-ppo",
         "--baseline-python", sys.executable, "--json", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:] + done.stdout[-2000:]
    assert "A/B: old / new seconds of the step" in done.stdout
    figures = json.loads(out.read_text())
    assert len(figures["raw"]["steps"]["old"]) == len(figures["raw"]["steps"]["new"]) == 1
    assert all(row["old_over_new"] > 0 for row in figures["steps"] if "old_over_new" in row)


@pytest.mark.slow
def test_device_benchmark_measures_on_the_cpu_when_asked():
    """Without CUDA the default quick run measures nothing, so the worker that wraps the env's
    functions (draws, advance) would never run here: on the CPU device it does, and its
    shares come out (a wrapped name that moved raises instead of dropping its row)."""
    done = subprocess.run(
        [sys.executable, str(BENCHMARKS / "bench_device.py"), "--quick", "--device", "cpu"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:] + done.stdout[-2000:]
    assert "device env-steps/s (warm)" in done.stdout and "failed" not in done.stdout


def test_where_users_step_table_is_the_committed_run():
    """docs/benchmarks.md's "Where users step" figures are the committed JSON of the run."""
    root = BENCHMARKS.parent
    data = json.loads((root / "docs/results/user-step/bench_user_step_ab.json").read_text())
    page = (root / "docs/benchmarks.md").read_text()
    section = page.split("### Where users step", 1)[1].split("Reading it:", 1)[0]
    steps = {row["figure"]: row for row in data["steps"]}
    rows = [
        ("`gym.make` env step / native per-env step (B = 64), 1 path", "| How far is the env"),
        ("bare `SwarmEnv` step (no wrapper) / native per-env step", "| | bare `SwarmEnv`"),
        ("PettingZoo step, N = 100 / native per-env step", "| How far is the PettingZoo"),
        ("PettingZoo step, N = 100 / its five dicts alone", "| | the same / its five dicts"),
        ("PettingZoo step, N = 10 / native per-env step, N = 10", "| | parallel env step, N = 10"),
        ("`gym.make` env step / native per-env step, 20 paths", "| And with 20 paths?"),
    ]
    for figure, start in rows:
        line = next(ln for ln in section.splitlines() if ln.startswith(start))
        cells = [c.strip() for c in line.strip("|").split("|")]
        assert cells[2] == f"{steps[figure]['value']:.2f}", figure
        if "dicts" not in figure:  # (the dicts' row shares the PettingZoo step's A/B)
            assert cells[3] == f"{steps[figure]['old_over_new']:.2f}x faster", figure
    for row in data["ppo"]:
        line = next(ln for ln in section.splitlines() if f"| {row['learn']:,.0f} |" in ln)
        cells = [c.strip() for c in line.strip("|").split("|")]
        assert cells[2] == f"{100 * row['env_share']:.0f} %" and cells[3] == (
            f"{row['new_over_old']:.2f}"
        ), row["vec_env"]
