"""How a trial's learner is trained: a new run, or the run of the same configuration reused
or resumed.

`train_from_dict(train)` trains the learner of a trial's training dict (`Trial.train`: an SB3
`TrainConfig` dict, or an apg one with ``algo == "apg"``) and returns its run folder. Both
`agent-envs compare` and `sweep` (and `leaderboard`) train through it: a finished run of the
same configuration (`SAME_RUN_FIELDS` for SB3; every `APGConfig` field but `progress`, `threads`
and `iterations` for apg) is reused, an unfinished one continues from its last checkpoint, and
``retrain`` starts a new run. `evaluation_spec` names what the held-out evaluation loads of a
trained run; `budget` says a trial's budget in words.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

from agent_envs.training.commands.experiment import APG, APG_RUN_KEYS
from agent_envs.training.config import TrainConfig

#: A run is reused or resumed only when all of these match, the budget included: a run resumed
#: with another budget would keep its old evaluation and checkpoint schedule. ``env_kwargs``
#: match when they name the same env (`same_env_kwargs`: defaults spelt out or left out).
SAME_RUN_FIELDS = (
    "algo",
    "env_id",
    "env_kwargs",
    "seed",
    "n_envs",
    "hyperparams",
    "eval_seed",
    "timesteps",
)


def same_env_kwargs(saved: Any, wanted: Any) -> bool:
    """Whether two env kwargs dicts name the same env: equal, or both valid and equal once
    validated (`EpisodeConfig.from_kwargs`), so a run saved with every default spelt out (a
    leaderboard task's kwargs) matches the same env given by its overrides only (a sweep's)."""
    if saved == wanted:
        return True
    if not isinstance(saved, dict) or not isinstance(wanted, dict):
        return False
    from agent_envs.envs.episode_config import EpisodeConfig

    try:
        return bool(EpisodeConfig.from_kwargs(**saved) == EpisodeConfig.from_kwargs(**wanted))
    except (TypeError, ValueError):  # invalid kwargs, or fields that do not compare (arrays)
        return False


def _same_field(name: str, saved: Any, wanted: Any) -> bool:
    return same_env_kwargs(saved, wanted) if name == "env_kwargs" else saved == wanted


def find_run(wanted: TrainConfig) -> tuple[Path, bool] | None:
    """The newest run of `wanted`'s configuration in ``wanted.out``: (run dir, finished).

    With a `run_name`, only that folder is a candidate; without, every run folder there.
    A run is finished when its summary counts at least `wanted.timesteps` timesteps.
    """
    runs_dir = Path(wanted.out)
    paths = (
        [runs_dir / wanted.run_name / "config.json"]
        if wanted.run_name
        else list(runs_dir.glob("*/config.json"))
    )
    candidates = []
    for cfg_path in paths:
        try:
            saved = json.loads(cfg_path.read_text())
        except (OSError, json.JSONDecodeError):
            continue
        if not all(_same_field(k, saved.get(k), getattr(wanted, k)) for k in SAME_RUN_FIELDS):
            continue
        summary_path = cfg_path.parent / "summary.json"
        finished = False
        if summary_path.exists():
            summary = json.loads(summary_path.read_text())
            finished = int(summary.get("timesteps", 0)) >= wanted.timesteps
        candidates.append((cfg_path.stat().st_mtime, cfg_path.parent, finished))
    if not candidates:
        return None
    _, run_dir, finished = max(candidates)
    return run_dir, finished


def train_learner(config: TrainConfig, *, retrain: bool = False) -> Path:
    """Train one learner, or reuse / resume its run; return the run directory.

    A finished run of the same configuration (`SAME_RUN_FIELDS`, `find_run`) is reused, an
    unfinished one continues from its last checkpoint (`train --resume`); `retrain` starts a
    new run whatever is there.
    """
    from agent_envs.training.commands.train import train

    existing = None if retrain else find_run(config)
    if existing is None:
        return train(config)
    run_dir, finished = existing
    if finished:
        print(f"  reusing finished run {run_dir}")
        return run_dir
    print(f"  resuming {run_dir} from its last checkpoint")
    return train(dataclasses.replace(config, resume=str(run_dir)))


def _apg_run(config: Any, out: Path, run_name_: str | None) -> tuple[Path, bool] | None:
    """The newest apg run in `out` (or `out/run_name_`) with `config`'s settings (`progress`
    and `threads` aside): (run dir, finished with enough iterations)."""
    from agent_envs.training.learners.apg_policy import is_apg_run

    wanted = {k: v for k, v in config.to_dict().items() if k not in ("progress", "threads")}
    wanted = json.loads(json.dumps(wanted))
    folders = [out / run_name_] if run_name_ else [p for p in out.glob("*") if is_apg_run(p)]
    candidates = []
    for folder in folders:
        try:
            saved = json.loads((folder / "config.json").read_text())
        except (OSError, json.JSONDecodeError):
            continue
        if not all(_same_field(k, saved.get(k), v) for k, v in wanted.items() if k != "iterations"):
            continue
        try:
            done = int(json.loads((folder / "summary.json").read_text())["iterations"])
        except (OSError, ValueError, KeyError):
            done = 0
        candidates.append((folder.stat().st_mtime, folder, done >= config.iterations))
    if not candidates:
        return None
    _, folder, finished = max(candidates)
    return folder, finished


def train_apg_trial(train: dict[str, Any], *, retrain: bool = False) -> Path:
    """Train the apg learner of a training dict (`apg_trial`), or reuse / resume its run."""
    from agent_envs.training.learners.apg import train_apg
    from agent_envs.training.learners.apg_config import APGConfig, default_run_dir

    config = APGConfig.from_dict({k: v for k, v in train.items() if k not in APG_RUN_KEYS})
    out = Path(train["out"])
    existing = None if retrain else _apg_run(config, out, train.get("run_name"))
    if existing is None:
        name = train.get("run_name")
        run_dir = out / name if name else default_run_dir(out, config)
        out.mkdir(parents=True, exist_ok=True)
        train_apg(config, run_dir)
        return run_dir
    run_dir, finished = existing
    if finished:
        print(f"  reusing finished run {run_dir}")
        return run_dir
    print(f"  resuming {run_dir} from its last checkpoint")
    train_apg(config, run_dir, resume=True)
    return run_dir


def train_from_dict(train: dict[str, Any], *, retrain: bool = False) -> Path:
    """Train a trial's learner from its training dict (SB3 `TrainConfig` or apg), or reuse /
    resume its run; return the run directory."""
    if train.get("algo") == APG:
        return train_apg_trial(train, retrain=retrain)
    return train_learner(TrainConfig.from_dict(train), retrain=retrain)


def budget(train: dict[str, Any]) -> str:
    """A trial's training budget in words: SB3 timesteps or apg iterations."""
    if train.get("algo") == APG:
        return f"{train['iterations']} iterations"
    return f"{train['timesteps']} timesteps"


def evaluation_spec(run_dir: Path) -> str:
    """What `evaluate_policies` loads for a trained run: an apg run folder as it is, an SB3
    run's best model on the validation seeds (else its final one)."""
    from agent_envs.training.learners.apg_policy import is_apg_run
    from agent_envs.training.learners.checkpoints import best_model_path

    return str(run_dir) if is_apg_run(run_dir) else str(best_model_path(run_dir))


__all__ = [
    "SAME_RUN_FIELDS",
    "budget",
    "evaluation_spec",
    "find_run",
    "same_env_kwargs",
    "train_apg_trial",
    "train_from_dict",
    "train_learner",
]
