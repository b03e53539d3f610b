"""Checkpoints of a training run: where a run directory keeps its models, how they are saved,
and which checkpoint a resumed run may trust.

A run directory holds ``checkpoints/`` named as SB3's `CheckpointCallback` names its files
(``rl_model_{t}_steps.zip``, ``rl_model_vecnormalize_{t}_steps.pkl``,
``rl_model_replay_buffer_{t}_steps.pkl``), plus the best and final models with their
`VecNormalize` statistics next to them as ``{stem}_vecnormalize.pkl``. Every one of these files is
written atomically and its SHA-256 recorded in the run's ``manifest.json``
(`agent_envs.training.storage.save_recorded`); the model file of a checkpoint is written last.

`resumable_checkpoint` picks the newest checkpoint whose files are whole (the zip opens and its
members pass their CRC checks) and match their recorded hashes, and says which newer ones it
skipped and why, so a run killed while writing (or a file damaged later) resumes from the
newest valid state instead of crashing.
"""

from __future__ import annotations

import os
import re
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from agent_envs.training.storage import RunManifest, save_recorded

#: File names in a run directory.
BEST_MODEL = "best_model.zip"
BEST_VECNORMALIZE = "best_model_vecnormalize.pkl"
FINAL_MODEL = "final_model.zip"
FINAL_VECNORMALIZE = "final_model_vecnormalize.pkl"
CHECKPOINT_PREFIX = "rl_model"


def best_model_path(run_dir: str | Path) -> Path:
    """The model a run is evaluated with: the best on the validation seeds, else the final one."""
    best = Path(run_dir) / BEST_MODEL
    return best if best.exists() else Path(run_dir) / FINAL_MODEL


def checkpoint_model(run_dir: str | Path, steps: int) -> Path:
    """Path of a checkpoint's model zip."""
    return Path(run_dir) / "checkpoints" / f"{CHECKPOINT_PREFIX}_{steps}_steps.zip"


def checkpoint_file(run_dir: str | Path, kind: str, steps: int) -> Path:
    """Path of a checkpoint part as CheckpointCallback names it (kind: vecnormalize, ...)."""
    return Path(run_dir) / "checkpoints" / f"{CHECKPOINT_PREFIX}_{kind}_{steps}_steps.pkl"


def checkpoint_steps(run_dir: str | Path) -> list[int]:
    """Timesteps of every checkpoint model file in the run, newest first."""
    folder = Path(run_dir) / "checkpoints"
    steps = []
    for path in folder.glob(f"{CHECKPOINT_PREFIX}_*_steps.zip"):
        match = re.fullmatch(rf"{CHECKPOINT_PREFIX}_(\d+)_steps\.zip", path.name)
        if match:
            steps.append(int(match.group(1)))
    return sorted(steps, reverse=True)


def latest_checkpoint(
    run_dir: str | Path, off_policy: bool, normalize: bool
) -> tuple[int, Path] | None:
    """(timesteps, model path) of the newest checkpoint with all its files, or None.

    Existence only; `resumable_checkpoint` also verifies the files.
    """
    for steps in checkpoint_steps(run_dir):
        if normalize and not checkpoint_file(run_dir, "vecnormalize", steps).exists():
            continue
        if off_policy and not checkpoint_file(run_dir, "replay_buffer", steps).exists():
            continue
        return steps, checkpoint_model(run_dir, steps)
    return None


def zip_problem(path: str | os.PathLike) -> str | None:
    """Why `path` is not a whole SB3 model zip (None: it is)."""
    try:
        with zipfile.ZipFile(path) as zf:
            bad = zf.testzip()
            names = zf.namelist()
    except (OSError, zipfile.BadZipFile, EOFError) as exc:
        return f"{Path(path).name} is not a readable zip ({exc})"
    if bad is not None:
        return f"{Path(path).name}: member {bad} fails its CRC check"
    if "data" not in names:
        return f"{Path(path).name} has no SB3 'data' member"
    return None


@dataclass
class ResumePoint:
    """The checkpoint a resumed run continues from, and what was skipped on the way."""

    steps: int
    model: Path
    vecnormalize: Path | None
    replay_buffer: Path | None
    #: one line per newer checkpoint that failed verification
    skipped: list[str] = field(default_factory=list)
    #: set when an off-policy run falls back to a checkpoint without its replay buffer
    buffer_note: str | None = None


def checkpoint_problems(
    run_dir: str | Path, steps: int, normalize: bool, manifest: RunManifest
) -> list[str]:
    """What is wrong with the model and statistics of one checkpoint ([] when valid)."""
    problems = []
    model = checkpoint_model(run_dir, steps)
    for check in (zip_problem(model), manifest.problem(model)):
        if check:
            problems.append(check)
            break
    if normalize:
        stats = checkpoint_file(run_dir, "vecnormalize", steps)
        if not stats.exists():
            problems.append(f"{stats.name} is missing")
        else:
            check = manifest.problem(stats)
            if check:
                problems.append(check)
    return problems


def resumable_checkpoint(
    run_dir: str | Path, off_policy: bool, normalize: bool
) -> tuple[ResumePoint | None, list[str]]:
    """The newest verified checkpoint of a run (None if there is no checkpoint at all).

    Returns (point, skipped): `skipped` names each newer checkpoint that failed and why. Raises
    ValueError when checkpoints exist but none is valid, or when the run has checkpoints but no
    manifest to verify them against (written before manifests existed, or not by this project).
    An off-policy checkpoint without a valid replay buffer is used only when no newer one has a
    valid buffer; its `buffer_note` says the buffer starts empty.
    """
    run_dir = Path(run_dir)
    steps_list = checkpoint_steps(run_dir)
    if not steps_list:
        return None, []
    manifest = RunManifest(run_dir)
    if not manifest.exists():
        raise ValueError(
            f"--resume {run_dir}: no {manifest.path.name} to verify its checkpoints against (the "
            "run was not written by this version of agent-envs); checkpoints are pickles, so "
            "they are loaded only when their SHA-256 is recorded"
        )
    skipped: list[str] = []
    for steps in steps_list:
        problems = checkpoint_problems(run_dir, steps, normalize, manifest)
        if problems:
            skipped.append(f"checkpoint at {steps} timesteps: {'; '.join(problems)}")
            continue
        stats = checkpoint_file(run_dir, "vecnormalize", steps) if normalize else None
        point = ResumePoint(steps, checkpoint_model(run_dir, steps), stats, None, list(skipped))
        if off_policy:
            buffer = checkpoint_file(run_dir, "replay_buffer", steps)
            problem = manifest.problem(buffer) if buffer.exists() else f"{buffer.name} is missing"
            if problem is None:
                point.replay_buffer = buffer
            else:
                point.buffer_note = f"no valid replay buffer ({problem}); it starts empty"
        return point, skipped
    raise ValueError(
        f"--resume {run_dir}: no valid checkpoint ({' | '.join(skipped)}); start a new run"
    )


def _save_model(model: Any, run_dir: Path, path: Path) -> Path:
    return save_recorded(run_dir, path, lambda tmp: model.save(tmp))


def _save_statistics(stats: Any, run_dir: Path, path: Path) -> Path:
    return save_recorded(run_dir, path, lambda tmp: stats.save(str(tmp)))


def save_model_with_statistics(model: Any, run_dir: str | Path, model_name: str) -> Path:
    """Save ``model_name`` (e.g. best_model.zip) and its VecNormalize statistics, recorded."""
    run_dir = Path(run_dir)
    stats = model.get_vec_normalize_env()
    if stats is not None:
        stem = model_name[:-4] if model_name.endswith(".zip") else model_name
        _save_statistics(stats, run_dir, run_dir / f"{stem}_vecnormalize.pkl")
    return _save_model(model, run_dir, run_dir / model_name)


def save_checkpoint(model: Any, run_dir: str | Path, off_policy: bool) -> Path:
    """Save model, VecNormalize statistics and replay buffer as CheckpointCallback names them.

    Each file is atomic and recorded in the manifest; the model file is written last, so a
    checkpoint is complete once its model file exists.
    """
    run_dir = Path(run_dir)
    steps = int(model.num_timesteps)
    folder = run_dir / "checkpoints"
    folder.mkdir(parents=True, exist_ok=True)
    if off_policy:
        buffer = checkpoint_file(run_dir, "replay_buffer", steps)
        save_recorded(run_dir, buffer, lambda tmp: model.save_replay_buffer(tmp))
        prune_replay_buffers(run_dir, keep_timesteps=steps)
    stats = model.get_vec_normalize_env()
    if stats is not None:
        _save_statistics(stats, run_dir, checkpoint_file(run_dir, "vecnormalize", steps))
    return _save_model(model, run_dir, checkpoint_model(run_dir, steps))


def checkpoint_callback(save_freq: int, run_dir: str | Path, off_policy: bool) -> Any:
    """An SB3 callback saving a checkpoint (`save_checkpoint`) every `save_freq` calls.

    It replaces SB3's `CheckpointCallback` (same file names) to write atomically, record the
    hashes and keep only the newest replay buffer: SB3 pickles the whole preallocated buffer,
    whose size grows with N and `buffer_size` (docs/learners/sb3.md has the sizes).
    """
    from stable_baselines3.common.callbacks import BaseCallback

    class RunCheckpointCallback(BaseCallback):
        def _on_step(self) -> bool:
            if self.n_calls % save_freq == 0:
                save_checkpoint(self.model, run_dir, off_policy)
            return True

    return RunCheckpointCallback()


def prune_replay_buffers(run_dir: str | os.PathLike, keep_timesteps: int) -> None:
    """Delete the checkpoints' replay buffers except the one at `keep_timesteps`."""
    folder = Path(run_dir) / "checkpoints"
    old = [
        path
        for path in folder.glob("*_replay_buffer_*_steps.pkl")
        if not path.name.endswith(f"_replay_buffer_{keep_timesteps}_steps.pkl")
    ]
    for path in old:
        path.unlink()
    RunManifest(run_dir).forget(old)
