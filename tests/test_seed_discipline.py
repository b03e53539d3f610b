"""Design choices never read a test seed (issue: validation seeds for every design choice).

The scripts and modules that choose something (a bound, an interface, a budget, a
hyperparameter) must draw their episodes from validation seeds; test seeds are for final tables.
Checked two ways: statically, no design source names a test seed (the constants, a task's
`test_seeds`, or a literal in a test-seed range); and by running the design scripts' seed
choice with their measurement stubbed, recording the seeds they ask for.
"""

from __future__ import annotations

import ast
import json
import sys
from pathlib import Path

import numpy as np
import pytest
from scripts import load_script

from agent_envs.tasks import TASKS
from agent_envs.training.defaults import DEFAULT_EVAL_SEED, DEFAULT_TEST_SEEDS

ROOT = Path(__file__).resolve().parents[1]

#: sources that make design choices: the presets and the tuner, the design benchmarks
DESIGN_SOURCES = [
    "training/commands/presets.py",
    "training/commands/tune.py",
    "training/commands/seed_objective.py",
    "benchmarks/env_options.py",
    "benchmarks/max_control.py",
    "benchmarks/task_design.py",
    "benchmarks/sweep_budget.py",
    "benchmarks/benchmarl_action_scale.py",
    "benchmarks/benchmarl_fresh_policy.py",
    "benchmarks/benchmarl_design_run.py",
    "training/learners/benchmarl_runs.py",
    "benchmarks/shared_design.py",
    "benchmarks/quick_design.py",
]
TEST_SEED_NAMES = {"DEFAULT_TEST_SEED", "DEFAULT_TEST_SEEDS", "test_seeds"}


def _test_seed_ranges() -> list[range]:
    ranges = [range(min(DEFAULT_TEST_SEEDS), max(DEFAULT_TEST_SEEDS) + 1)]
    ranges += [range(min(t.test_seeds), max(t.test_seeds) + 1) for t in TASKS.values()]
    return ranges


#: (source, reference) -> why it is not a read of a test seed's episode
ALLOWED = {
    ("benchmarks/task_design.py", ".test_seeds"): "refuses a test seed passed as --seeds",
    ("benchmarks/sweep_budget.py", ".test_seeds"): "counts the test episodes a sweep will "
    "run, to estimate its time; runs none",
}


def _seed_context(node: ast.AST, parents: dict[ast.AST, ast.AST]) -> bool:
    """Whether a literal sits where a seed goes: an argument of range(), or the value of a
    name, keyword or attribute that says seed (a budget of 20_000 steps is not a seed)."""
    while node in parents:
        parent = parents[node]
        if isinstance(parent, ast.Call) and getattr(parent.func, "id", "") == "range":
            return True
        if isinstance(parent, ast.keyword) and "seed" in (parent.arg or ""):
            return True
        if isinstance(parent, ast.Assign | ast.AnnAssign):
            targets = parent.targets if isinstance(parent, ast.Assign) else [parent.target]
            return any("seed" in ast.unparse(t).lower() for t in targets)
        node = parent
    return False


def _test_seed_references(path: Path, source: str = "") -> list[str]:
    found = []
    ranges = _test_seed_ranges()
    tree = ast.parse(path.read_text())
    parents = {child: node for node in ast.walk(tree) for child in ast.iter_child_nodes(node)}
    for node in ast.walk(tree):
        if isinstance(node, ast.Name) and node.id in TEST_SEED_NAMES:
            found.append((node.lineno, node.id))
        elif isinstance(node, ast.Attribute) and node.attr in TEST_SEED_NAMES:
            found.append((node.lineno, f".{node.attr}"))
        elif isinstance(node, ast.alias) and node.name in TEST_SEED_NAMES:
            found.append((0, f"import {node.name}"))
        elif (
            isinstance(node, ast.Constant)
            and type(node.value) is int
            and any(node.value in r for r in ranges)
            and _seed_context(node, parents)
        ):
            found.append((node.lineno, f"literal {node.value}"))
    return [f"{line}: {ref}" for line, ref in sorted(found) if (source, ref) not in ALLOWED]


@pytest.mark.parametrize("source", DESIGN_SOURCES)
def test_no_design_source_names_a_test_seed(source):
    assert _test_seed_references(ROOT / source, source) == []


def test_the_static_check_finds_a_test_seed(tmp_path):
    """The check above can fail: each way of naming a test seed is found."""
    bad = tmp_path / "bad.py"
    bad.write_text(
        "from agent_envs.training.defaults import DEFAULT_TEST_SEEDS\n"
        "a = task.test_seeds\nb = list(range(10000, 10005))\nseed = 20003\n"
        "run(seed=21000)\nbudget = 20_000\n"
    )
    assert len(_test_seed_references(bad)) == 6  # not the budget


def _load(name: str):
    return load_script(ROOT / "benchmarks" / name)


def test_env_options_figures_come_from_validation_seeds(monkeypatch, tmp_path):
    module = _load("env_options.py")
    asked = []

    def measure(name, seeds, max_control):
        asked.extend(seeds)
        run = {"cost": 1.0, "controls": np.ones((2, 3)), "offsets": np.ones(2)}
        rows = [module.episode_rows(name, s, run, 1.0, max_control) for s in seeds]
        return [e for e, _ in rows], [step for _, steps in rows for step in steps]

    monkeypatch.setattr(module, "measure", measure)
    out = tmp_path / "figures.json"
    monkeypatch.setattr(sys, "argv", ["env_options.py", "--seeds", "3", "--out", str(out)])
    module.main()
    assert sorted(set(asked)) == [DEFAULT_EVAL_SEED, DEFAULT_EVAL_SEED + 1, DEFAULT_EVAL_SEED + 2]
    assert json.loads(out.read_text())["seeds"] == sorted(set(asked))


def test_max_control_runs_on_validation_seeds(monkeypatch):
    module = _load("max_control.py")
    assert module.VALIDATION_SEED == DEFAULT_EVAL_SEED
    asked = []

    def peak_control(kernel, target, integrator, n_paths, seed, n_agents=100):
        asked.append(seed)
        return 1.0, 0.0, 0.5, False

    monkeypatch.setattr(module, "peak_control", peak_control)
    monkeypatch.setattr(sys, "argv", ["max_control.py", "--seeds", "2"])
    assert module.main() == 0
    assert sorted(set(asked)) == [DEFAULT_EVAL_SEED, DEFAULT_EVAL_SEED + 1]


@pytest.mark.parametrize("task", sorted(TASKS))
def test_validation_and_test_seeds_are_disjoint(task):
    spec = TASKS[task]
    validation = set(range(DEFAULT_EVAL_SEED, DEFAULT_EVAL_SEED + 100))
    assert not validation & set(spec.test_seeds)
    assert not validation & set(DEFAULT_TEST_SEEDS)
