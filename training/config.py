"""What a training run is made of: the `TrainConfig` dataclass and the default hyperparameters
of every (algorithm, env id) pair, resolved into SB3 keyword arguments by `resolve_hyperparams`.

`TrainConfig` is the CLI (CleanRL style): one field is one option of `agent-envs train`, and the
`help` in the field's metadata is its `--help` text, so the two cannot drift apart.

The default hyperparameters live in one place, the rl-zoo3 YAML files shipped in
`training/hyperparams/{algo}.yml` (entries per env id), read as rl-zoo3 reads them: what
`agent-envs train` uses is what `python -m rl_zoo3.train --conf-file
training/hyperparams/ppo.yml` trains with. The measurements behind them (N = 10, m = 20;
docs/learners/sb3.md) are in the files' comments.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
import shlex
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from agent_envs.training.defaults import (
    ALGORITHMS,
    DEFAULT_BETA,
    DEFAULT_DELTA,
    DEFAULT_EVAL_SEED,
    GYM_ENV_ID,
    PETTINGZOO_ENV_ID,
    check_algo,
    check_env_id,
    is_multiagent,
    parse_env_kwargs,
    parse_json_object,
)
from agent_envs.training.sb3_arguments import NOISE_KEYS, check_hyperparams
from agent_envs.validation import MAX_SEED, check_int

#: Keys of a hyperparameter entry that are not keyword arguments of the SB3 algorithm
#: (rl-zoo3 reads them itself).
ZOO_KEYS = ("n_envs", "n_timesteps", "normalize", "policy", "env_kwargs", "env_wrapper")
#: `--vec-env` choices: SB3 VecEnvs of the training envs (native: NativeVecEnv, one batch).
VEC_ENV_CHOICES = ("native", "dummy", "subproc")
#: Largest --timesteps (and evaluation / checkpoint period) accepted.
MAX_TIMESTEPS = 10**12

#: The hyperparameter files shipped in ``training/hyperparams``: one per algorithm (the
#: training layer's own, rl-zoo3 format, entries per env id) and ``zoo_pendulum`` (rl-zoo3's
#: tuned Pendulum-v1 entries, used by the paper preset).
HYPERPARAMS_DIR = Path(__file__).parent / "hyperparams"


@functools.cache
def _read_yaml(path: Path) -> dict[str, Any]:
    import yaml  # the `train` extra

    with open(path) as handle:
        return yaml.safe_load(handle)


def read_hyperparams_file(name: str) -> dict[str, Any]:
    """A deep copy of the shipped YAML file ``training/hyperparams/{name}.yml``, read as
    rl-zoo3 reads it (`yaml.safe_load`; merge keys ``<<: *anchor`` resolved)."""
    path = HYPERPARAMS_DIR / f"{name}.yml"
    if not path.is_file():
        known = sorted(p.stem for p in HYPERPARAMS_DIR.glob("*.yml"))
        raise ValueError(f"no hyperparameter file {name!r}; shipped: {', '.join(known)}")
    return json.loads(json.dumps(_read_yaml(path)))


def hyperparams_file(algo: str) -> Path:
    """Path of the rl-zoo3 YAML file shipped for `algo` (for `rl_zoo3.train --conf-file`)."""
    return HYPERPARAMS_DIR / f"{check_algo(algo)}.yml"


def default_hyperparams(algo: str, env_id: str) -> dict[str, Any]:
    """The entry of `env_id` in the shipped ``hyperparams/{algo}.yml`` (a deep copy)."""
    entries = read_hyperparams_file(check_algo(algo))
    if env_id not in entries:
        raise ValueError(
            f"no default hyperparameters for --algo {algo} on --env-id {env_id}; "
            f"known env ids: {', '.join(entries)}"
        )
    return entries[env_id]


def option_field(default: Any, help: str, **kwargs: Any) -> Any:
    """A dataclass field with a scalar default and its --help text."""
    return field(default=default, metadata={"help": help, **kwargs})


def json_field(help: str) -> Any:
    """A dataclass field holding a JSON object (default {}), with its --help text; the CLI
    takes it as one JSON string."""
    return field(default_factory=dict, metadata={"help": help})


def command_line(prog: str, config: Any) -> str:
    """The `agent-envs PROG` command line of an options dataclass: non-default options only
    (`preset` always), ``--no-x`` for a false flag, dicts as quoted JSON, a tuple or list as
    its items."""
    parts = ["agent-envs", prog]
    default = type(config)()
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if value == getattr(default, f.name) and f.name != "preset":
            continue
        flag = "--" + f.name.replace("_", "-")
        if isinstance(value, bool):
            parts.append(flag if value else "--no-" + f.name.replace("_", "-"))
        elif isinstance(value, dict):
            parts += [flag, shlex.quote(json.dumps(value))]
        elif isinstance(value, (tuple, list)):
            parts += [flag, *(shlex.quote(str(v)) for v in value)]
        else:
            parts += [flag, shlex.quote(str(value))]
    return " ".join(parts)


@dataclass
class TrainConfig:
    """One training run. Every field is an `agent-envs train` option (`--field-name`)."""

    algo: str = option_field(
        "ppo",
        "Stable-Baselines3 algorithm, or apg (a feedback law trained by backpropagation "
        "through the core's integrator, agent_envs.training.learners.apg: its settings go in "
        "--hyperparams, e.g. '{\"iterations\": 300}'; --timesteps, --n-envs and the other "
        "SB3 options do not apply)",
        choices=(*ALGORITHMS, "apg"),
    )
    env_id: str = option_field(
        GYM_ENV_ID,
        f"environment: the Gymnasium id {GYM_ENV_ID!r} (one controller for the swarm) or "
        f"{PETTINGZOO_ENV_ID!r} (PettingZoo, one agent per swarm member, parameter-shared "
        "policy trained through SuperSuit)",
    )
    env_kwargs: dict = json_field(
        'env keyword arguments as a JSON object, e.g. \'{"n_agents": 10, '
        '"n_steps": 20, "integrator": "em"}\' (default: the paper\'s stiff setting)'
    )
    timesteps: int = option_field(
        100_000,
        "total SB3 timesteps (for the PettingZoo env one timestep is one agent-step, so a swarm "
        "step counts N times)",
    )
    seed: int = option_field(0, "seed of the algorithm, the networks and the training envs' resets")
    out: str = option_field("runs", "directory under which the run directory is created")
    run_name: str | None = option_field(
        None, "name of the run directory (default {env}__{algo}__{seed}__{unix time})"
    )
    n_envs: int | None = option_field(
        None,
        "parallel training envs (default: the hyperparameter file's n_envs; for the PettingZoo "
        "env, copies of the swarm)",
    )
    hyperparams: dict = json_field(
        "JSON object overriding SB3 keyword arguments of the algorithm, e.g. "
        '\'{"learning_rate": 0.001, "policy_kwargs": {"net_arch": [32, 32]}}\''
    )
    normalize: bool | None = option_field(
        None,
        "VecNormalize observations and rewards (statistics saved with every checkpoint and "
        "frozen at evaluation); default: the hyperparameter file's choice",
    )
    eval_freq: int = option_field(
        10_000, "evaluate every this many timesteps on the validation seeds (0: never)"
    )
    eval_episodes: int = option_field(5, "validation episodes per evaluation (seeds eval_seed + i)")
    eval_seed: int = option_field(
        DEFAULT_EVAL_SEED,
        "first validation seed; the turnpike, proportional and zero controllers are logged on "
        "the same seeds",
    )
    checkpoint_freq: int = option_field(
        20_000, "save model + VecNormalize stats (+ replay buffer) every this many timesteps"
    )
    turnpike_beta: float = option_field(
        DEFAULT_BETA, "beta of the turnpike (and proportional) reference controllers"
    )
    turnpike_delta: float = option_field(
        DEFAULT_DELTA, "delta of the turnpike reference controller"
    )
    vec_env: str = option_field(
        "native",
        "vectorization of the training envs: native (all envs stepped as one batch, "
        "agent_envs.training.learners.native_vec_env; the Gymnasium env only, the PettingZoo env "
        "ignores it), dummy (one env after the other, in process) or subproc",
        choices=VEC_ENV_CHOICES,
    )
    device: str = option_field("cpu", "torch device")
    torch_threads: int = option_field(
        1,
        "torch intra-op threads during training (1 is by far the fastest for these small "
        "networks on CPU; 0 keeps torch's default)",
    )
    env_threads: int = option_field(
        1,
        "threads of the training envs' compiled passes (numba; --vec-env native: over its "
        "batch; the Gymnasium env only; the same results on any number)",
    )
    progress_bar: bool = option_field(True, "show a progress bar (tqdm + rich)")
    tensorboard: bool = option_field(True, "write TensorBoard logs into the run directory (tb/)")
    verbose: int = option_field(0, "SB3 verbosity (0, 1, 2)")
    resume: str | None = option_field(
        None,
        "resume the run in this directory from its newest checkpoint whose files match the run's "
        "manifest.json (damaged newer ones are skipped, with a message; its config.json is used; "
        "--timesteps may raise the total)",
    )

    def __post_init__(self) -> None:
        self.env_kwargs = parse_env_kwargs(self.env_kwargs)
        self.hyperparams = parse_json_object(self.hyperparams, "--hyperparams")

    def validate(self) -> TrainConfig:
        """Check every option; raise ValueError/TypeError naming the option. Returns self.

        Imports torch and SB3 (for --device and --hyperparams); creates nothing.
        """
        self.algo = check_algo(self.algo)
        check_env_id(self.env_id)
        if self.env_id not in (GYM_ENV_ID, PETTINGZOO_ENV_ID):
            raise ValueError(
                f"--env-id {self.env_id!r} is not a swarm env; agent-envs train trains on "
                f"{GYM_ENV_ID!r} (one controller) or {PETTINGZOO_ENV_ID!r} (one agent per member)"
            )
        check_int("--timesteps", self.timesteps, 1, MAX_TIMESTEPS)
        check_int("--eval-freq", self.eval_freq, 0, MAX_TIMESTEPS)
        check_int("--checkpoint-freq", self.checkpoint_freq, 0, MAX_TIMESTEPS)
        check_int("--seed", self.seed, 0, MAX_SEED)
        check_int("--eval-seed", self.eval_seed, 0, MAX_SEED)
        check_int("--verbose", self.verbose, 0, 2)
        check_int("--torch-threads", self.torch_threads, 0, 1024)
        check_int("--env-threads", self.env_threads, 1, 1024)
        if self.env_threads > 1:
            from agent_envs.native import check_compiled_threads

            if is_multiagent(self.env_id):
                raise ValueError("--env-threads > 1 needs the Gymnasium env (--env-id)")
            check_compiled_threads(self.env_threads, "--env-threads")
        check_int("--eval-episodes", self.eval_episodes, 1, 10_000)
        if self.n_envs is not None:
            check_int("--n-envs", self.n_envs, 1, 1024)
        if self.vec_env not in VEC_ENV_CHOICES:
            raise ValueError(f"--vec-env must be one of {VEC_ENV_CHOICES}, got {self.vec_env!r}")
        for name in ("turnpike_beta", "turnpike_delta"):
            value = getattr(self, name)
            if not (
                isinstance(value, (int, float))
                and not isinstance(value, bool)
                and math.isfinite(value)
                and value > 0
            ):
                raise ValueError(f"--{name.replace('_', '-')} must be a number > 0, got {value!r}")
        if self.run_name is not None:
            check_run_name(self.run_name)
        check_device(self.device)
        unknown = set(self.hyperparams) & set(ZOO_KEYS)
        if unknown:
            raise ValueError(
                f"--hyperparams takes SB3 keyword arguments only; {sorted(unknown)} are set by "
                "--n-envs, --timesteps, --normalize and --env-kwargs"
            )
        kwargs, n_envs, _, policy = resolve_hyperparams(self)
        check_hyperparams(self.algo, self.hyperparams, policy)
        if self.algo in ("ppo", "a2c") and int(kwargs.get("n_steps", 2)) * n_envs < 2:
            raise ValueError(
                "--hyperparams n_steps times the number of envs must be > 1 (SB3's rollout "
                f"needs two samples), got n_steps={kwargs.get('n_steps')} with {n_envs} env(s)"
            )
        return self

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrainConfig:
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(data) - names
        if unknown:
            raise ValueError(f"unknown TrainConfig fields {sorted(unknown)}")
        return cls(**data)


def check_run_name(name: str) -> str:
    """A run name is one folder name: no path separator, not empty, not '.' or '..'."""
    if (
        not isinstance(name, str)
        or name in ("", ".", "..")
        or "/" in name
        or os.sep in name
        or (os.altsep is not None and os.altsep in name)
    ):
        raise ValueError(
            f"--run-name must be one folder name (no '/', not '.' or '..'), got {name!r}"
        )
    return name


def check_device(device: str) -> str:
    """`device` if torch can use it here: auto, cpu, or an available cuda[:i] / mps device."""
    import torch

    if device == "auto":
        return device
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError, ValueError):
        raise ValueError(
            f"--device must be a torch device: auto, cpu, cuda, cuda:INDEX or mps; got {device!r}"
        ) from None
    if dev.type == "cpu":
        return device
    if dev.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if count == 0:
            raise ValueError(f"--device {device}: no CUDA device is available (use cpu)")
        if dev.index is not None and dev.index >= count:
            raise ValueError(f"--device {device}: only {count} CUDA device(s) (0..{count - 1})")
        return device
    if dev.type == "mps":
        if not torch.backends.mps.is_available():
            raise ValueError(f"--device {device}: MPS is not available here (use cpu)")
        return device
    raise ValueError(f"--device {device!r}: Stable-Baselines3 runs on auto, cpu, cuda or mps")


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


def sb3_kwargs(kwargs: dict[str, Any], action_dim: int) -> dict[str, Any]:
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
