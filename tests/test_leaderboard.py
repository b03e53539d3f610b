"""The published benchmark tables are recomputed from the committed files, digit for digit."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from agent_envs.tasks import TASK_LIST, get_task, load_references

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
EPISODES = DOCS / "results" / "leaderboard" / "episodes.csv"


def _between(text: str, marker: str) -> str:
    match = re.search(rf"<!-- {marker}:start -->\n(.*?)<!-- {marker}:end -->", text, re.S)
    assert match, f"no {marker} markers"
    return match.group(1).strip()


def test_tasks_page_shows_the_shipped_references():
    from agent_envs.training.commands.task_evaluation import reference_table_markdown

    page = (DOCS / "tasks.md").read_text()
    assert _between(page, "reference-table") == reference_table_markdown()
    for task in TASK_LIST:  # the one-line "what it tests" is the catalogue's, verbatim
        assert f"| `{task.id}` | {task.tests} |" in page


def test_tasks_page_figures_hold():
    """The figures the task cards quote: the bound's tightness, the optimum's largest |u|."""
    page = (DOCS / "tasks.md").read_text()
    stiff = load_references("agent_envs/StiffSwarm-v0")
    ratio = stiff.costs["lower_bound"] / stiff.yardstick
    assert f"({ratio.min():.2f}-{ratio.max():.2f} of V on the stiff task)" in page
    largest = [r["max_abs_control"] for r in stiff.solver["optimal"]]
    assert f"Its largest |u| is {min(largest):.1f}-{max(largest):.1f}" in page


def test_leaderboard_page_is_its_episodes_file():
    from agent_envs.training.commands.leaderboard import leaderboard_table, read_episodes

    rows = read_episodes(EPISODES)
    page = (DOCS / "leaderboard.md").read_text()
    assert _between(page, "leaderboard-table") == leaderboard_table(rows).strip()


def test_leaderboard_file_is_complete_and_consistent():
    from agent_envs.tasks.scores import gap, normalized_score
    from agent_envs.training.commands.leaderboard import (
        LEARNERS,
        MARL_LEARNERS,
        TRAINING_SEEDS,
        read_episodes,
        runs_on,
    )

    rows = read_episodes(EPISODES)
    for task in TASK_LIST:
        refs = load_references(task)
        mine = [r for r in rows if r["task"] == task.id]
        present = {r["policy"] for r in mine if r["kind"] == "learner"}
        default = {name for name in LEARNERS if runs_on(name, task.id)}
        opt_in = {name for name in MARL_LEARNERS if runs_on(name, task.id)}
        # every default learner; the opt-in (BenchMARL) ones only where they run
        assert default <= present and present - default <= opt_in, task.id
        for learner in present:
            for seed in TRAINING_SEEDS:
                got = [
                    r for r in mine if r["policy"] == learner and r["training_seed"] == str(seed)
                ]
                assert sorted(r["seed"] for r in got) == list(task.test_seeds), (learner, seed)
        for r in mine:  # every score and gap from the row's own cost and the shipped V, J0
            v, z = refs.cost(task.yardstick, r["seed"]), refs.cost("zero", r["seed"])
            assert r["value"] == v and r["zero_cost"] == z
            assert r["score"] == pytest.approx(float(normalized_score(r["cost"], v, z)), rel=1e-12)
            assert r["gap"] == pytest.approx(float(gap(r["cost"], v)), rel=1e-12)
            if r["kind"] == "reference":
                assert r["cost"] == refs.cost(r["policy"], r["seed"])
    assert not any(r["diverged"] for r in rows)
    assert np.isfinite([r["cost"] for r in rows]).all()
    get_task("agent_envs/StiffSwarm-v0")


@pytest.mark.slow
def test_leaderboard_smoke_run_and_table(tmp_path):
    """The whole command on one task, one training seed, 1% budgets: every unit, the centre
    law, the references, the episodes file and the table rebuilt from it."""
    pytest.importorskip("torch")
    from agent_envs.training.commands.cli import main
    from agent_envs.training.commands.leaderboard import (
        CENTRE_LAW,
        leaderboard_table,
        read_episodes,
    )

    out = tmp_path / "lb"
    args = ["leaderboard", "--out", str(out), "--tasks", "agent_envs/NoisySwarm-v0"]
    assert main([*args, "--seeds", "0", "--timesteps-scale", "0.01"]) == 0
    rows = read_episodes(out / "episodes.csv")
    policies = {r["policy"] for r in rows}
    assert {"apg", "sac", CENTRE_LAW, "mpc", "optimal", "zero"} <= policies
    assert all(len([r for r in rows if r["policy"] == p]) == 20 for p in policies)
    assert main([*args, "--table", str(tmp_path / "t.md")]) == 0
    assert (tmp_path / "t.md").read_text().strip() == leaderboard_table(rows).strip()


@pytest.mark.slow
def test_regenerate_resumes_and_reproduces_the_shipped_costs(tmp_path):
    """--regenerate with 19 of 20 seed records in its work folder runs the last seed only and
    writes a file (and hash) whose costs equal the shipped ones."""
    pytest.importorskip("torch")
    import json

    from agent_envs.tasks.references import data_dir, recorded_hashes, sha256_hex
    from agent_envs.training.commands.task_references import regenerate

    task = get_task("agent_envs/NoisySwarm-v0")
    shipped = json.loads((data_dir() / "NoisySwarm-v0.json").read_text())
    work = tmp_path / "work" / task.file_stem
    work.mkdir(parents=True)
    for row in shipped["seeds"][1:]:
        (work / f"{row['seed']}.json").write_text(json.dumps(row))
    path = regenerate(task.id, tmp_path / "work", out_dir=tmp_path, progress=None)
    new = json.loads(path.read_text())
    assert recorded_hashes(tmp_path)[path.name] == sha256_hex(path.read_bytes())
    for old, now in zip(shipped["seeds"], new["seeds"], strict=True):
        for name, cost in old["costs"].items():
            assert now["costs"][name] == pytest.approx(cost, rel=1e-9), (old["seed"], name)
    refs = load_references(task, tmp_path)
    assert np.allclose(refs.yardstick, load_references(task).yardstick, rtol=1e-9, atol=0)


def test_findings_quote_the_stiff_tasks_references():
    stiff = load_references("agent_envs/StiffSwarm-v0")
    turnpike, proportional = stiff.mean("turnpike"), stiff.mean("proportional")
    text = (DOCS / "findings.md").read_text()
    assert f"{turnpike / proportional:.0f}x cheaper on `StiffSwarm-v0`" in text
    assert f"({turnpike:.4g} against\n  {proportional:.3g} on average" in text


def test_leaderboard_prose_quotes_the_table():
    """Every gap with two decimals in "What it says" is one of the table's own cells."""
    page = (DOCS / "leaderboard.md").read_text()
    prose = page.split("## What it says", 1)[1].split("<!-- leaderboard-table:start -->")[0]
    table = _between(page, "leaderboard-table")
    quoted = re.findall(r"\+\d+\.\d\d%", prose)
    assert len(quoted) >= 5
    for number in quoted:
        assert re.search(rf"[| ]{re.escape(number)}[ ,\]]", table), number


def test_tasks_page_design_table_is_its_file():
    import json

    from agent_envs.training.results.committed_tables import design_table

    rows = json.loads((DOCS / "results" / "task-design.json").read_text())
    assert all(r["seed"] in get_task(r["task"]).validation_seeds for r in rows)
    page = (DOCS / "tasks.md").read_text()
    assert _between(page, "design-table") == design_table(rows)


def test_units_follow_each_learners_tasks():
    """apg and SAC run on every task; the parameter-shared learners on the two stiffness regimes
    and the transfer to N = 10^4, the opt-in BenchMARL learners on the two regimes; `--learners`
    picks a part; transfers come last."""
    from agent_envs.training.commands.leaderboard import (
        LEARNER_TASKS,
        LEARNERS,
        MARL_LEARNERS,
        units,
    )

    ids = [t.id for t in TASK_LIST]
    every = units(ids, seeds=(0,), learners=(*LEARNERS, *MARL_LEARNERS))
    for name in ("apg", "sac"):
        assert sorted(u.task for u in every if u.learner == name) == sorted(ids)
    for name, tasks in LEARNER_TASKS.items():
        assert sorted(u.task for u in every if u.learner == name) == sorted(tasks)
    part = units(["agent_envs/StiffSwarm-v0"], seeds=(0, 1), learners=("ppo-local",))
    assert [(u.learner, u.seed) for u in part] == [("ppo-local", 0), ("ppo-local", 1)]
    kinds = [u.task != u.source for u in every]
    assert kinds == sorted(kinds)  # transfers after the units they read


def test_leaderboard_learners_bad_input(tmp_path):
    from agent_envs.training.commands.leaderboard import LeaderboardConfig

    with pytest.raises(ValueError, match="--learners must be among"):
        LeaderboardConfig(learners=("ppo-magic",), out=tmp_path / "lb")


def test_benchmarl_learners_are_opt_in_and_name_the_marl_extra(tmp_path, monkeypatch):
    """mappo and ippo are not run by default; asked for without BenchMARL, the command stops
    with one line naming the `marl` extra (BenchMARL's absence simulated)."""
    import importlib.util

    from agent_envs.training.commands import leaderboard
    from agent_envs.training.commands.cli import main

    assert not set(leaderboard.MARL_LEARNERS) & set(leaderboard.LEARNERS)
    assert leaderboard.LeaderboardConfig(out=tmp_path / "lb").learners == leaderboard.LEARNERS
    for name in leaderboard.MARL_LEARNERS:
        assert leaderboard.LEARNER_TASKS[name] == (
            "agent_envs/StiffSwarm-v0",
            "agent_envs/WeakCouplingSwarm-v0",
        )
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "benchmarl" else real(name)
    )
    with pytest.raises(ValueError, match=r"--learners mappo ippo needs BenchMARL.*marl"):
        leaderboard.LeaderboardConfig(learners=("apg", "mappo", "ippo"), out=tmp_path / "lb")
    leaderboard.LeaderboardConfig(learners=("apg",), out=tmp_path / "lb")  # no BenchMARL needed
    assert main(["leaderboard", "--out", str(tmp_path / "lb"), "--learners", "mappo"]) != 0
