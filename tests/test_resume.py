"""Resume paths of `train` and `sweep` that tests/test_training.py and tests/test_sweep.py leave
out (issue 24): a run without a manifest, an off-policy run whose replay buffer is gone, a
second concurrent resume refused by the run's lock, a sweep's learner trial continuing its run,
and a sweep resumed with another preset.

Through the public entry points where they exist (`agent-envs train --resume`,
`agent_envs.training.commands.train.train`, `agent-envs sweep`); the sweep's learner trial goes
through `agent_envs.training.commands.sweep.train_learner` (what the Tune trainable calls). The runs
are tiny (N = 5, m = 10, a few hundred timesteps) and marked slow.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

pytest.importorskip("stable_baselines3")

from agent_envs.training.config import TrainConfig
from agent_envs.training.defaults import GYM_ENV_ID

TINY_ENV = {"n_agents": 5, "n_steps": 10}
TINY_HYPERPARAMS = {
    "ppo": {"n_steps": 16, "batch_size": 32, "n_epochs": 2},
    "sac": {"learning_starts": 50, "batch_size": 32},
    "td3": {"learning_starts": 50, "batch_size": 32},
}


def tiny_run(tmp_path: Path, algo: str, timesteps: int = 200, verbose: int = 0) -> Path:
    from agent_envs.training.commands.train import train

    config = TrainConfig(
        algo=algo,
        env_id=GYM_ENV_ID,
        env_kwargs=dict(TINY_ENV),
        timesteps=timesteps,
        seed=0,
        out=str(tmp_path / "runs"),
        hyperparams=dict(TINY_HYPERPARAMS[algo]),
        eval_freq=100,
        eval_episodes=2,
        checkpoint_freq=100,
        progress_bar=False,
        tensorboard=False,
        verbose=verbose,
    )
    return train(config)


def resume_config(run_dir: Path, timesteps: int) -> TrainConfig:
    return TrainConfig(
        resume=str(run_dir), timesteps=timesteps, progress_bar=False, tensorboard=False
    )


@pytest.mark.slow
def test_resume_without_a_manifest_is_refused_before_anything_is_written(tmp_path, capsys):
    from agent_envs.training.commands.cli import main
    from agent_envs.training.commands.train import train

    run_dir = tiny_run(tmp_path, "ppo")
    (run_dir / "manifest.json").unlink()
    before = {p: p.stat().st_mtime_ns for p in run_dir.rglob("*") if p.is_file()}
    with pytest.raises(ValueError, match=r"--resume .*manifest\.json"):
        train(resume_config(run_dir, 400))
    # the CLI: one line, exit code 2
    assert main(["train", "--resume", str(run_dir), "--timesteps", "400"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "manifest.json" in err[0] and "--resume" in err[0]
    after = {p: p.stat().st_mtime_ns for p in run_dir.rglob("*") if p.is_file()}
    assert after == before  # nothing rewritten, nothing added


@pytest.mark.slow
@pytest.mark.parametrize("algo", ["sac", "td3"])
def test_off_policy_resume_without_its_replay_buffer_starts_it_empty(algo, tmp_path, capsys):
    from stable_baselines3.common.callbacks import BaseCallback

    from agent_envs.training.commands.train import train

    run_dir = tiny_run(tmp_path, algo)
    buffers = sorted((run_dir / "checkpoints").glob("*_replay_buffer_*_steps.pkl"))
    assert len(buffers) == 1  # only the newest is kept
    buffers[0].unlink()
    capsys.readouterr()

    class BufferAtStart(BaseCallback):
        size: int | None = None
        timesteps: int | None = None

        def _on_training_start(self) -> None:
            BufferAtStart.size = self.model.replay_buffer.size()
            BufferAtStart.timesteps = self.model.num_timesteps

        def _on_step(self) -> bool:
            return True

    assert train(resume_config(run_dir, 300), callbacks=[BufferAtStart()]) == run_dir
    err = capsys.readouterr().err
    assert "no valid replay buffer" in err and "it starts empty" in err
    assert BufferAtStart.timesteps == 200  # the weights and timesteps of the checkpoint
    assert BufferAtStart.size == 0  # the buffer, gone, starts empty
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["timesteps"] >= 300


@pytest.mark.slow
def test_a_second_concurrent_resume_is_refused_by_the_lock(tmp_path):
    from agent_envs.training.commands.train import train
    from agent_envs.training.storage import RunDirectoryBusy, RunLock

    run_dir = tiny_run(tmp_path, "ppo")
    summary = (run_dir / "summary.json").read_text()
    with RunLock(run_dir):  # another process resuming it holds this lock
        with pytest.raises(RunDirectoryBusy, match="in use"):
            train(resume_config(run_dir, 400))
    assert (run_dir / "summary.json").read_text() == summary
    # released: the resume goes ahead
    assert train(resume_config(run_dir, 300)) == run_dir
    assert json.loads((run_dir / "summary.json").read_text())["timesteps"] >= 300


@pytest.mark.slow
def test_a_sweep_learner_trial_continues_its_interrupted_run(tmp_path):
    """A learner trial whose run was interrupted (KeyboardInterrupt half-way, as a stopped
    sweep leaves it: same configuration, checkpoints, no summary) continues that run to the
    trial's budget, keeping its history, instead of starting anew or failing on the folder."""
    from stable_baselines3.common.callbacks import BaseCallback

    from agent_envs.training.commands import sweep
    from agent_envs.training.commands.sweep import SweepConfig, _load_or_save_grid, learner_run_dir
    from agent_envs.training.commands.train import train
    from agent_envs.training.learners.callbacks import read_learning_curve

    # what the Tune trainable calls for a learner trial (train_trial after the CLI refactor)
    train_learner = getattr(sweep, "train_learner", None) or sweep.train_trial
    out = tmp_path / "sweep"
    _, trials, _ = _load_or_save_grid(SweepConfig(preset="smoke", out=str(out)), out)
    trial = next(t for t in trials if t.kind == "learner")
    budget = int(trial.train["timesteps"])

    class InterruptHalfway(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps >= budget // 2:
                raise KeyboardInterrupt
            return True

    config = TrainConfig.from_dict({**trial.train, "out": str(out / "runs")})
    with pytest.raises(KeyboardInterrupt):
        train(config, callbacks=[InterruptHalfway()])
    run_dir = learner_run_dir(trial, out)
    assert run_dir.is_dir() and not (run_dir / "summary.json").exists()
    first = read_learning_curve(run_dir / "learning_curve.csv")

    assert train_learner(trial, out) == run_dir
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["timesteps"] >= budget
    curve = read_learning_curve(run_dir / "learning_curve.csv")
    assert curve[: len(first)] == first  # the interrupted part's evaluations are kept
    assert [p.name for p in (out / "runs").iterdir() if p.is_dir()] == [run_dir.name]


def test_a_sweep_resumed_with_another_preset_is_refused(tmp_path, capsys):
    from agent_envs.training.commands.cli import main
    from agent_envs.training.commands.sweep import SweepConfig, _load_or_save_grid

    out = tmp_path / "sweep"
    _load_or_save_grid(SweepConfig(preset="smoke", out=str(out)), out)
    saved = (out / "sweep.json").read_text()
    assert main(["sweep", "--preset", "paper", "--out", str(out), "--resume"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--resume" in err[0] and "smoke preset, not paper" in err[0]
    assert (out / "sweep.json").read_text() == saved


@pytest.mark.parametrize("verbose", [0, 1])
def test_training_without_tensorboard_leaves_no_folder_in_the_temp_dir(
    tmp_path, monkeypatch, capsys, verbose
):
    """SB3 gives `learn` a logger whose folder is a fresh $TMPDIR/SB3-<date> when TensorBoard is
    off; the training layer logs without a folder instead (training and its resume), to the
    standard output with verbose >= 1."""
    import dataclasses
    import tempfile

    temp = tmp_path / "tmp"
    temp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temp))
    from agent_envs.training.commands.train import train

    run_dir = tiny_run(tmp_path, "ppo", timesteps=128, verbose=verbose)
    train(dataclasses.replace(resume_config(run_dir, 256), verbose=verbose))
    assert (run_dir / "manifest.json").is_file()
    assert ("total_timesteps" in capsys.readouterr().out) == (verbose >= 1)
    assert [p.name for p in temp.iterdir() if p.name.startswith("SB3-")] == []
