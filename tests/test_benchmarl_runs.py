"""BenchMARL's MAPPO / IPPO as leaderboard units (training/learners/benchmarl_runs.py).

Needs the optional `marl` extra (BenchMARL, TorchRL); skipped without it. Fast: the action scale
is exact (a policy trained at max_control 25 s and scored with actions x s applies the same
controls on the task's env: same costs, bit for bit), bad input names its parameter, and a unit
(training replaced by the untrained policy's weights) writes the leaderboard's file. Slow: one
tiny unit end to end through `agent-envs leaderboard --learners mappo`.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("benchmarl", reason="BenchMARL is in the optional `marl` extra")
import torch

from agent_envs.tasks import get_task
from agent_envs.training.learners import benchmarl_runs
from agent_envs.training.learners.benchmarl_policy import DEFAULT_GROUP as GROUP
from agent_envs.training.learners.benchmarl_policy import GroupPolicy
from agent_envs.training.learners.benchmarl_runs import MarlRun
from agent_envs.training.learners.multiagent import evaluate_per_agent

STIFF = "agent_envs/StiffSwarm-v0"


class Tanh:
    """A stand-in group policy: a = tanh(3 (own offset) + drift / 10), per agent."""

    def __call__(self, td):
        obs = td.get((GROUP, "observation"))
        td.set((GROUP, "action"), torch.tanh(3.0 * obs[:, :1] + obs[:, 1:2] / 10.0))
        return td


@pytest.mark.parametrize("scale", [0.25, 0.5])
def test_scaled_actions_on_the_task_env_are_the_train_envs_controls(scale):
    """u = 25 (s a) on the task's env, u = (25 s) a on the train env: the same controls, hence
    the same per-agent costs, bit for bit (s a power of two)."""
    run = MarlRun(STIFF, "mappo", 0, frames=100, action_scale=scale)
    train, task = run.train_env_kwargs(), run.task_env_kwargs()
    assert train["max_control"] == 25.0 * scale and task["max_control"] == 25.0
    assert {k: v for k, v in train.items() if k != "max_control"} == {
        k: v for k, v in task.items() if k != "max_control"
    }
    seeds = [1000]
    on_train = evaluate_per_agent(GroupPolicy(Tanh()), train, seeds)
    on_task = evaluate_per_agent(GroupPolicy(Tanh(), scale=scale), task, seeds)
    assert np.array_equal(on_train, on_task)
    unscaled = evaluate_per_agent(GroupPolicy(Tanh()), task, seeds)
    assert not np.array_equal(unscaled, on_task)


def test_the_run_is_the_tasks_env_with_the_swarm_interface():
    run = MarlRun(STIFF, "ippo", 2)
    kwargs = run.train_env_kwargs()
    spec = get_task(STIFF)
    for key in ("n_agents", "n_steps", "epsilon", "sigma", "integrator", "target"):
        assert kwargs[key] == spec.env_kwargs[key]
    assert kwargs["observation"] == "swarm" and kwargs["agent_reward"] == "team"
    assert run.frames == benchmarl_runs.DEFAULT_FRAMES["ippo"]
    assert run.validation_seeds() == list(spec.validation_seeds[:5])
    assert min(run.validation_seeds()) >= 1000 and not set(run.validation_seeds()) & set(
        spec.test_seeds
    )


@pytest.mark.parametrize(
    ("kwargs", "name", "error"),
    [
        ({"algorithm": "qmix"}, "algorithm", ValueError),
        ({"frames": 0}, "frames", ValueError),
        ({"frames": -6000}, "frames", ValueError),
        ({"frames": 1.5}, "frames", TypeError),
        ({"action_scale": 0.0}, "action_scale", ValueError),
        ({"action_scale": 2.0}, "action_scale", ValueError),
        ({"batch_frames": 0}, "batch_frames", ValueError),
        ({"seed": -1}, "seed", ValueError),
        ({"task": "agent_envs/NoSuchSwarm-v0"}, "NoSuchSwarm", ValueError),
    ],
)
def test_bad_input_names_the_parameter(kwargs, name, error):
    args = {"task": STIFF, "algorithm": "mappo", "seed": 0, **kwargs}
    with pytest.raises(error, match=name):
        MarlRun(**args)
    with pytest.raises(ValueError, match="algorithm"):
        benchmarl_runs.default_frames("qmix")
    with pytest.raises(ValueError, match="scale"):
        GroupPolicy(Tanh(), scale=0.0)


def test_a_unit_writes_the_leaderboards_file(tmp_path, monkeypatch):
    """The unit's dispatch, weights saved and read back (weights_only), scoring per agent on
    the 20 test seeds, the file: training replaced by the untrained policy (fast)."""
    from agent_envs.training.commands import leaderboard

    def untrained(run, runs_dir):
        folder = tmp_path / "run"
        folder.mkdir()
        (folder / benchmarl_runs.CONFIG_FILE).write_text(json.dumps(run.to_dict()))
        experiment = benchmarl_runs.build_experiment(run, tmp_path / "scratch")
        torch.save(experiment.policy.state_dict(), folder / benchmarl_runs.WEIGHTS_FILE)
        return folder

    monkeypatch.setattr(benchmarl_runs, "train_run", untrained)
    unit = leaderboard.Unit(STIFF, "mappo", 1, STIFF)
    path = leaderboard.run_unit(unit, tmp_path / "lb")
    assert path == tmp_path / "lb" / "units" / "StiffSwarm-v0__mappo__1.csv"
    rows = leaderboard.read_episodes(path)
    header = path.read_text().splitlines()[0].split(",")
    assert tuple(header) == leaderboard.EPISODE_COLUMNS
    assert [r["seed"] for r in rows] == list(get_task(STIFF).test_seeds)
    assert {(r["policy"], r["kind"], r["training_seed"]) for r in rows} == {
        ("mappo", "learner", "1")
    }
    # the untrained policy's cost on a test seed, measured directly
    policy = benchmarl_runs.load_policy(tmp_path / "run")
    assert policy.scale == benchmarl_runs.DEFAULT_ACTION_SCALE
    direct = evaluate_per_agent(policy, MarlRun(STIFF, "mappo", 1).task_env_kwargs(), [20000])
    assert rows[0]["cost"] == pytest.approx(direct[0, 0], rel=1e-12)
    table = leaderboard.leaderboard_table(rows, [STIFF])
    assert leaderboard.POLICY_LABELS["mappo"] in table


@pytest.mark.slow
def test_a_tiny_unit_end_to_end(tmp_path):
    """`agent-envs leaderboard --learners mappo` at 1/1000 of the budget (48 frames, one
    batch): the run folder (config, curve, best weights, wall time), the unit file, the table;
    the saved weights reproduce the best validation cost. About a minute on a loaded core."""
    from agent_envs.training.commands.cli import main
    from agent_envs.training.commands.leaderboard import read_episodes

    out = tmp_path / "lb"
    args = ["leaderboard", "--out", str(out), "--tasks", STIFF, "--learners", "mappo"]
    assert main([*args, "--seeds", "0", "--timesteps-scale", "0.001"]) == 0
    folder = out / "runs" / "StiffSwarm-v0" / "mappo_seed0"
    run = benchmarl_runs.load_run(folder)
    assert run.frames == 48 and run.seed == 0 and run.task == STIFF
    result = json.loads((folder / benchmarl_runs.RESULT_FILE).read_text())
    assert result["train_seconds"] > 0 and result["torch_threads"] == 1
    curve = (folder / benchmarl_runs.CURVE_FILE).read_text().splitlines()
    assert curve[0] == ",".join(benchmarl_runs.CURVE_COLUMNS) and len(curve) == 3
    best = benchmarl_runs.validation_cost(benchmarl_runs.load_policy(folder).module, run)
    assert best == result["best_validation_cost"]
    rows = read_episodes(out / "units" / "StiffSwarm-v0__mappo__0.csv")
    assert len(rows) == 20 and {r["training_seed"] for r in rows} == {"0"}
    assert "BenchMARL MAPPO" in (out / "leaderboard.md").read_text()
