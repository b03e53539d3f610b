"""The CleanRL-style example (examples/cleanrl_ppo_swarm.py): its saved policy loads with numpy
alone, and (slow) a tiny training run is scored end to end by `agent-envs evaluate --task`."""

import csv
import importlib
import itertools
import math
import os
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import agent_envs  # noqa: F401  (registers the task ids)

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "examples" / "cleanrl_ppo_swarm.py"
TASK = "agent_envs/NoisySwarm-v0"


@pytest.fixture
def example(monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT))
    return importlib.import_module("examples.cleanrl_ppo_swarm")


def test_saved_policy_loads_with_numpy_and_acts_in_bounds(example, tmp_path, monkeypatch):
    env = gym.make(TASK)
    obs, _ = env.reset(seed=1000)  # a validation seed
    obs_dim, act_dim, hidden = obs.shape[0], env.action_space.shape[0], 8
    rng = np.random.default_rng(0)
    sizes = [obs_dim, hidden, hidden, act_dim]
    layers = [
        (3.0 * rng.standard_normal((i, o)), rng.standard_normal(o))  # large: some actions clip
        for i, o in itertools.pairwise(sizes)
    ]
    path = example.save_policy(
        tmp_path / "p.npz", layers, obs.astype(np.float64), np.full(obs_dim, 4.0), task=TASK
    )
    with np.load(path, allow_pickle=False) as data:  # plain arrays only
        assert str(data["task"]) == TASK
    monkeypatch.setenv(example.POLICY_ENV_VAR, str(path))
    act = example.policy(env)
    action = act(obs)
    assert action.shape == env.action_space.shape and action.dtype == np.float32
    assert np.all(np.abs(action) <= 1.0) and np.any(np.abs(action) == 1.0)
    # the numpy forward pass: normalize (mean = obs here, so x = 0), tanh layers, clip
    x = np.zeros(obs_dim)
    for k, (w, b) in enumerate(layers):
        x = x @ w.astype(np.float32) + b.astype(np.float32)
        x = np.tanh(x) if k < 2 else x
    np.testing.assert_allclose(action, np.clip(x, -1, 1), rtol=1e-5, atol=1e-5)
    assert act(np.stack([obs, obs])).shape == (2, act_dim)  # a batch of observations
    env.step(action)
    env.close()
    with pytest.raises(ValueError, match="this env has"):
        example.policy(gym.make("agent_envs/StiffSwarm-v0"))  # N = 100: another shape


@pytest.mark.slow
def test_tiny_training_run_scores_end_to_end(tmp_path):
    pytest.importorskip("torch")
    saved = tmp_path / "run" / "policy.npz"
    env = {**os.environ, "OMP_NUM_THREADS": "1", "CLEANRL_SWARM_POLICY": str(saved)}
    train = [sys.executable, str(SCRIPT), "--total-timesteps", "1024", "--num-envs", "4"]
    out = subprocess.run(
        [*train, "--save-path", str(saved)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    assert saved.is_file() and "-p cleanrl=examples.cleanrl_ppo_swarm:policy" in out.stdout

    scores = tmp_path / "scores"
    evaluate = [
        sys.executable,
        "-m",
        "agent_envs.training.commands.cli",
        "evaluate",
        "--task",
        TASK,
    ]
    out = subprocess.run(
        [*evaluate, "-p", "cleanrl=examples.cleanrl_ppo_swarm:policy", "--out", str(scores)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stdout + out.stderr
    with open(scores / "scores.csv", newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r["policy"] == "cleanrl"]
    assert len(rows) == 20
    for row in rows:
        cost, value, zero = float(row["cost"]), float(row["value"]), float(row["zero_cost"])
        assert math.isfinite(cost) and row["diverged"] == "False"
        expected = 100 * (zero - cost) / (zero - value)
        assert float(row["score"]) == pytest.approx(expected, rel=0, abs=1e-9)
