"""The experiment builder: a preset and the command line's changes -> the runs of an experiment.

In the spirit of rl-zoo3's `ExperimentManager`, one place turns a `presets.Preset` and an
`ExperimentOptions` into the list of `Trial`s that `agent-envs compare` runs in process (one
training seed, one setting) and `agent-envs sweep` runs on Ray Tune (the whole grid):

- a *learner trial* per (setting, learner, training seed): one `train.train` run (its usual
  run folder under ``OUT/runs``), then an evaluation of its best model on the held-out test
  seeds; its `TrainConfig` comes from `learner_config` (one formula for the validation and
  checkpoint periods);
- a *reference trial* per reference controller and distinct evaluation env (the controllers do
  not train, so the training seed does not apply; settings that evaluate on the same env share
  them).

How a trial's learner is trained (a finished run of the same configuration reused, an
interrupted one resumed) is `learner_runs.train_from_dict`, the one way both commands train.
Building the trials imports
neither Ray nor torch, so the grid is testable on its own.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from agent_envs.training.commands.interface_references import (
    INTERFACE_REFERENCES,
    interface_reference,
)
from agent_envs.training.commands.presets import EnvSetting, Learner, Preset
from agent_envs.training.config import (
    VEC_ENV_CHOICES,
    TrainConfig,
    json_field,
    option_field,
)
from agent_envs.training.defaults import DEFAULT_TEST_SEED, is_multiagent, parse_env_kwargs
from agent_envs.validation import MAX_SEED, check_int

LEARNER = "learner"
REFERENCE = "reference"
#: the learner trained by analytic policy gradients (`agent_envs.training.learners.apg`); every
#: other learner's algo is a Stable-Baselines3 one
APG = "apg"
#: keys of an apg trial's training dict that are not `APGConfig` fields
APG_RUN_KEYS = ("algo", "env_id", "out", "run_name")
#: a trial's log file (in its run folder, or its reference folder)
TRIAL_LOG = "sweep_trial.log"
#: a learner trial's held-out evaluation, in its run folder
TEST_EVALUATION = "test_evaluation"
#: Largest --timesteps-scale (the paper preset's budgets times this stay far below 10**12).
MAX_TIMESTEPS_SCALE = 1000.0
#: Most held-out test episodes per policy.
MAX_TEST_EPISODES = 100_000


@dataclass(frozen=True)
class Trial:
    """One run of an experiment: train + evaluate one learner, or evaluate one reference.

    `train` is the `TrainConfig` of a learner trial as a dict (None for a reference);
    `eval_env_kwargs` are the full env kwargs of the held-out evaluation; `test_seeds` its
    reset seeds. `settings` lists the env settings whose report uses this trial (a reference
    trial serves every setting evaluated on the same env). `policy_kwargs` are the keyword
    arguments a reference controller is built with (empty: its defaults).
    """

    trial_id: str
    kind: str
    setting: str
    policy: str
    seed: int | None
    eval_env_kwargs: dict[str, Any]
    test_seeds: tuple[int, ...]
    settings: tuple[str, ...] = ()
    train: dict[str, Any] | None = None
    policy_kwargs: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def reference_spec(self) -> Any:
        """The policy spec `evaluate_policies` takes for this reference trial: its registered
        name, or a factory building it with `policy_kwargs` (`make_baseline(name, env, **kw)`);
        a reference acting through another interface (`interface_references`) is a factory
        ``env -> InterfacePolicy``.
        """
        if self.policy in INTERFACE_REFERENCES:
            return functools.partial(interface_reference, self.policy, **self.policy_kwargs)
        if not self.policy_kwargs:
            return self.policy
        from agent_envs.baselines import make_baseline

        return functools.partial(make_baseline, self.policy, **self.policy_kwargs)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Trial:
        values = dict(data)
        values["test_seeds"] = tuple(int(s) for s in values["test_seeds"])
        values["settings"] = tuple(values.get("settings", ()))
        values["policy_kwargs"] = dict(values.get("policy_kwargs") or {})
        return cls(**values)


@dataclass(frozen=True)
class ExperimentOptions:
    """The command line's changes to a preset (None / 1.0: the preset's own).

    `seeds`, `learners`, `settings` select part of the grid; `timesteps_scale` multiplies every
    budget; `env_kwargs` change the env of every setting; `references` replace the preset's;
    `run_names` names learner runs ``{setting}__{learner}__{seed}`` (a sweep, which finds them
    again by name) or, when False, ``{env}__{algo}__{seed}__{unix time}`` (compare, which finds a
    finished run by its configuration); the rest goes into every `TrainConfig`.
    """

    seeds: tuple[int, ...] | None = None
    learners: tuple[str, ...] | None = None
    settings: tuple[str, ...] | None = None
    timesteps_scale: float = 1.0
    test_episodes: int | None = None
    vec_env: str | None = None
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    references: tuple[str, ...] | None = None
    run_names: bool = True
    progress_bar: bool = False
    verbose: int = 0
    torch_threads: int = 1

    def check(self, preset: Preset) -> None:
        """ValueError / TypeError naming the option for anything `preset` cannot run."""
        scale = self.timesteps_scale
        if not (
            isinstance(scale, (int, float))
            and not isinstance(scale, bool)
            and math.isfinite(scale)
            and 0 < scale <= MAX_TIMESTEPS_SCALE
        ):
            raise ValueError(
                f"--timesteps-scale must be a number in (0, {MAX_TIMESTEPS_SCALE}], got {scale!r}"
            )
        if self.test_episodes is not None:
            check_int("--test-episodes", self.test_episodes, 2, MAX_TEST_EPISODES)
        seeds = self.training_seeds(preset)
        for seed in seeds:
            check_int("--seeds", seed, 0, MAX_SEED)
        if len(set(seeds)) != len(seeds):
            raise ValueError(f"--seeds lists a seed twice: {self.seeds!r}")
        vec_env = self.vec_env or preset.vec_env
        if vec_env not in VEC_ENV_CHOICES:
            raise ValueError(
                f"--vec-env must be one of {', '.join(VEC_ENV_CHOICES)}, got {vec_env!r}"
            )
        select([lr.name for lr in preset.learners], self.learners, "--learners")
        select([s.name for s in preset.settings], self.settings, "--settings")

    def training_seeds(self, preset: Preset) -> tuple[int, ...]:
        seeds = tuple(self.seeds) if self.seeds is not None else preset.seeds
        if not seeds:
            raise ValueError("--seeds: no seed given")
        return seeds

    def test_seeds(self, preset: Preset) -> tuple[int, ...]:
        """The held-out test seeds 10000, 10001, ... (`defaults.DEFAULT_TEST_SEED`)."""
        n_test = self.test_episodes or preset.test_episodes
        return tuple(range(DEFAULT_TEST_SEED, DEFAULT_TEST_SEED + n_test))


def split_names(text: str | None) -> tuple[str, ...] | None:
    """``a, b,c`` -> ("a", "b", "c"); None stays None (the preset's own)."""
    if text is None:
        return None
    return tuple(s.strip() for s in str(text).split(",") if s.strip())


@dataclass
class ExperimentArguments:
    """The options every experiment command takes (`compare`, `sweep`, `tune`): its changes to
    the preset's env and budgets. Each command's config adds its own fields; the CLI makes one
    option of every field (`--field-name`, the metadata's help as its --help)."""

    env_kwargs: dict = json_field(
        "JSON object of env kwargs overriding the preset's (every setting's), for "
        'training and evaluation, e.g. \'{"integrator": "em"}\''
    )
    timesteps_scale: float = option_field(
        1.0, "multiply every learner's training timesteps (e.g. 0.1 for a smoke run)"
    )
    vec_env: str | None = option_field(
        None,
        "vectorization of the single-controller learners' training envs (native, dummy, "
        "subproc; default: the preset's; see agent-envs train --help)",
    )

    def __post_init__(self) -> None:
        self.env_kwargs = parse_env_kwargs(self.env_kwargs)

    def experiment_options(self, **changes: Any) -> ExperimentOptions:
        """These options for the experiment builder, with the command's own `changes`."""
        return ExperimentOptions(
            env_kwargs=self.env_kwargs,
            timesteps_scale=self.timesteps_scale,
            vec_env=self.vec_env,
            **changes,
        )


@dataclass
class GridArguments(ExperimentArguments):
    """The options of the commands that train and evaluate several learners (`compare`,
    `sweep`): which learners, and how many held-out test episodes."""

    learners: str | None = option_field(
        None, "comma-separated learners of the preset to run (default: all of each setting's)"
    )
    test_episodes: int | None = option_field(
        None, "held-out test episodes per policy (seeds 10000 + i; default: the preset's)"
    )

    def experiment_options(self, **changes: Any) -> ExperimentOptions:
        return super().experiment_options(
            learners=split_names(self.learners), test_episodes=self.test_episodes, **changes
        )


# ---------------------------------------------------------------------------------- building


def select(names: Sequence[str], wanted: Sequence[str] | None, option: str) -> list[str]:
    """`names` in order, restricted to `wanted` (None: all); ValueError naming `option` for an
    unknown or repeated name."""
    if wanted is None:
        return list(names)
    unknown = [w for w in wanted if w not in names]
    if unknown or not wanted or len(set(wanted)) != len(wanted):
        raise ValueError(
            f"{option} must list distinct names of this preset ({', '.join(names)}), "
            f"comma-separated; got {', '.join(wanted) or 'none'}"
            + (f" (unknown: {', '.join(unknown)})" if unknown else "")
        )
    return [n for n in names if n in wanted]


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text)


def run_name(setting: str, learner: str, seed: int) -> str:
    """The run folder of a learner trial in a sweep: ``{setting}__{learner}__{seed}`` (no time
    stamp, so an interrupted sweep finds its runs again)."""
    return f"{_safe(setting)}__{_safe(learner)}__{seed}"


def setting_env_kwargs(
    preset: Preset, setting: EnvSetting, options: ExperimentOptions
) -> tuple[dict[str, Any], dict[str, Any]]:
    """(training env kwargs, held-out evaluation env kwargs) of one setting."""
    train_kwargs = {**preset.env_kwargs, **setting.env_kwargs, **options.env_kwargs}
    return train_kwargs, {**train_kwargs, **setting.eval_env_kwargs}


def learner_config(
    preset: Preset,
    setting: EnvSetting,
    learner: Learner,
    seed: int,
    options: ExperimentOptions,
    runs_dir: str | Path,
) -> TrainConfig | dict[str, Any]:
    """The validated training config of one learner trial: for an SB3 learner its `TrainConfig`
    (the learner's budget times the scale, `preset.evaluations` validations of
    `preset.validation_episodes` episodes, a checkpoint every quarter of the budget); for `apg`
    the dict of `apg_trial` (its budget is iterations)."""
    timesteps = max(round(learner.timesteps * options.timesteps_scale), 1)
    train_kwargs, _ = setting_env_kwargs(preset, setting, options)
    name = run_name(setting.name, learner.name, seed) if options.run_names else None
    if learner.algo == APG:
        return apg_trial(learner, train_kwargs, seed, timesteps, options, runs_dir, name)
    return TrainConfig(
        algo=learner.algo,
        env_id=learner.env_id,
        env_kwargs={**train_kwargs, **learner.env_kwargs},
        timesteps=timesteps,
        seed=seed,
        out=str(runs_dir),
        run_name=name,
        n_envs=learner.n_envs,
        normalize=learner.normalize,
        hyperparams=dict(learner.hyperparams),
        eval_freq=max(timesteps // preset.evaluations, 1),
        eval_episodes=preset.validation_episodes,
        checkpoint_freq=max(timesteps // 4, 1),
        # the PettingZoo learner trains on SuperSuit's vector env
        vec_env="dummy" if is_multiagent(learner.env_id) else options.vec_env or preset.vec_env,
        progress_bar=options.progress_bar,
        verbose=options.verbose,
        torch_threads=options.torch_threads,
    ).validate()


def apg_trial(
    learner: Learner,
    env_kwargs: dict[str, Any],
    seed: int,
    iterations: int,
    options: ExperimentOptions,
    runs_dir: str | Path,
    name: str | None,
) -> dict[str, Any]:
    """The training dict of an `apg` learner trial: ``algo``, ``env_id``, ``out``, ``run_name``
    and the fields of its validated `apg_config.APGConfig` (the learner's `hyperparams` over the
    defaults, `iterations` = its budget times the scale; validation every 25 iterations and a
    checkpoint every 50, or at the end of a shorter run)."""
    from agent_envs.training.defaults import GYM_ENV_ID
    from agent_envs.training.learners.apg_config import APGConfig

    values = {
        "eval_freq": min(25, iterations),
        "checkpoint_freq": min(50, iterations),
        **learner.hyperparams,
        "env_kwargs": env_kwargs,
        "seed": seed,
        "iterations": iterations,
        "progress": options.progress_bar,
        "threads": max(options.torch_threads, 1),
    }
    config = APGConfig(**values)
    where = {"algo": APG, "env_id": GYM_ENV_ID, "out": str(runs_dir), "run_name": name}
    return {**where, **config.to_dict()}


def available_references(
    preset: Preset, wanted: Sequence[str] | None = None
) -> tuple[list[str], list[str]]:
    """(references of `preset` (or `wanted`) this install has, those it lacks) per
    `agent_envs.baselines.BASELINES` and the interface references (`INTERFACE_REFERENCES`)."""
    from agent_envs.baselines import BASELINES

    names = preset.references if wanted is None else tuple(wanted)
    known = set(BASELINES) | set(INTERFACE_REFERENCES)
    return [r for r in names if r in known], [r for r in names if r not in known]


def _learner_trials(
    preset: Preset, setting: EnvSetting, options: ExperimentOptions, runs_dir: str | Path
) -> list[Trial]:
    names = select([lr.name for lr in preset.learners], options.learners, "--learners")
    _, eval_kwargs = setting_env_kwargs(preset, setting, options)
    trials = []
    for learner in preset.learners:
        if learner.name not in names:
            continue
        if setting.learners is not None and learner.name not in setting.learners:
            continue
        for seed in options.training_seeds(preset):
            config = learner_config(preset, setting, learner, seed, options, runs_dir)
            if isinstance(config, TrainConfig):
                config = config.to_dict()
            trials.append(
                Trial(
                    trial_id=run_name(setting.name, learner.name, seed),
                    kind=LEARNER,
                    setting=setting.name,
                    policy=learner.name,
                    seed=seed,
                    eval_env_kwargs=eval_kwargs,
                    test_seeds=options.test_seeds(preset),
                    settings=(setting.name,),
                    train=config,
                )
            )
    return trials


def _add_reference_trials(
    preset: Preset,
    setting: EnvSetting,
    options: ExperimentOptions,
    by_env: dict[str, Trial],
) -> None:
    """Add the reference trials of `setting` to `by_env` (key: evaluation env + reference);
    a reference already evaluated on the same env serves this setting too."""
    _, eval_kwargs = setting_env_kwargs(preset, setting, options)
    references, _ = available_references(preset, options.references)
    for reference in references:
        if setting.references is not None and reference not in setting.references:
            continue
        key = repr(sorted(eval_kwargs.items())) + reference
        if key in by_env:
            shared = by_env[key]
            by_env[key] = dataclasses.replace(shared, settings=(*shared.settings, setting.name))
            continue
        by_env[key] = Trial(
            trial_id=f"{_safe(setting.name)}__{reference}",
            kind=REFERENCE,
            setting=setting.name,
            policy=reference,
            seed=None,
            eval_env_kwargs=eval_kwargs,
            test_seeds=options.test_seeds(preset),
            settings=(setting.name,),
            policy_kwargs=dict(preset.reference_kwargs.get(reference, {})),
        )


def build_trials(
    preset: Preset, options: ExperimentOptions | None = None, runs_dir: str | Path = "runs"
) -> list[Trial]:
    """The trials of `preset` with `options`: learners x seeds x settings, then the references.

    Raises ValueError naming the option for an unknown learner / setting, a bad scale, seed or
    test episode count, or a `vec_env` that `agent-envs train` does not offer (every learner's
    `TrainConfig` is validated).
    """
    options = options or ExperimentOptions()
    options.check(preset)
    settings = select([s.name for s in preset.settings], options.settings, "--settings")
    learners: list[Trial] = []
    references: dict[str, Trial] = {}
    for setting in preset.settings:
        if setting.name in settings:
            learners += _learner_trials(preset, setting, options, runs_dir)
            _add_reference_trials(preset, setting, options, references)
    return learners + list(references.values())


def check_envs(trials: Sequence[Trial], option: str = "--env-kwargs") -> None:
    """Build every distinct training and evaluation env of `trials` once, so that bad env
    kwargs are a ValueError naming `option` before anything trains (`env_description`)."""
    from agent_envs.training.defaults import GYM_ENV_ID
    from agent_envs.training.learners.environments import env_description

    seen: set[str] = set()
    for trial in trials:
        train = trial.train or {}
        envs = [(GYM_ENV_ID, trial.eval_env_kwargs), (train.get("env_id"), train.get("env_kwargs"))]
        for env_id, kwargs in envs:
            key = json.dumps([env_id, kwargs], sort_keys=True)
            if kwargs is not None and key not in seen:
                seen.add(key)
                env_description(env_id, kwargs, option)


# ---------------------------------------------------------------------------- where trials write


def learner_run_dir(trial: Trial, out: Path) -> Path:
    """The run folder of a sweep's learner trial under the sweep's output folder `out`."""
    return out / "runs" / str(trial.train["run_name"])


def reference_dir(trial: Trial, out: Path) -> Path:
    """The folder of a reference trial's evaluation."""
    return out / "references" / trial.setting / trial.policy


def evaluation_dir(trial: Trial, out: Path) -> Path:
    """Where a trial's held-out evaluation is saved."""
    if trial.kind == LEARNER:
        return learner_run_dir(trial, out) / TEST_EVALUATION
    return reference_dir(trial, out)


__all__ = [
    "APG",
    "LEARNER",
    "REFERENCE",
    "ExperimentArguments",
    "ExperimentOptions",
    "GridArguments",
    "Trial",
    "available_references",
    "build_trials",
    "check_envs",
    "evaluation_dir",
    "learner_config",
    "learner_run_dir",
    "run_name",
]
