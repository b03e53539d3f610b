"""`agent-envs train`: train a Stable-Baselines3 agent on a swarm env (thin CLI over `train`).

    agent-envs train --algo ppo --env-id agent_envs/Swarm-v0 \\
        --env-kwargs '{"n_agents": 10, "n_steps": 20}' --timesteps 50000 --seed 0 --out runs
    agent-envs train --algo ppo --env-id agent_envs.swarm_v0 ...     # parameter-shared PPO
    agent-envs train --resume runs/agent_envs_Swarm-v0__ppo__0__1700000000

Everything is SB3's own machinery: vectorized envs (`make_vec_env`, or SuperSuit for the
PettingZoo env), `VecNormalize` (statistics saved with every checkpoint and the model, frozen at
evaluation), `CheckpointCallback` (model + VecNormalize + replay buffer), an `EvalCallback`
subclass that logs the turnpike controller's cost on the same validation seeds
(`agent_envs.training.callbacks.SwarmEvalCallback`), TensorBoard and the progress bar.

A run directory ``{out}/{env}__{algo}__{seed}__{unix time}`` holds:

    config.json            the TrainConfig (what --resume reads back)
    env.json               N, d, n_steps of the env (for loading the policy later)
    hyperparams.json       the SB3 keyword arguments used
    checkpoints/           rl_model_{t}_steps.zip, rl_model_vecnormalize_{t}_steps.pkl,
                           rl_model_replay_buffer_{t}_steps.pkl (off-policy; newest only)
    learning_curve.csv     validation cost vs timesteps, with the turnpike cost on those seeds
    evaluations.npz        SB3's EvalCallback log (rewards = minus costs)
    best_model.zip + best_model_vecnormalize.pkl    best on the validation seeds
    final_model.zip + final_model_vecnormalize.pkl  at the end of training
    summary.json           timesteps, wall time, last validation result
    tb/                    TensorBoard logs

Interrupting a run (Ctrl-C) saves a checkpoint first; ``--resume RUN_DIR`` continues from the
last complete checkpoint (model, VecNormalize statistics, replay buffer, timesteps done, the
learning curve up to that point).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import re
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from agent_envs.training.config import (
    FINAL_MODEL,
    FINAL_VECNORMALIZE,
    NOISE_KEYS,
    OFF_POLICY,
    ZOO_KEYS,
    TrainConfig,
    add_dataclass_arguments,
    check_algo,
    default_hyperparams,
    is_multiagent,
)

#: Options that may change when resuming; all others come from the run's config.json.
RESUME_OVERRIDES = (
    "timesteps",
    "progress_bar",
    "verbose",
    "device",
    "tensorboard",
    "torch_threads",
)
CHECKPOINT_PREFIX = "rl_model"


def algorithm_class(algo: str):
    """The SB3 class of `algo` (ppo, sac, td3, a2c); ValueError naming --algo otherwise."""
    import stable_baselines3 as sb3

    return {"ppo": sb3.PPO, "sac": sb3.SAC, "td3": sb3.TD3, "a2c": sb3.A2C}[check_algo(algo)]


def default_run_name(config: TrainConfig) -> str:
    """``{env}__{algo}__{seed}__{unix time}`` (CleanRL's pattern; '/' in the env id -> '_')."""
    env = re.sub(r"[^A-Za-z0-9._-]", "_", config.env_id)
    return f"{env}__{config.algo}__{config.seed}__{int(time.time())}"


def make_gym_env(env_id: str, env_kwargs: dict[str, Any] | None = None):
    """`gym.make(env_id, **env_kwargs)` after registering the swarm envs."""
    import gymnasium as gym

    import agent_envs  # noqa: F401  (registers agent_envs/Swarm-v0)

    try:
        return gym.make(env_id, **(env_kwargs or {}))
    except TypeError as exc:  # unknown or mistyped keyword: a user error, not a crash
        raise ValueError(f"--env-kwargs {env_kwargs}: {exc}") from None


def eval_env_id(config: TrainConfig) -> str:
    """The Gymnasium env on which a run is evaluated (the PettingZoo env's Gymnasium twin)."""
    from agent_envs.training.config import GYM_ENV_ID

    return GYM_ENV_ID if is_multiagent(config.env_id) else config.env_id


def make_eval_vec_env(env_id: str, env_kwargs: dict[str, Any] | None, n_episodes: int):
    """Raw (unnormalized) DummyVecEnv with one sub-env per evaluation episode."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    kwargs = dict(env_kwargs or {})
    return DummyVecEnv([lambda: make_gym_env(env_id, kwargs)] * int(n_episodes))


def env_description(env_id: str, env_kwargs: dict[str, Any] | None) -> dict[str, Any]:
    """N, d, n_steps, integrator and the full kwargs of the Gymnasium env a run uses."""
    env = make_gym_env(env_id, env_kwargs)
    try:
        base = env.unwrapped
        params = base.params
        return {
            "env_id": env_id,
            "env_kwargs": dict(env_kwargs or {}),
            "n_agents": int(params.n_agents),
            "dim": int(params.dim),
            "n_steps": int(base.n_steps),
            "integrator": str(base.integrator_name),
            "max_control": float(base.max_control),
        }
    finally:
        env.close()


def resolve_hyperparams(
    config: TrainConfig,
) -> tuple[dict[str, Any], int, dict[str, Any] | None, str]:
    """(SB3 kwargs, n_envs, VecNormalize kwargs or None, policy) for a config.

    The defaults come from `HYPERPARAMS` (rl-zoo3 format: ``normalize`` is a bool or a dict of
    VecNormalize keyword arguments such as ``{norm_obs: true, norm_reward: false}``);
    `config.hyperparams`, `config.n_envs` and `config.normalize` override them.
    """
    entry = default_hyperparams(config.algo, config.env_id)
    n_envs = int(config.n_envs or entry.get("n_envs", 1))
    normalize = entry.get("normalize", False)
    normalize_kwargs = dict(normalize) if isinstance(normalize, dict) else {}
    if config.normalize is not None:
        normalize = config.normalize
    policy = entry.get("policy", "MlpPolicy")
    kwargs = {k: v for k, v in entry.items() if k not in ZOO_KEYS}
    kwargs.update(config.hyperparams)
    if not normalize:
        return kwargs, n_envs, None, policy
    normalize_kwargs.setdefault("gamma", float(kwargs.get("gamma", 0.99)))
    return kwargs, n_envs, normalize_kwargs, policy


def _sb3_kwargs(kwargs: dict[str, Any], action_dim: int) -> dict[str, Any]:
    """Turn rl-zoo3's noise keys into an SB3 action-noise object."""
    out = {k: v for k, v in kwargs.items() if k not in NOISE_KEYS}
    noise_type = kwargs.get("noise_type")
    if noise_type is not None:
        from stable_baselines3.common.noise import NormalActionNoise

        if noise_type != "normal":
            raise ValueError(f"--hyperparams noise_type must be 'normal', got {noise_type!r}")
        sigma = float(kwargs.get("noise_std", 0.1))
        out["action_noise"] = NormalActionNoise(np.zeros(action_dim), sigma * np.ones(action_dim))
    return out


def make_training_env(config: TrainConfig, n_envs: int):
    """The vectorized training env (Monitor-wrapped), seeded from config.seed by SB3."""
    if is_multiagent(config.env_id):
        from agent_envs.training.multiagent import make_shared_vec_env

        return make_shared_vec_env(config.env_kwargs, n_copies=n_envs)
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    import agent_envs  # noqa: F401
    from agent_envs.training.wrappers import HorizonAsTermination

    if config.vec_env == "native":
        from agent_envs.training.native_vec_env import NativeVecEnv

        try:
            venv = NativeVecEnv(n_envs, config.env_kwargs, horizon_as_termination=True)
        except TypeError as exc:  # unknown keyword: a user error, as in make_gym_env
            raise ValueError(f"--env-kwargs {config.env_kwargs}: {exc}") from None
        venv.seed(config.seed)  # as make_vec_env: env i resets with seed + i
        return venv
    return make_vec_env(
        config.env_id,
        n_envs=n_envs,
        seed=config.seed,
        env_kwargs=config.env_kwargs,
        vec_env_cls=SubprocVecEnv if config.vec_env == "subproc" else DummyVecEnv,
        wrapper_class=HorizonAsTermination,
    )


def live_policy(model: Any, agent_shape: tuple[int, int] | None = None) -> Any:
    """`model` as a PolicyPredictor on the raw Gymnasium env, following its live VecNormalize.

    `agent_shape` = (N, d) for a parameter-shared per-agent model (PettingZoo training), which
    then acts on the Gymnasium env through `agent_envs.training.evaluate.PerAgentPolicy`.
    """
    from agent_envs.training.evaluate import NormalizedObservationPolicy, PerAgentPolicy

    stats = model.get_vec_normalize_env()
    policy = model if stats is None else NormalizedObservationPolicy(model, stats)
    if agent_shape is not None:
        policy = PerAgentPolicy(policy, *agent_shape)
    return policy


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
    from agent_envs.training.callbacks import prune_replay_buffers

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


def _write_json(path: Path, data: Any) -> None:
    path.write_text(json.dumps(data, indent=2, default=str) + "\n")


def train(config: TrainConfig, callbacks: Sequence[Any] | None = None) -> Path:
    """Train one agent; return its run directory.

    With `config.resume` set to a run directory, the run continues from its last complete
    checkpoint: its config.json defines the run, except `timesteps`, `progress_bar`,
    `verbose`, `device` and `tensorboard`, which are taken from `config`.
    `callbacks` are extra SB3 callbacks appended to the run's own.
    """
    if config.resume:
        run_dir = Path(config.resume)
        saved_path = run_dir / "config.json"
        if not saved_path.exists():
            raise ValueError(f"--resume {run_dir}: no config.json there (not a run directory)")
        saved = TrainConfig.from_dict(json.loads(saved_path.read_text()))
        for name in RESUME_OVERRIDES:
            setattr(saved, name, getattr(config, name))
        saved.resume = str(run_dir)
        config = saved.validate()
    else:
        config.validate()
        run_dir = Path(config.out) / (config.run_name or default_run_name(config))
        if (run_dir / "config.json").exists():
            raise ValueError(
                f"run directory {run_dir} exists; pass --resume {run_dir} to continue it or "
                "choose another --run-name"
            )
    env_description(eval_env_id(config), config.env_kwargs)  # validate before creating files
    run_dir.mkdir(parents=True, exist_ok=True)
    with torch_threads(config.torch_threads):
        return _train_in(config, run_dir, list(callbacks or []))


@contextlib.contextmanager
def torch_threads(n: int):
    """Run with `n` torch intra-op threads (0: unchanged), restoring the previous number after.

    With torch's default (one thread per core), a 64x64 MLP forward pass on a busy 2-core
    machine measured 5.5 ms instead of 17 us with one thread: the threads spin-wait.
    """
    import torch

    previous = torch.get_num_threads()
    if n > 0:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def _train_in(config: TrainConfig, run_dir: Path, extra_callbacks: list[Any]) -> Path:
    from stable_baselines3.common.callbacks import CallbackList
    from stable_baselines3.common.vec_env import VecNormalize

    from agent_envs.baselines import ProportionalController, TurnpikeController, ZeroController
    from agent_envs.training.callbacks import (
        ReplayBufferPruningCheckpointCallback,
        SwarmEvalCallback,
        read_learning_curve,
    )

    algo_kwargs, n_envs, normalize_kwargs, policy_name = resolve_hyperparams(config)
    normalize = normalize_kwargs is not None
    off_policy = config.algo in OFF_POLICY
    eval_id = eval_env_id(config)
    description = env_description(eval_id, config.env_kwargs)  # also validates env_kwargs

    # Every run ends with a checkpoint of its final state (below), so the newest complete
    # checkpoint is where a resumed run continues, finished or interrupted.
    checkpoint = latest_checkpoint(run_dir, off_policy, normalize) if config.resume else None
    if checkpoint is not None and checkpoint[0] >= config.timesteps:
        print(
            f"{run_dir.name}: {checkpoint[0]} timesteps already done (>= --timesteps "
            f"{config.timesteps}); nothing to train"
        )
        return run_dir
    stored = {**config.to_dict(), "resume": None}
    _write_json(run_dir / "config.json", stored)
    _write_json(run_dir / "env.json", description)
    _write_json(
        run_dir / "hyperparams.json",
        {
            "algo": config.algo,
            "policy": policy_name,
            "n_envs": n_envs,
            "normalize": normalize_kwargs if normalize else False,
            **algo_kwargs,
        },
    )

    venv = make_training_env(config, n_envs)
    cls = algorithm_class(config.algo)
    tb_log = str(run_dir / "tb") if config.tensorboard else None
    if checkpoint is None:
        if normalize:
            venv = VecNormalize(venv, **normalize_kwargs)
        action_dim = int(np.prod(venv.action_space.shape))
        model = cls(
            policy_name,
            venv,
            seed=config.seed,
            device=config.device,
            verbose=config.verbose,
            tensorboard_log=tb_log,
            **_sb3_kwargs(algo_kwargs, action_dim),
        )
        done = 0
    else:
        steps, model_path = checkpoint
        if normalize:
            stats_path = checkpoint_file(run_dir, "vecnormalize", steps)
            venv = VecNormalize.load(str(stats_path), venv)
            venv.training = True
        model = cls.load(model_path, env=venv, device=config.device, tensorboard_log=tb_log)
        model.verbose = config.verbose
        if off_policy:
            model.load_replay_buffer(checkpoint_file(run_dir, "replay_buffer", steps))
        done = int(model.num_timesteps)
        # a fresh, reproducible seeding of the resumed part
        model.set_random_seed(config.seed + done)
        print(f"resuming {run_dir.name} from {model_path.name} ({done} timesteps done)")

    sb3_envs = venv.num_envs
    shape = (description["n_agents"], description["dim"]) if is_multiagent(config.env_id) else None

    def policy_factory(m: Any) -> Any:
        return live_policy(m, shape)

    callbacks: list[Any] = []
    if config.checkpoint_freq > 0:
        callbacks.append(
            ReplayBufferPruningCheckpointCallback(
                save_freq=max(config.checkpoint_freq // sb3_envs, 1),
                save_path=str(run_dir / "checkpoints"),
                name_prefix=CHECKPOINT_PREFIX,
                save_replay_buffer=off_policy,
                save_vecnormalize=normalize,
            )
        )
    eval_callback = None
    if config.eval_freq > 0:
        eval_vec = make_eval_vec_env(eval_id, config.env_kwargs, config.eval_episodes)
        reference_env = eval_vec.envs[0]
        references = {
            "turnpike": TurnpikeController(
                reference_env, beta=config.turnpike_beta, delta=config.turnpike_delta
            ),
            "proportional": ProportionalController(reference_env, beta=config.turnpike_beta),
            "zero": ZeroController(reference_env),
        }
        eval_callback = SwarmEvalCallback(
            eval_vec,
            policy_factory,
            references,
            eval_seed=config.eval_seed,
            eval_freq=max(config.eval_freq // sb3_envs, 1),
            run_dir=run_dir,
            history=read_learning_curve(run_dir / "learning_curve.csv", max(done, 0))
            if done
            else None,
            verbose=config.verbose,
        )
        callbacks.append(eval_callback)
    callbacks.extend(extra_callbacks)

    remaining = config.timesteps - done
    start = time.perf_counter()
    if remaining > 0:
        try:
            model.learn(
                total_timesteps=remaining,
                callback=CallbackList(callbacks),
                progress_bar=config.progress_bar,
                reset_num_timesteps=checkpoint is None,
                tb_log_name="run",
            )
        except KeyboardInterrupt:
            path = save_checkpoint(model, run_dir, off_policy)
            print(
                f"\ninterrupted at {model.num_timesteps} timesteps; checkpoint {path}\n"
                f"continue with: agent-envs train --resume {run_dir}",
                file=sys.stderr,
            )
            raise
    if eval_callback is not None and (
        not eval_callback.history or eval_callback.history[-1]["timesteps"] != model.num_timesteps
    ):
        eval_callback.evaluate_now()  # the final model is always on the learning curve
    wall = time.perf_counter() - start
    save_checkpoint(model, run_dir, off_policy)  # the final state is the newest checkpoint
    model.save(run_dir / FINAL_MODEL)
    stats = model.get_vec_normalize_env()
    if stats is not None:
        stats.save(str(run_dir / FINAL_VECNORMALIZE))
    summary_path = run_dir / "summary.json"
    previous = json.loads(summary_path.read_text()) if summary_path.exists() else {}
    summary = {
        "run_name": run_dir.name,
        "algo": config.algo,
        "env_id": config.env_id,
        "timesteps": int(model.num_timesteps),
        "swarm_steps": int(model.num_timesteps)
        // (description["n_agents"] if is_multiagent(config.env_id) else 1),
        "train_wall_time_s": round(float(previous.get("train_wall_time_s", 0.0)) + wall, 2),
        "last_eval": eval_callback.history[-1] if eval_callback and eval_callback.history else None,
    }
    _write_json(summary_path, summary)
    venv.close()
    return run_dir


# --------------------------------------------------------------------------------------- CLI


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """`agent-envs train` options: one per TrainConfig field."""
    parser.description = (
        "Train a Stable-Baselines3 agent on a swarm env. The validation cost is logged next to "
        "the turnpike controller's on the same seeds (learning_curve.csv, TensorBoard)."
    )
    add_dataclass_arguments(parser, TrainConfig, suppress_defaults=True)


def config_from_args(args: argparse.Namespace) -> TrainConfig:
    """The TrainConfig of the parsed options (with --resume: the run's config + overrides)."""
    names = {f.name for f in dataclasses.fields(TrainConfig)}
    given = {k: v for k, v in vars(args).items() if k in names}
    if given.get("resume"):
        run_dir = Path(given["resume"])
        saved_path = run_dir / "config.json"
        if not saved_path.exists():
            raise ValueError(f"--resume {run_dir}: no config.json there (not a run directory)")
        base = json.loads(saved_path.read_text())
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


def run(args: argparse.Namespace) -> int:
    try:
        config = config_from_args(args)
        run_dir = train(config)
    except ValueError as exc:
        print(f"agent-envs train: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    summary = json.loads((run_dir / "summary.json").read_text())
    print(f"run directory: {run_dir}")
    last = summary.get("last_eval")
    if last:
        print(
            f"validation cost {last['cost_mean']:.4g} ± {last['cost_ci95']:.2g} "
            f"(turnpike {last.get('turnpike_cost', float('nan')):.4g}) after "
            f"{summary['timesteps']} timesteps, {summary['train_wall_time_s']:.0f} s"
        )
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="agent-envs train")
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
