"""What an `apg` run is: `APGConfig`, its options on the command line, its run folder's name.

`APGConfig` holds every setting of one run of the analytic-policy-gradient learner
(`agent_envs.training.learners.apg.train_apg`): the env's kwargs, the trainer's seed, the Adam
steps and rates with their cosine decay to `final_learning_rate_fraction`, the episodes and
Brownian paths per step, the law's shape (`apg_policy.LawSpec`), the validation seeds and the
checkpoint and evaluation periods; every field is checked in `__post_init__` and an error names
it. `from_train_options` maps `agent-envs train --algo apg` options (and ``--hyperparams``, a JSON
object of APGConfig fields) to (config, run folder, resume); `default_run_dir` names a new run
folder as the SB3 runs are named.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from agent_envs.envs.episode_config import EpisodeConfig
from agent_envs.training.defaults import (
    DEFAULT_EVAL_SEED,
    GYM_ENV_ID,
    parse_env_kwargs,
    parse_json_object,
)
from agent_envs.training.learners.apg_policy import LawSpec
from agent_envs.validation import check_int, check_seed

#: the reference controllers logged next to the law on the validation seeds
DEFAULT_REFERENCES = ("proportional", "turnpike")


def _real(name: str, value: Any, low: float, high: float, *, low_open: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a real number, got {value!r}")
    value = float(value)
    bad_low = value <= low if low_open else value < low
    if not math.isfinite(value) or bad_low or value > high:
        bracket = "(" if low_open else "["
        raise ValueError(f"{name} must be in {bracket}{low:g}, {high:g}], got {value}")
    return value


@dataclass(frozen=True)
class APGConfig:
    """One `apg` training run (every field checked in `__post_init__`, errors name it).

    Attributes:
        env_kwargs: the env's kwargs (those of `agent_envs/Swarm-v0`, e.g. the sweep's paper
            preset); the law is trained for this env.
        seed: int >= 0, seeds the trainer's generator (starts and Brownian paths).
        iterations: 1 <= Adam steps <= 1e6 (default 300).
        episodes_per_iteration: 1..1024 fresh episodes averaged per step (default 1).
        train_paths: Brownian paths of a training episode, 1..1e6; None = the env's n_paths.
            The law sees path means, so fewer paths than the env's change its input only by
            noise of order sigma sqrt(t / K); at N = 100 a cost + gradient takes 0.2 s of CPU
            with 4 paths, 0.85 s with 20 (docs/learners/apg.md).
        learning_rate: Adam's rate in (0, 10] for the gains (default 0.2).
        mlp_learning_rate: the rate of the shared MLP's weights in (0, 10] (default 0.2).
        final_learning_rate_fraction: cosine decay to this fraction of the rates, [0, 1].
        max_grad_norm: clip the gradient's global norm to this, (0, 1e6] (default 1).
        hidden: width of the shared MLP, 0..1024 (0: the linear law alone; default 16).
        n_knots: gain knots, 1..1e5; None = the env's m (one gain per step).
        initial_gain: the proportional law's beta the gains start from, [0, 1e6] (default 12).
        eval_freq: validate every this many iterations, 1..1e6 (default 25).
        n_eval_episodes: validation episodes (env seeds eval_seed..), 1..1000 (default 4).
        eval_seed: the first validation seed (default 1000, the training layer's).
        checkpoint_freq: save a resumable checkpoint every this many iterations (default 50).
        references: controllers (baseline names) run once on the validation seeds and logged
            as ``{name}_cost`` next to the law's cost.
        phi_method: phi strategy of the differentiated steps (None: the solver's choice).
        threads: torch intra-op threads while training, 1..256 (default 1).
        progress: show a tqdm progress bar.
    """

    env_kwargs: dict[str, Any] = field(default_factory=dict)
    seed: int = 0
    iterations: int = 300
    episodes_per_iteration: int = 1
    train_paths: int | None = 4
    learning_rate: float = 0.2
    mlp_learning_rate: float = 0.2
    final_learning_rate_fraction: float = 0.02
    max_grad_norm: float = 1.0
    hidden: int = 16
    n_knots: int | None = None
    initial_gain: float = 12.0
    eval_freq: int = 25
    n_eval_episodes: int = 4
    eval_seed: int = DEFAULT_EVAL_SEED
    checkpoint_freq: int = 50
    references: tuple[str, ...] = DEFAULT_REFERENCES
    phi_method: str | None = None
    threads: int = 1
    progress: bool = True

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        if not isinstance(self.env_kwargs, dict):
            raise TypeError(f"env_kwargs must be a dict, got {type(self.env_kwargs).__name__}")
        self.episode_config()  # the env kwargs, checked by the env's own validation
        set_(self, "seed", check_seed(self.seed))
        set_(self, "iterations", check_int("iterations", self.iterations, 1, 1_000_000))
        set_(
            self,
            "episodes_per_iteration",
            check_int("episodes_per_iteration", self.episodes_per_iteration, 1, 1024),
        )
        if self.train_paths is not None:
            set_(self, "train_paths", check_int("train_paths", self.train_paths, 1, 1_000_000))
        set_(
            self, "learning_rate", _real("learning_rate", self.learning_rate, 0, 10, low_open=True)
        )
        set_(
            self,
            "mlp_learning_rate",
            _real("mlp_learning_rate", self.mlp_learning_rate, 0, 10, low_open=True),
        )
        set_(
            self,
            "final_learning_rate_fraction",
            _real("final_learning_rate_fraction", self.final_learning_rate_fraction, 0, 1),
        )
        set_(
            self, "max_grad_norm", _real("max_grad_norm", self.max_grad_norm, 0, 1e6, low_open=True)
        )
        set_(self, "hidden", check_int("hidden", self.hidden, 0, 1024))
        if self.n_knots is not None:
            set_(self, "n_knots", check_int("n_knots", self.n_knots, 1, 100_000))
        set_(self, "initial_gain", _real("initial_gain", self.initial_gain, 0, 1e6))
        set_(self, "eval_freq", check_int("eval_freq", self.eval_freq, 1, 1_000_000))
        set_(self, "n_eval_episodes", check_int("n_eval_episodes", self.n_eval_episodes, 1, 1000))
        set_(self, "eval_seed", check_seed(self.eval_seed))
        set_(self, "checkpoint_freq", check_int("checkpoint_freq", self.checkpoint_freq, 1, 10**6))
        refs = (self.references,) if isinstance(self.references, str) else self.references
        from agent_envs.baselines import BASELINES

        refs = tuple(refs)
        for name in refs:
            if name not in BASELINES or name in ("optimal", "mpc"):
                allowed = sorted(set(BASELINES) - {"optimal", "mpc"})
                raise ValueError(f"references: unknown controller {name!r}; choose from {allowed}")
        set_(self, "references", refs)
        set_(self, "threads", check_int("threads", self.threads, 1, 256))
        set_(self, "progress", bool(self.progress))

    def episode_config(self) -> EpisodeConfig:
        """The env's validated kwargs (errors name the kwarg, as `gym.make` would)."""
        kwargs = {k: v for k, v in self.env_kwargs.items() if k != "render_mode"}
        return EpisodeConfig.from_kwargs("env_kwargs", **kwargs)

    def law_spec(self) -> LawSpec:
        config = self.episode_config()
        return LawSpec(
            dim=config.params.dim,
            n_knots=self.n_knots or config.n_steps,
            hidden=self.hidden,
            max_control=config.max_control,
            initial_gain=self.initial_gain,
        )

    def to_dict(self) -> dict[str, Any]:
        data = dataclasses.asdict(self)
        data["references"] = list(self.references)
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> APGConfig:
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise ValueError(f"unknown APGConfig field(s) {unknown}")
        data = dict(data)
        if "references" in data:
            data["references"] = tuple(data["references"])
        return cls(**data)


#: `agent-envs train` options that mean the same for `--algo apg`, and the APGConfig field each
#: sets; APG's own settings (iterations, learning rates, hidden, ...) go in --hyperparams.
TRAIN_OPTIONS = {
    "env_kwargs": "env_kwargs",
    "seed": "seed",
    "eval_episodes": "n_eval_episodes",
    "eval_seed": "eval_seed",
    "progress_bar": "progress",
    "torch_threads": "threads",
}
#: `agent-envs train` options about where the run lives (not APGConfig fields)
RUN_OPTIONS = ("algo", "out", "run_name", "resume")


def from_train_options(options: dict[str, Any]) -> tuple[APGConfig, Path, bool]:
    """(config, run folder, resume) of `agent-envs train --algo apg` from the options given.

    `options` holds only the options the user gave (field name -> value, `TrainConfig`'s
    names). ``--hyperparams`` holds APGConfig fields (e.g. ``{"iterations": 300, "hidden":
    16}``); an SB3-only option (``--timesteps``, ``--n-envs``, ...) is a ValueError naming it.
    ``--resume RUN`` continues that run with its own config.json.
    """
    given = dict(options)
    unknown = sorted(set(given) - set(TRAIN_OPTIONS) - set(RUN_OPTIONS) - {"hyperparams"})
    if unknown:
        flags = ", ".join("--" + n.replace("_", "-") for n in unknown)
        verb = "does" if len(unknown) == 1 else "do"
        raise ValueError(
            f"{flags} {verb} not apply to --algo apg; its own settings go in --hyperparams "
            f"(APGConfig fields: {', '.join(f.name for f in dataclasses.fields(APGConfig))})"
        )
    hyper = parse_json_object(given.get("hyperparams"), "--hyperparams")
    if "env_kwargs" in given:
        given["env_kwargs"] = parse_env_kwargs(given["env_kwargs"])
    values = {TRAIN_OPTIONS[k]: v for k, v in given.items() if k in TRAIN_OPTIONS}
    if given.get("resume"):
        # the run's own config.json; what may change on a resume (iterations, eval_freq, ...)
        # is checked by train_apg, which names any other difference
        run_dir = Path(given["resume"])
        if not (run_dir / "config.json").is_file():
            raise ValueError(f"--resume {run_dir}: not an apg run folder (no config.json)")
        saved = json.loads((run_dir / "config.json").read_text())
        return APGConfig.from_dict({**saved, **values, **hyper}), run_dir, True
    fields = {f.name for f in dataclasses.fields(APGConfig)}
    wrong = sorted(set(hyper) - fields)
    if wrong:
        raise ValueError(
            f"--hyperparams: {wrong} are not APGConfig fields; choose from {sorted(fields)}"
        )
    config = APGConfig(**{**values, **hyper})
    out = given.get("out", "runs")
    run_dir = (
        Path(out) / given["run_name"] if given.get("run_name") else default_run_dir(out, config)
    )
    return config, run_dir, False


def default_run_dir(out: str | os.PathLike, config: APGConfig) -> Path:
    """``{out}/{env id, '/' -> '_'}__apg__{seed}__{unix time}`` (the SB3 runs' naming)."""
    name = f"{GYM_ENV_ID.replace('/', '_')}__apg__{config.seed}__{int(time.time())}"
    return Path(out) / name


__all__ = [
    "DEFAULT_REFERENCES",
    "RUN_OPTIONS",
    "TRAIN_OPTIONS",
    "APGConfig",
    "default_run_dir",
    "from_train_options",
]
