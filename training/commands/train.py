"""The training loop: `train(TrainConfig)` trains a Stable-Baselines3 agent on a swarm env.

The command line is `agent-envs train` (`agent_envs.training.commands.cli`):

    agent-envs train --algo ppo --env-id agent_envs/Swarm-v0 \\
        --env-kwargs '{"n_agents": 10, "n_steps": 20}' --timesteps 50000 --seed 0 --out runs
    agent-envs train --algo ppo --env-id agent_envs.swarm_v0 ...     # parameter-shared PPO
    agent-envs train --resume runs/agent_envs_Swarm-v0__ppo__0__1700000000

Everything is SB3's own machinery: vectorized envs (`make_vec_env`, or SuperSuit for the
PettingZoo env), `VecNormalize` (statistics saved with every checkpoint and the model, frozen at
evaluation), `CheckpointCallback` (model + VecNormalize + replay buffer), an `EvalCallback`
subclass that logs the turnpike controller's cost on the same validation seeds
(`agent_envs.training.learners.callbacks.SwarmEvalCallback`), TensorBoard and the progress bar.

A run directory ``{out}/{env}__{algo}__{seed}__{unix time}`` holds:

    config.json            the TrainConfig (what --resume reads back)
    env.json               N, d, n_steps of the env (for loading the policy later), its
                           step plan (`StepPlan.describe`: which code a step runs)
    hyperparams.json       the SB3 keyword arguments used
    checkpoints/           rl_model_{t}_steps.zip, rl_model_vecnormalize_{t}_steps.pkl,
                           rl_model_replay_buffer_{t}_steps.pkl (off-policy; newest only)
    learning_curve.csv     validation cost vs timesteps, with the turnpike cost on those seeds
    evaluations.npz        SB3's EvalCallback log (rewards = minus costs)
    best_model.zip + best_model_vecnormalize.pkl    best on the validation seeds
    final_model.zip + final_model_vecnormalize.pkl  at the end of training
    summary.json           timesteps, wall time, last validation result
    tb/                    TensorBoard logs
    manifest.json          SHA-256 and size of every .zip and .pkl above
    .lock                  empty; flock-ed while a process trains in the run

The folder is created with an exclusive ``os.mkdir`` (a second process gets a ValueError), and
every file is written atomically (`agent_envs.training.storage`). Interrupting a run (Ctrl-C)
saves a checkpoint first; ``--resume RUN_DIR`` continues from the newest checkpoint whose files
are whole and match the manifest (model, VecNormalize statistics, replay buffer, timesteps done,
the learning curve up to that point), skipping damaged newer ones with a message.
"""

from __future__ import annotations

import contextlib
import json
import re
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from agent_envs.training.config import TrainConfig, resolve_hyperparams, sb3_kwargs
from agent_envs.training.defaults import (
    GYM_ENV_ID,
    OFF_POLICY,
    algorithm_class,
    default_interface,
    interface_of,
    is_multiagent,
)
from agent_envs.training.learners.environments import (
    env_description,
    eval_env_id,
    eval_env_kwargs,
    make_eval_vec_env,
    make_training_env,
    training_step_plan,
)
from agent_envs.training.storage import (
    RunLock,
    check_output_dir,
    create_run_directory,
    remove_stale_temporaries,
    write_json_atomic,
)

#: Options that may change when resuming; all others come from the run's config.json.
RESUME_OVERRIDES = (
    "timesteps",
    "progress_bar",
    "verbose",
    "device",
    "tensorboard",
    "torch_threads",
    "env_threads",
)


def default_run_name(config: TrainConfig) -> str:
    """``{env}__{algo}__{seed}__{unix time}`` (CleanRL's pattern; '/' in the env id -> '_')."""
    env = re.sub(r"[^A-Za-z0-9._-]", "_", config.env_id)
    return f"{env}__{config.algo}__{config.seed}__{int(time.time())}"


def train(
    config: TrainConfig,
    callbacks: Sequence[Any] | None = None,
    on_evaluation: Callable[[dict[str, Any]], None] | None = None,
) -> Path:
    """Train one agent; return its run directory.

    Everything is validated before anything is written: the options, the env kwargs, the
    output folder and, when resuming, the checkpoint to continue from. A new run directory is
    created exclusively (a second process with the same run directory gets a ValueError), and
    the run holds its lock (`agent_envs.training.storage.RunLock`) while it trains.

    With `config.resume` set to a run directory, the run continues from its newest verified
    checkpoint (`agent_envs.training.learners.checkpoints.resumable_checkpoint`; damaged newer ones
    are skipped with a message): its config.json defines the run, except `RESUME_OVERRIDES`,
    which are taken from `config`. `callbacks` are extra SB3 callbacks appended to the run's own;
    `on_evaluation` is called with every validation row (`callbacks.SwarmEvalCallback`).
    """
    if config.resume:
        run_dir = Path(config.resume)
        saved = TrainConfig.from_dict(_read_run_config(run_dir))
        for name in RESUME_OVERRIDES:
            setattr(saved, name, getattr(config, name))
        saved.resume = str(run_dir)
        config = saved.validate()
        description = env_description(config.env_id, config.env_kwargs)
        lock = RunLock(run_dir).acquire()
    else:
        config.validate()
        check_output_dir(config.out, "--out")
        description = env_description(config.env_id, config.env_kwargs)
        run_dir = Path(config.out) / (config.run_name or default_run_name(config))
        create_run_directory(run_dir)  # exclusive: a second process stops here
        lock = RunLock(run_dir).acquire()
    try:
        with torch_threads(config.torch_threads):
            return _train_in(config, run_dir, list(callbacks or []), description, on_evaluation)
    finally:
        lock.release()


def _read_run_config(run_dir: Path) -> dict[str, Any]:
    """The config.json of a run directory; ValueError naming --resume when it is not one."""
    saved_path = run_dir / "config.json"
    if not saved_path.is_file():
        raise ValueError(f"--resume {run_dir}: no config.json there (not a run directory)")
    try:
        data = json.loads(saved_path.read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"--resume {run_dir}: config.json is unreadable ({exc})") from None
    if not isinstance(data, dict):
        raise ValueError(f"--resume {run_dir}: config.json is not a JSON object")
    return data


@contextlib.contextmanager
def torch_threads(n: int):
    """Run with `n` torch intra-op threads (0: unchanged), restoring the previous number after.

    Small networks on a busy CPU run far faster with one thread than with torch's default of
    one per core (the threads spin-wait; docs/learners/sb3.md has the measurement).
    """
    import torch

    previous = torch.get_num_threads()
    if n > 0:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def _train_in(
    config: TrainConfig,
    run_dir: Path,
    extra_callbacks: list[Any],
    description: dict[str, Any],
    on_evaluation: Callable[[dict[str, Any]], None] | None = None,
) -> Path:
    """Train in `run_dir` (created and locked by `train`): resume point, run files, model,
    callbacks, learning, final checkpoint and summary."""
    from agent_envs.training.learners.checkpoints import FINAL_MODEL, save_model_with_statistics

    resolved = resolve_hyperparams(config)  # (SB3 kwargs, n_envs, VecNormalize kwargs, policy)
    off_policy = config.algo in OFF_POLICY
    point = _resume_point(config, run_dir, off_policy, resolved[2] is not None)
    if point is not None and point.steps >= config.timesteps:
        print(
            f"{run_dir.name}: {point.steps} timesteps already done (>= --timesteps "
            f"{config.timesteps}); nothing to train"
        )
        return run_dir
    _write_run_files(config, run_dir, description, resolved)
    model, venv = _build_model(config, run_dir, point, resolved)
    done = 0 if point is None else int(model.num_timesteps)
    callbacks, eval_callback = _callbacks(config, run_dir, venv.num_envs, description, done)
    if eval_callback is not None:
        eval_callback.on_evaluation = on_evaluation
    start = time.perf_counter()
    _learn(model, config, [*callbacks, *extra_callbacks], point is None, run_dir)
    if eval_callback is not None and (
        not eval_callback.history or eval_callback.history[-1]["timesteps"] != model.num_timesteps
    ):
        eval_callback.evaluate_now()  # the final model is always on the learning curve
    wall = time.perf_counter() - start
    save_checkpoint_of(model, run_dir, off_policy)  # the final state is the newest checkpoint
    save_model_with_statistics(model, run_dir, FINAL_MODEL)
    _write_summary(config, run_dir, description, model, wall, eval_callback)
    venv.close()
    return run_dir


def _resume_point(config: TrainConfig, run_dir: Path, off_policy: bool, normalize: bool):
    """The checkpoint to continue from (None for a new run), with what was skipped reported.

    Every run ends with a checkpoint of its final state, so the newest valid checkpoint is where
    a resumed run continues, finished or interrupted. Nothing in the run directory is rewritten
    before it is verified.
    """
    from agent_envs.training.learners.checkpoints import resumable_checkpoint

    if not config.resume:
        return None
    point, skipped = resumable_checkpoint(run_dir, off_policy, normalize)
    for line in skipped:
        print(f"{run_dir.name}: skipping the damaged {line}", file=sys.stderr)
    if point is not None and skipped:
        print(
            f"{run_dir.name}: resuming from the newest valid checkpoint, {point.model.name}",
            file=sys.stderr,
        )
    if point is not None and point.buffer_note:
        print(f"{run_dir.name}: {point.buffer_note}", file=sys.stderr)
    return point


def _write_run_files(
    config: TrainConfig, run_dir: Path, description: dict[str, Any], resolved: tuple
) -> None:
    """config.json, env.json and hyperparams.json (after removing a killed run's temporaries;
    the caller holds the run's lock)."""
    algo_kwargs, n_envs, normalize_kwargs, policy_name = resolved
    for folder in (run_dir, run_dir / "checkpoints"):
        remove_stale_temporaries(folder)
    write_json_atomic(run_dir / "config.json", {**config.to_dict(), "resume": None})
    write_json_atomic(run_dir / "env.json", description)
    write_json_atomic(
        run_dir / "hyperparams.json",
        {
            "algo": config.algo,
            "policy": policy_name,
            "n_envs": n_envs,
            "normalize": normalize_kwargs if normalize_kwargs is not None else False,
            **algo_kwargs,
        },
    )


def _build_model(config: TrainConfig, run_dir: Path, point, resolved: tuple):
    """(model, training VecEnv): a new SB3 model, or the one of checkpoint `point` with its
    VecNormalize statistics and replay buffer (verified against the run's manifest).
    `resolved` is `config.resolve_hyperparams(config)`."""
    from stable_baselines3.common.vec_env import VecNormalize

    algo_kwargs, n_envs, normalize_kwargs, policy_name = resolved
    venv = make_training_env(config, n_envs)
    cls = algorithm_class(config.algo)
    tb_log = str(run_dir / "tb") if config.tensorboard else None
    if point is None:
        if normalize_kwargs is not None:
            venv = VecNormalize(venv, **normalize_kwargs)
        action_dim = int(np.prod(venv.action_space.shape))
        model = cls(
            policy_name,
            venv,
            seed=config.seed,
            device=config.device,
            verbose=config.verbose,
            tensorboard_log=tb_log,
            **sb3_kwargs(algo_kwargs, action_dim),
        )
        return model, venv
    if point.vecnormalize is not None:
        venv = VecNormalize.load(str(point.vecnormalize), venv)
        venv.training = True
    model = cls.load(point.model, env=venv, device=config.device, tensorboard_log=tb_log)
    model.verbose = config.verbose
    if point.replay_buffer is not None:
        model.load_replay_buffer(point.replay_buffer)
    done = int(model.num_timesteps)
    model.set_random_seed(config.seed + done)  # a fresh, reproducible seeding of the rest
    print(f"resuming {run_dir.name} from {point.model.name} ({done} timesteps done)")
    return model, venv


def _callbacks(config, run_dir: Path, sb3_envs: int, description: dict[str, Any], done: int):
    """(the run's SB3 callbacks, its evaluation callback or None): checkpoints every
    `checkpoint_freq` timesteps, validation every `eval_freq` with the reference controllers
    logged on the same seeds (the learning curve continues from `done` timesteps)."""
    from agent_envs.baselines import ProportionalController, TurnpikeController, ZeroController
    from agent_envs.training.learners.callbacks import SwarmEvalCallback, read_learning_curve
    from agent_envs.training.learners.checkpoints import checkpoint_callback
    from agent_envs.training.learners.policies import live_policy

    off_policy = config.algo in OFF_POLICY
    callbacks: list[Any] = []
    if config.checkpoint_freq > 0:
        callbacks.append(
            checkpoint_callback(max(config.checkpoint_freq // sb3_envs, 1), run_dir, off_policy)
        )
    if config.eval_freq <= 0:
        return callbacks, None
    shape = (description["n_agents"], description["dim"]) if is_multiagent(config.env_id) else None
    eval_kwargs = eval_env_kwargs(config)
    eval_vec = make_eval_vec_env(eval_env_id(config), eval_kwargs, config.eval_episodes)
    # the references act on the default interface: same dynamics, cost and draws (env options);
    # the validation env itself when it has the default interface
    reference_kwargs = default_interface(config.env_kwargs)
    reference_vec = (
        eval_vec
        if reference_kwargs == eval_kwargs
        else make_eval_vec_env(GYM_ENV_ID, reference_kwargs, config.eval_episodes)
    )
    reference_env = reference_vec.envs[0]
    references = {
        "turnpike": TurnpikeController(
            reference_env, beta=config.turnpike_beta, delta=config.turnpike_delta
        ),
        "proportional": ProportionalController(reference_env, beta=config.turnpike_beta),
        "zero": ZeroController(reference_env),
    }
    eval_callback = SwarmEvalCallback(
        eval_vec,
        lambda m: live_policy(
            m,
            shape,
            interface_of(config.env_kwargs)["observation"],
            config.env_kwargs.get("neighbours"),
        ),
        references,
        reference_env=reference_vec,
        eval_seed=config.eval_seed,
        eval_freq=max(config.eval_freq // sb3_envs, 1),
        run_dir=run_dir,
        history=read_learning_curve(run_dir / "learning_curve.csv", done) if done else None,
        verbose=config.verbose,
    )
    return [*callbacks, eval_callback], eval_callback


def _learn(model, config: TrainConfig, callbacks: list[Any], fresh: bool, run_dir: Path) -> None:
    """`model.learn` for the timesteps left; on Ctrl-C, a checkpoint first, then re-raise."""
    from stable_baselines3.common.callbacks import CallbackList

    remaining = config.timesteps - (0 if fresh else int(model.num_timesteps))
    if remaining <= 0:
        return
    if model.tensorboard_log is None:
        _log_without_folder(model)
    try:
        model.learn(
            total_timesteps=remaining,
            callback=CallbackList(callbacks),
            progress_bar=config.progress_bar,
            reset_num_timesteps=fresh,
            tb_log_name="run",
        )
    except KeyboardInterrupt:
        path = save_checkpoint_of(model, run_dir, config.algo in OFF_POLICY)
        print(
            f"\ninterrupted at {model.num_timesteps} timesteps; checkpoint {path}\n"
            f"continue with: agent-envs train --resume {run_dir}",
            file=sys.stderr,
        )
        raise


def _log_without_folder(model: Any) -> None:
    """SB3's logger without a folder (standard output only, with verbose >= 1): without
    TensorBoard, `model.learn` configures one whose folder is a fresh, empty
    ``$TMPDIR/SB3-<date>`` directory per call, which nothing reads and nothing removes."""
    from stable_baselines3.common.logger import HumanOutputFormat, Logger

    formats = [HumanOutputFormat(sys.stdout)] if model.verbose >= 1 else []
    model.set_logger(Logger(folder=None, output_formats=formats))


def save_checkpoint_of(model: Any, run_dir: Path, off_policy: bool) -> Path:
    """`checkpoints.save_checkpoint` (imported lazily: it needs SB3)."""
    from agent_envs.training.learners.checkpoints import save_checkpoint

    return save_checkpoint(model, run_dir, off_policy)


def _write_summary(config, run_dir: Path, description, model, wall: float, eval_callback) -> None:
    """summary.json: timesteps, swarm steps, training wall time (added over resumes), the last
    validation result, and the native training env's step plan (`training_step_plan`; None
    for DummyVecEnv or SubprocVecEnv, whose envs are env.json's)."""
    summary_path = run_dir / "summary.json"
    try:
        previous = json.loads(summary_path.read_text()) if summary_path.exists() else {}
    except ValueError:
        previous = {}
    steps = int(model.num_timesteps)
    write_json_atomic(
        summary_path,
        {
            "run_name": run_dir.name,
            "algo": config.algo,
            "env_id": config.env_id,
            "timesteps": steps,
            "swarm_steps": steps
            // (description["n_agents"] if is_multiagent(config.env_id) else 1),
            "train_wall_time_s": round(float(previous.get("train_wall_time_s", 0.0)) + wall, 2),
            "last_eval": eval_callback.history[-1]
            if eval_callback and eval_callback.history
            else None,
            "training_step_plan": training_step_plan(model.get_env()),
        },
    )


# --------------------------------------------------------------------------------------- CLI


def config_from_options(options: dict[str, Any]) -> TrainConfig:
    """The TrainConfig of the options given (with ``resume``: the run's config + overrides).

    `options` holds only the options the user gave (field name -> value). With ``resume`` set,
    only `RESUME_OVERRIDES` may be among them; ValueError naming the others otherwise.
    """
    given = dict(options)
    if given.get("resume"):
        base = _read_run_config(Path(given["resume"]))
        fixed = sorted(set(given) - set(RESUME_OVERRIDES) - {"resume"})
        if fixed:
            flags = ", ".join("--" + n.replace("_", "-") for n in fixed)
            raise ValueError(
                f"--resume continues the run as configured; {flags} cannot change "
                f"(allowed: {', '.join('--' + n.replace('_', '-') for n in RESUME_OVERRIDES)})"
            )
        base.update(given)
        return TrainConfig.from_dict(base)
    return TrainConfig(**given)
