"""Checkpoints of a training run: where a run directory keeps its models, and how they are saved.

A run directory holds ``checkpoints/`` as SB3's `CheckpointCallback` names the files
(``rl_model_{t}_steps.zip``, ``rl_model_vecnormalize_{t}_steps.pkl``,
``rl_model_replay_buffer_{t}_steps.pkl``), plus the best and final models with their
`VecNormalize` statistics next to them as ``{stem}_vecnormalize.pkl`` (the name
`agent_envs.training.policies.find_vecnormalize` looks for). A checkpoint counts once its model
file exists (it is written last), so the newest complete checkpoint is where a resumed run
continues.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

from stable_baselines3.common.callbacks import CheckpointCallback

#: File names in a run directory.
BEST_MODEL = "best_model.zip"
BEST_VECNORMALIZE = "best_model_vecnormalize.pkl"
FINAL_MODEL = "final_model.zip"
FINAL_VECNORMALIZE = "final_model_vecnormalize.pkl"
CHECKPOINT_PREFIX = "rl_model"


def latest_checkpoint(
    run_dir: str | Path, off_policy: bool, normalize: bool
) -> tuple[int, Path] | None:
    """(timesteps, model path) of the newest checkpoint with all its files, or None."""
    folder = Path(run_dir) / "checkpoints"
    found = []
    for path in folder.glob(f"{CHECKPOINT_PREFIX}_*_steps.zip"):
        match = re.fullmatch(rf"{CHECKPOINT_PREFIX}_(\d+)_steps\.zip", path.name)
        if not match:
            continue
        steps = int(match.group(1))
        if normalize and not checkpoint_file(run_dir, "vecnormalize", steps).exists():
            continue
        if off_policy and not checkpoint_file(run_dir, "replay_buffer", steps).exists():
            continue
        found.append((steps, path))
    return max(found) if found else None


def checkpoint_file(run_dir: str | Path, kind: str, steps: int) -> Path:
    """Path of a checkpoint part as CheckpointCallback names it (kind: vecnormalize, ...)."""
    return Path(run_dir) / "checkpoints" / f"{CHECKPOINT_PREFIX}_{kind}_{steps}_steps.pkl"


def save_checkpoint(model: Any, run_dir: str | Path, off_policy: bool) -> Path:
    """Save model, VecNormalize statistics and replay buffer as CheckpointCallback does."""
    steps = int(model.num_timesteps)
    folder = Path(run_dir) / "checkpoints"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{CHECKPOINT_PREFIX}_{steps}_steps.zip"
    if off_policy:
        model.save_replay_buffer(checkpoint_file(run_dir, "replay_buffer", steps))
        prune_replay_buffers(folder, keep_timesteps=steps)
    stats = model.get_vec_normalize_env()
    if stats is not None:
        stats.save(str(checkpoint_file(run_dir, "vecnormalize", steps)))
    model.save(path)  # last: a checkpoint counts once its model file exists
    return path


class ReplayBufferPruningCheckpointCallback(CheckpointCallback):
    """SB3's `CheckpointCallback` that keeps only the newest replay buffer on disk.

    SB3 pickles the whole preallocated buffer, whose size grows with N and `buffer_size` (README.md
    has the sizes). Older checkpoints keep their model and VecNormalize statistics; resuming uses
    the newest checkpoint, which has all three.
    """

    def _on_step(self) -> bool:
        result = super()._on_step()
        if self.save_replay_buffer and self.n_calls % self.save_freq == 0:
            prune_replay_buffers(self.save_path, keep_timesteps=self.num_timesteps)
        return result


def prune_replay_buffers(folder: str | os.PathLike, keep_timesteps: int) -> None:
    """Delete ``*_replay_buffer_{t}_steps.pkl`` files in `folder` except for t = keep."""
    for path in Path(folder).glob("*_replay_buffer_*_steps.pkl"):
        if not path.name.endswith(f"_replay_buffer_{keep_timesteps}_steps.pkl"):
            path.unlink()
