"""`agent-envs tune`: a hyperparameter search for one learner of a preset, on Ray Tune + Optuna.

    agent-envs tune --preset smoke --learner ppo --num-samples 4 --out tune-smoke   # CI
    agent-envs tune --preset paper --learner ppo-shared --num-samples 40 --out tune-paper
    agent-envs tune --preset paper --learner ppo-shared --out tune-paper --resume

The way the SB3 ecosystem tunes (rl-zoo3's ``hyperparams_opt.py``): Optuna's TPE sampler
proposes the hyperparameters (`SEARCH_SPACES`: rl-zoo3's ranges, with gamma's range widened to
the short episodes here and the options the issue asks for: normalize, log_std_init, ortho_init,
n_envs, net_arch), Ray Tune runs the trials (`ray.tune.search.optuna.OptunaSearch`, one trial =
one `agent-envs train` run of the learner with the sampled hyperparameters per training seed of
``--seeds``, its validation cost reported at every evaluation), and a scheduler stops the
unpromising ones early (ASHA on the timesteps, or the median stopping rule). The objective is
the best validation cost of a run (the model `compare`/`sweep` would evaluate), with several
training seeds their worst, median or mean (``--seed-objective``; the seeds run one after the
other inside the trial, `seed_objective` says how they are reported): validation seeds only,
the held-out test seeds stay unseen.

Each trial trains into ``OUT/runs/trial_{id}`` (the usual run folder; ``trial_{id}__{seed}``
per seed with several seeds); Tune's experiment state goes to ``OUT/tune``. At the end
``OUT/tune_summary.md`` lists the best trials with their per-seed costs, their hyperparameters
and Optuna's parameter importances (fANOVA), ``OUT/trials.csv`` every trial, and
``OUT/best_hyperparams.yml`` the best trial's hyperparameters in the shipped YAML format, with
a comment naming the study, its seeds and objective, ready to paste into
``training/hyperparams/{algo}.yml``.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from agent_envs.params import SwarmParams
from agent_envs.training.commands.experiment import ExperimentArguments, learner_config
from agent_envs.training.commands.presets import PRESETS, Learner, get_preset
from agent_envs.training.commands.seed_objective import (
    SEED_COLUMN_PREFIX,
    SEED_OBJECTIVES,
    SeedReports,
    aggregate_seeds,
    seed_column,
)
from agent_envs.training.commands.sweep import RayArguments
from agent_envs.training.config import TrainConfig, command_line, option_field
from agent_envs.training.defaults import is_multiagent, parse_seeds, seed_text
from agent_envs.validation import MAX_SEED, check_int

#: Tune's experiment folder under OUT
TUNE_NAME = "tune"
#: what the trials report and the search minimizes
METRIC = "validation_cost"
#: the training seeds of every trial when --seeds is left out
DEFAULT_SEEDS = (0,)
#: schedulers that stop unpromising trials early
PRUNERS = ("asha", "median", "none")
#: net_arch choices (rl-zoo3's names)
NET_ARCHS = {"tiny": [64], "small": [64, 64], "medium": [256, 256]}


# ------------------------------------------------------------------------------ search spaces


def _common(trial: Any, hyper: dict[str, Any]) -> dict[str, Any]:
    """The options every algorithm's space has: gamma (1 - gamma log-uniform in [1e-3, 0.2]:
    the 20-50 step episodes here want gamma down to 0.8, below rl-zoo3's 0.97), the learning
    rate, the network and the observation/reward normalization."""
    hyper["gamma"] = 1.0 - trial.suggest_float("one_minus_gamma", 1e-3, 0.2, log=True)
    hyper["learning_rate"] = trial.suggest_float("learning_rate", 1e-5, 2e-3, log=True)
    arch = trial.suggest_categorical("net_arch", list(NET_ARCHS))
    hyper.setdefault("policy_kwargs", {})["net_arch"] = NET_ARCHS[arch]
    return {
        "hyperparams": hyper,
        "normalize": trial.suggest_categorical("normalize", [True, False]),
    }


def sample_ppo(trial: Any, budget: int = 0, agents: int = 1) -> dict[str, Any]:
    """rl-zoo3's PPO space (`sample_ppo_params`) plus log_std_init, ortho_init and n_envs.

    For the parameter-shared learner (`agents` = N agent-envs per swarm copy, `budget` in
    agent-steps) n_steps counts steps per agent: its range is 2^3 .. 2^9 and it is cut so that
    the budget holds at least 8 rollouts of n_steps x n_envs x N samples.
    """
    n_envs = trial.suggest_categorical("n_envs", [1, 2, 4, 8])
    low, high = (3, 9) if agents > 1 else (5, 11)
    n_steps = 2 ** trial.suggest_int("n_steps_pow", low, high)
    if agents > 1 and budget > 0:
        n_steps = max(min(n_steps, budget // (8 * agents * n_envs)), 1)
    batch_size = 2 ** trial.suggest_int("batch_size_pow", 5, 10)
    hyper: dict[str, Any] = {
        "n_steps": n_steps,
        "batch_size": min(batch_size, n_steps * n_envs * agents),
        "gae_lambda": 1.0 - trial.suggest_float("one_minus_gae_lambda", 1e-4, 0.1, log=True),
        "ent_coef": trial.suggest_float("ent_coef", 1e-8, 0.1, log=True),
        "clip_range": trial.suggest_categorical("clip_range", [0.1, 0.2, 0.3, 0.4]),
        "n_epochs": trial.suggest_categorical("n_epochs", [1, 5, 10, 20]),
        "max_grad_norm": trial.suggest_float("max_grad_norm", 0.3, 2.0),
        "policy_kwargs": {
            "log_std_init": trial.suggest_float("log_std_init", -4.0, 1.0),
            "ortho_init": trial.suggest_categorical("ortho_init", [True, False]),
        },
    }
    return {**_common(trial, hyper), "n_envs": n_envs}


def _off_policy(trial: Any, budget: int) -> dict[str, Any]:
    """The replay and update options rl-zoo3's SAC and TD3 spaces share, within `budget`."""
    train_freq = trial.suggest_categorical("train_freq", [1, 4, 8, 16, 32])
    return {
        "batch_size": trial.suggest_categorical("batch_size", [64, 128, 256, 512]),
        "buffer_size": budget,  # the whole budget: SB3 allocates it up front
        "learning_starts": min(
            trial.suggest_categorical("learning_starts", [0, 1000]), budget // 4
        ),
        "train_freq": train_freq,
        "gradient_steps": train_freq,
        "tau": trial.suggest_categorical("tau", [0.001, 0.005, 0.01, 0.02, 0.05]),
    }


def sample_sac(trial: Any, budget: int) -> dict[str, Any]:
    """rl-zoo3's SAC space (`sample_sac_params`) with log_std_init."""
    hyper = _off_policy(trial, budget)
    hyper["ent_coef"] = "auto"
    hyper["policy_kwargs"] = {"log_std_init": trial.suggest_float("log_std_init", -4.0, 1.0)}
    return {**_common(trial, hyper), "n_envs": 1}


def sample_td3(trial: Any, budget: int) -> dict[str, Any]:
    """rl-zoo3's TD3 space (`sample_td3_params`): Gaussian action noise of tuned scale."""
    hyper = _off_policy(trial, budget)
    hyper["noise_type"] = "normal"
    hyper["noise_std"] = trial.suggest_float("noise_std", 0.01, 1.0, log=True)
    return {**_common(trial, hyper), "n_envs": 1}


def search_space(algo: str, budget: int, agents: int = 1) -> Callable[[Any], dict[str, Any]]:
    """The define-by-run search space of `algo` (an Optuna trial -> sampled settings);
    `agents` > 1 for the parameter-shared learner (N agent-envs per swarm copy)."""
    if algo == "ppo":
        return functools.partial(sample_ppo, budget=budget, agents=agents)
    if algo == "sac":
        return functools.partial(sample_sac, budget=budget)
    if algo == "td3":
        return functools.partial(sample_td3, budget=budget)
    raise ValueError(f"--learner: no search space for {algo!r}; tune takes ppo, sac, td3 learners")


def agents_per_copy(base: dict[str, Any]) -> int:
    """N for the parameter-shared learner (SB3 sees one env per agent), 1 otherwise."""
    if not is_multiagent(base["env_id"]):
        return 1
    return int(base.get("env_kwargs", {}).get("n_agents", SwarmParams.n_agents))


def trial_train_config(base: TrainConfig, sampled: dict[str, Any], run_name: str) -> TrainConfig:
    """The learner's `TrainConfig` with a trial's sampled settings (its own run folder)."""
    return dataclasses.replace(
        base,
        hyperparams={**base.hyperparams, **sampled["hyperparams"]},
        n_envs=sampled["n_envs"],
        normalize=sampled["normalize"],
        run_name=run_name,
    )


# ------------------------------------------------------------------------------------ config


@dataclass
class TuneConfig(ExperimentArguments, RayArguments):
    """Options of `agent-envs tune` (one field = one option): the shared experiment and Ray
    options and tune's own."""

    preset: str = option_field("smoke", "the experiment setting", choices=tuple(PRESETS))
    learner: str | None = option_field(
        None, "the preset's learner to tune (default: its first; ppo, sac and td3 learners)"
    )
    setting: str | None = option_field(
        None, "the preset's env setting to tune on (default: its main one)"
    )
    out: str | None = option_field(None, "output directory (default tune-{preset}-{learner})")
    num_samples: int = option_field(20, "trials (hyperparameter sets) to run")
    seeds: tuple[int, ...] = option_field(
        DEFAULT_SEEDS,
        "training seeds of every trial, each a run of the sampled hyperparameters: '0 1 2', "
        "'0-2' or '0,1,2'",
        nargs="+",
        type=str,
    )
    seed_objective: str = option_field(
        "worst",
        "a trial's objective over its training seeds' best validation costs",
        choices=SEED_OBJECTIVES,
    )
    sampler_seed: int = option_field(0, "seed of Optuna's TPE sampler")
    pruner: str = option_field(
        "asha", "early stopping of unpromising trials on the validation cost", choices=PRUNERS
    )
    resume: bool = option_field(False, "continue the interrupted search in OUT (Tuner.restore)")
    dry_run: bool = option_field(False, "print the learner's base config and exit (no Ray)")

    def __post_init__(self) -> None:
        ExperimentArguments.__post_init__(self)
        RayArguments.__post_init__(self)
        preset = get_preset(self.preset)
        preset.setting(self.setting)
        check_int("--num-samples", self.num_samples, 1, 100_000)
        self.seeds = tuple(parse_seeds(self.seeds, "--seeds", default=DEFAULT_SEEDS))
        aggregate_seeds([0.0], self.seed_objective)  # ValueError naming --seed-objective
        check_int("--sampler-seed", self.sampler_seed, 0, MAX_SEED)
        if self.pruner not in PRUNERS:
            raise ValueError(f"--pruner must be one of {', '.join(PRUNERS)}, got {self.pruner!r}")
        search_space(self.learner_entry().algo, 1)  # ValueError naming --learner

    def learner_entry(self) -> Learner:
        preset = get_preset(self.preset)
        if self.learner is None:
            return preset.learners[0]
        by_name = {lr.name: lr for lr in preset.learners}
        if self.learner not in by_name:
            raise ValueError(
                f"--learner must be one of the {self.preset} preset's learners "
                f"({', '.join(by_name)}), got {self.learner!r}"
            )
        return by_name[self.learner]

    @property
    def out_dir(self) -> Path:
        return Path(self.out or f"tune-{self.preset}-{self.learner_entry().name}").resolve()

    def base_config(self) -> TrainConfig:
        """The learner's `TrainConfig` in the preset (its budget times --timesteps-scale, its
        validation schedule), before the sampled hyperparameters."""
        preset = get_preset(self.preset)
        options = self.experiment_options(seeds=self.seeds, run_names=False)
        options.check(preset)
        config = learner_config(
            preset,
            preset.setting(self.setting),
            self.learner_entry(),
            self.seeds[0],
            options,
            self.out_dir / "runs",
        )
        return dataclasses.replace(config, progress_bar=False, tensorboard=False)

    def command(self) -> str:
        return command_line("tune", self)

    def objective_text(self) -> str:
        """The objective in words, e.g. ``the worst over training seeds 0,1,2``."""
        if len(self.seeds) == 1:
            return f"training seed {self.seeds[0]}"
        return f"the {self.seed_objective} over training seeds {seed_text(self.seeds)}"


# ------------------------------------------------------------------------------------ trials


def tune_trainable(config: dict[str, Any]) -> None:
    """One Tune trial: train with the sampled settings on each training seed in turn,
    reporting at every evaluation the objective so far over the seeds (`SeedReports`: the
    scheduler may stop the trial there)."""
    from ray import tune

    from agent_envs.training.commands.train import train

    base = TrainConfig.from_dict(config["base"])
    # a search started before --seeds existed (resumed) has one seed, in its base config
    seeds = tuple(config.get("seeds", (base.seed,)))
    name = f"trial_{tune.get_context().get_trial_id()}"
    reports = SeedReports(seeds, base.timesteps, config.get("objective", "worst"), METRIC)
    for seed in seeds:
        run_name = name if len(seeds) == 1 else f"{name}__{seed}"
        trial = trial_train_config(base, config["sampled"], run_name)
        train(
            dataclasses.replace(trial, seed=seed),
            on_evaluation=lambda row: tune.report(reports.evaluation(row)),
        )
        reports.next_seed()


@dataclass(frozen=True)
class DefineByRun:
    """The define-by-run function OptunaSearch calls (picklable: Tune checkpoints the
    searcher): samples, and returns the constants a trial needs (`CONSTANTS`: its base config,
    the sampled settings in the form `trial_train_config` takes, its training seeds and their
    objective)."""

    base: dict[str, Any]
    seeds: tuple[int, ...] = DEFAULT_SEEDS
    objective: str = SEED_OBJECTIVES[0]

    def __call__(self, trial: Any) -> dict[str, Any]:
        sample = search_space(
            self.base["algo"], int(self.base["timesteps"]), agents_per_copy(self.base)
        )
        return {
            "base": self.base,
            "sampled": sample(trial),
            "seeds": list(self.seeds),
            "objective": self.objective,
        }


#: the keys of a trial's config that `DefineByRun` returns (not sampled parameters)
CONSTANTS = ("base", "sampled", "seeds", "objective")


def _scheduler(config: TuneConfig, base: TrainConfig) -> Any:
    """The pruner on the trials' time axis: the seeds' timesteps end to end."""
    from ray.tune.schedulers import ASHAScheduler, FIFOScheduler, MedianStoppingRule

    grace = 2 * max(base.eval_freq, 1)  # two evaluations before a trial can be stopped
    if config.pruner == "asha":
        return ASHAScheduler(
            time_attr="timesteps",
            max_t=base.timesteps * len(config.seeds),
            grace_period=grace,
            reduction_factor=2,
        )
    if config.pruner == "median":
        return MedianStoppingRule(time_attr="timesteps", grace_period=grace)
    return FIFOScheduler()


def _trial_name(trial: Any) -> str:
    """Tune's folder of a trial: ``trial_{id}`` (not Tune's long config string)."""
    return f"trial_{trial.trial_id}"


def run_search(config: TuneConfig, base: TrainConfig) -> Any:
    """Run (or restore and finish) the Tune experiment; its ResultGrid."""
    import optuna
    from ray import tune
    from ray.tune.search.optuna import OptunaSearch

    trainable = tune.with_resources(tune_trainable, {"cpu": config.cpus_per_trial})
    path = config.out_dir / TUNE_NAME
    if config.resume and tune.Tuner.can_restore(str(path)):
        return tune.Tuner.restore(
            str(path), trainable=trainable, resume_unfinished=True, restart_errored=True
        ).fit()
    search = OptunaSearch(
        space=DefineByRun(base.to_dict(), config.seeds, config.seed_objective),
        metric=METRIC,
        mode="min",
        sampler=optuna.samplers.TPESampler(seed=config.sampler_seed),
    )
    tuner = tune.Tuner(
        trainable,
        tune_config=tune.TuneConfig(
            search_alg=search,
            scheduler=_scheduler(config, base),
            metric=METRIC,
            mode="min",
            num_samples=config.num_samples,
        ),
        run_config=tune.RunConfig(
            name=TUNE_NAME,
            storage_path=str(config.out_dir),
            verbose=1,
            failure_config=tune.FailureConfig(max_failures=0),
        ),
    )
    return tuner.fit()


# ----------------------------------------------------------------------------------- summary


#: columns of the trials table that are not sampled parameters (and the per-seed costs)
RESULT_COLUMNS = ("trial", METRIC, "timesteps", "error")


def _is_result(column: str) -> bool:
    """Whether a column of the trials table is a result, not a sampled parameter."""
    return column in RESULT_COLUMNS or column.startswith(SEED_COLUMN_PREFIX)


def _params(row: Any, columns: Any) -> dict[str, Any]:
    """The sampled parameters of one row of the trials table (NaN: not sampled there)."""
    values = {k: row[k].item() if hasattr(row[k], "item") else row[k] for k in columns}
    return {
        k: v
        for k, v in values.items()
        if not _is_result(k) and not (isinstance(v, float) and math.isnan(v))
    }


def trials_table(grid: Any, seeds: tuple[int, ...]):
    """One row per trial: its objective (the aggregate over `seeds`), each seed's best
    validation cost (NaN: the trial was stopped before that seed), its timesteps on the seeds'
    common axis (`seed_objective`), its status and its sampled parameters. Best first: trials
    that reached more seeds rank first (a partial objective over fewer seeds is not the
    objective), then by the objective."""
    import pandas as pd

    rows = []
    for result in grid:
        if not result.config:
            continue
        params = {k: v for k, v in result.config.items() if k not in CONSTANTS}
        metrics = result.metrics or {}
        rows.append(
            {
                "trial": metrics.get("trial_id", ""),
                METRIC: metrics.get(METRIC, math.nan),
                **{seed_column(s): metrics.get(seed_column(s), math.nan) for s in seeds},
                "timesteps": metrics.get("timesteps", 0),
                "error": bool(result.error),
                **params,
            }
        )
    table = pd.DataFrame(rows)
    reached = table[[seed_column(s) for s in seeds]].notna().sum(axis=1)
    order = table.assign(_reached=-reached).sort_values(["_reached", METRIC], na_position="last")
    return order.drop(columns="_reached").reset_index(drop=True)


def parameter_importances(config: TuneConfig, base: TrainConfig, table) -> dict[str, float]:
    """Optuna's fANOVA importances of the finished trials (a cost on every training seed): an
    in-memory study replays every trial's parameters through the same search space with its
    measured cost."""
    import optuna

    every_seed = table[[seed_column(s) for s in config.seeds]].notna().all(axis=1)
    finished = table[every_seed & table[METRIC].apply(math.isfinite)]
    if len(finished) < 2:
        return {}
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    sample = search_space(base.algo, base.timesteps, agents_per_copy(base.to_dict()))
    study = optuna.create_study(direction="minimize")
    costs = []
    for _, row in finished.iterrows():
        study.enqueue_trial(_params(row, finished.columns))
        costs.append(float(row[METRIC]))
    values = iter(costs)
    study.optimize(lambda t: (sample(t), next(values))[1], n_trials=len(costs))
    try:
        return dict(optuna.importance.get_param_importances(study))
    except (RuntimeError, ValueError):  # e.g. every trial with the same cost
        return {}


def best_yaml(config: TuneConfig, base: TrainConfig, table) -> str:
    """The best trial's settings as an entry of the shipped YAML files, with its study named."""
    import yaml

    best = table.iloc[0]
    sample = search_space(base.algo, base.timesteps, agents_per_copy(base.to_dict()))
    import optuna

    trial = optuna.trial.FixedTrial(_params(best, table.columns))
    sampled = sample(trial)
    entry = {
        "n_envs": sampled["n_envs"],
        "normalize": sampled["normalize"],
        **{k: v for k, v in sampled["hyperparams"].items()},
    }
    per_seed = ", ".join(f"{best[seed_column(s)]:.6g}" for s in config.seeds)
    header = (
        f"# tuned by `{config.command()}` ({time.strftime('%Y-%m-%d')}): best of "
        f"{len(table)} trials, validation cost {best[METRIC]:.6g} on the validation seeds "
        f"({config.objective_text()}" + (f": {per_seed}" if len(config.seeds) > 1 else "") + ")\n"
    )
    return header + yaml.safe_dump({base.env_id: entry}, sort_keys=False)


def write_summary(config: TuneConfig, base: TrainConfig, grid: Any) -> dict[str, Path]:
    """OUT/trials.csv, OUT/tune_summary.md and OUT/best_hyperparams.yml."""
    from agent_envs.training.results.report import markdown_table
    from agent_envs.training.storage import write_text_atomic

    out = config.out_dir
    table = trials_table(grid, config.seeds)
    table.to_csv(out / "trials.csv", index=False)
    importances = parameter_importances(config, base, table)
    lines = [
        f"# Tuning {config.learner_entry().name} ({base.algo} on {base.env_id}), preset "
        f"{config.preset}",
        "",
        f"Command: `{config.command()}`. {len(table)} trials, {base.timesteps} timesteps each "
        f"at most per training seed (pruner {config.pruner}); objective: the best validation "
        f"cost of a run, {config.objective_text()} (validation seeds "
        f"{base.eval_seed}..{base.eval_seed + base.eval_episodes - 1}).",
        "",
        "## Best trials",
        "",
        markdown_table(table.head(10)),
        "",
        "## Parameter importances (Optuna, fANOVA)",
        "",
    ]
    lines += [f"- {name}: {value:.3f}" for name, value in importances.items()] or [
        "(too few trials)"
    ]
    paths = {"summary": out / "tune_summary.md", "trials": out / "trials.csv"}
    write_text_atomic(paths["summary"], "\n".join(lines) + "\n")
    if math.isfinite(float(table.iloc[0][METRIC])):
        paths["best"] = out / "best_hyperparams.yml"
        write_text_atomic(paths["best"], best_yaml(config, base, table))
    return paths


def tune_learner(config: TuneConfig) -> dict[str, Any]:
    """Run the search of `config` and write its summary; returns paths and the trials table."""
    from agent_envs.training.commands.sweep import start_ray
    from agent_envs.training.learners.environments import env_description
    from agent_envs.training.ray_session import clean_up_after_killed_driver, forget_session
    from agent_envs.training.storage import check_output_dir

    out = config.out_dir
    check_output_dir(out, "--out")
    base = config.base_config()
    env_description(base.env_id, base.env_kwargs)  # the env kwargs, before Ray starts
    if config.dry_run:
        print(json.dumps(base.to_dict(), indent=1))
        return {"base": base}
    if not config.resume and (out / TUNE_NAME).exists():
        raise ValueError(f"{out} already holds a search; pass --resume or choose another --out")
    clean_up_after_killed_driver(out)
    started_ray = start_ray(config, out)
    try:
        grid = run_search(config, base)
    finally:
        if started_ray:
            import ray

            ray.shutdown()
            forget_session(out)
    paths = write_summary(config, base, grid)
    print(paths["summary"].read_text())
    return {"paths": paths, "table": trials_table(grid, config.seeds), "base": base}


__all__ = ["TuneConfig", "search_space", "tune_learner"]
