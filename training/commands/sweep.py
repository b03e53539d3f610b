"""`agent-envs sweep`: the trials of the experiment builder run as Ray Tune trials.

    agent-envs sweep --preset smoke --out sweep-smoke          # CI: 2 trials, well under 2 min
    agent-envs sweep --preset paper --out sweep-paper          # issue 12's study (hours)
    agent-envs sweep --preset paper --out sweep-paper --resume # after an interrupt
    agent-envs sweep --preset paper --address auto             # on a running Ray cluster

Ray. By default a local Ray instance is started (`ray.init(num_cpus=...)`, all of the
machine's CPUs unless ``--num-cpus``); ``--address`` joins an existing cluster instead (its
nodes need this package installed, and OUT must be on a filesystem every node shares: the
trials write their run folders there themselves, and the driver reads them for the report).
Each trial asks for ``--cpus-per-trial`` CPUs (1: the networks are small and train with one
torch thread), so Ray runs (CPUs / cpus-per-trial) trials at once; the workers get
``OPENBLAS_NUM_THREADS=1`` and ``OMP_NUM_THREADS=1`` (Ray's ``runtime_env``).
Ray's own session logs go to its temp dir (``/tmp/ray`` by default), Tune's experiment state to
``OUT/tune`` (`RunConfig(storage_path=OUT)`), never to the working directory.

Trials (one `tune.grid_search` over the trials of `experiment.build_trials`, for the preset of
`agent_envs.training.commands.presets`, the same presets `agent-envs compare` takes):

- a learner trial runs `agent_envs.training.commands.train.train` into
  ``OUT/runs/{setting}__{learner}__{seed}`` (config, checkpoints, learning curve, TensorBoard in
  ``tb/``: the usual run folder), with its stdout/stderr in ``{run folder}.sweep_trial.log`` beside
  it, then evaluates the best model (on the validation seeds) on the held-out test seeds
  (`agent_envs.training.commands.evaluate`) into the run folder's ``test_evaluation/``;
- a reference trial evaluates one reference controller on the same test seeds into
  ``OUT/references/{setting}/{name}/``.

Resuming. ``--resume`` restores the Tune experiment (`Tuner.restore`): finished trials are kept,
interrupted and failed ones run again, and a learner trial that runs again continues its run
from its last checkpoint (`train --resume`; a sweep checkpoints every quarter of a run's budget,
and Ray stops the trials at an interrupt without the checkpoint that `train` writes on Ctrl-C);
a finished training or evaluation is not repeated. The grid is the one saved in
``OUT/sweep.json`` at the start.

Report. When every trial has finished, `agent_envs.training.commands.sweep_report` writes
``OUT/report/report.md`` and ``.html``: the report of `agent-envs compare` (per-policy table,
plots) for the main setting, the across-seed statistics (IQM, stratified-bootstrap CIs,
probability of improvement; `agent_envs.training.results.seed_statistics`), the learning curves with
a band over seeds, and a section per contrast setting.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import shlex
import time
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

from agent_envs.training.commands.experiment import (
    LEARNER,
    TRIAL_LOG,
    ExperimentOptions,
    GridArguments,
    Trial,
    build_trials,
    check_envs,
    evaluation_dir,
    learner_run_dir,
    split_names,
)
from agent_envs.training.commands.learner_runs import budget
from agent_envs.training.commands.presets import PRESETS, get_preset
from agent_envs.training.config import command_line, option_field
from agent_envs.training.defaults import parse_seeds
from agent_envs.validation import MAX_SEED, check_int

#: what `OUT/sweep.json` holds: the options and the expanded grid of the first start
SWEEP_FILE = "sweep.json"
#: Tune's experiment folder under OUT
TUNE_NAME = "tune"


@dataclass
class RayArguments:
    """The Ray options of the commands that run trials on Ray Tune (`sweep`, `tune`)."""

    num_cpus: int | None = option_field(
        None, "CPUs of the local Ray instance (default: all of this machine's)"
    )
    address: str | None = option_field(
        None, "address of an existing Ray cluster ('auto': the one on this machine)"
    )
    cpus_per_trial: float = option_field(1.0, "CPUs Ray reserves for each trial")

    def __post_init__(self) -> None:
        if self.num_cpus is not None:
            check_int("--num-cpus", self.num_cpus, 1, 1_000_000)
        if not (
            isinstance(self.cpus_per_trial, (int, float))
            and not isinstance(self.cpus_per_trial, bool)
            and math.isfinite(self.cpus_per_trial)
            and self.cpus_per_trial > 0
        ):
            raise ValueError(f"--cpus-per-trial must be a number > 0, got {self.cpus_per_trial}")
        if self.address is not None and self.num_cpus is not None:
            raise ValueError("--num-cpus sizes a local Ray instance; leave it out with --address")
        if self.address is not None and not self.address.strip():
            raise ValueError("--address must name a Ray cluster ('auto' or HOST:PORT), got ''")


@dataclass
class SweepConfig(GridArguments, RayArguments):
    """Options of `agent-envs sweep` (one field = one option): the shared experiment options
    (`GridArguments`) and the sweep's own."""

    preset: str = option_field("smoke", "the sweep", choices=tuple(PRESETS))
    out: str | None = option_field(None, "output directory (default sweep-{preset})")
    resume: bool = option_field(
        False, "continue the interrupted sweep in OUT (Tune's Tuner.restore; the saved grid)"
    )
    seeds: str | None = option_field(
        None, "training seeds: '0,1,2', '0-2' or '0:3' (default: the preset's)"
    )
    settings: str | None = option_field(
        None, "comma-separated env settings of the preset to run (default: all)"
    )
    dry_run: bool = option_field(False, "print the trials and exit (starts no Ray)")
    bootstrap_seed: int = option_field(0, "seed of the bootstrap's generator in the report")

    def __post_init__(self) -> None:
        GridArguments.__post_init__(self)
        RayArguments.__post_init__(self)
        get_preset(self.preset)  # ValueError naming --preset
        check_int("--bootstrap-seed", self.bootstrap_seed, 0, MAX_SEED)
        self.training_seeds()  # ValueError naming --seeds

    def validate(self, trials: list[Trial] | None = None) -> SweepConfig:
        """Check the output folder and the whole grid (`trials` when the caller built it
        already) before Ray starts; returns self."""
        from agent_envs.training.storage import check_output_dir

        check_output_dir(self.out_dir, "--out")
        if not self.resume:
            check_envs(self.trials() if trials is None else trials)
        return self

    @property
    def out_dir(self) -> Path:
        return Path(self.out or f"sweep-{self.preset}").resolve()

    def trials(self) -> list[Trial]:
        """The grid of this sweep (the experiment builder's trials; every config checked)."""
        return build_trials(get_preset(self.preset), self.options(), self.out_dir / "runs")

    def training_seeds(self) -> tuple[int, ...] | None:
        """--seeds in the one seed syntax (`defaults.parse_seeds`; None: the preset's)."""
        seeds = parse_seeds(self.seeds, "--seeds", default=None)
        return None if seeds is None else tuple(seeds)

    def options(self) -> ExperimentOptions:
        return self.experiment_options(
            seeds=self.training_seeds(), settings=split_names(self.settings)
        )

    def command(self) -> str:
        """The `agent-envs sweep` command line of this config (non-default options only)."""
        return command_line("sweep", self)


# ------------------------------------------------------------------------------------- trials


def _finished_evaluation(folder: Path, trial: Trial) -> bool:
    meta_path = folder / "meta.json"
    if not (folder / "episodes.csv").is_file() or not meta_path.is_file():
        return False
    meta = json.loads(meta_path.read_text())
    return list(meta.get("seeds", [])) == list(trial.test_seeds) and meta.get(
        "env_kwargs"
    ) == json.loads(json.dumps(trial.eval_env_kwargs))


def train_trial(trial: Trial, out: Path) -> Path:
    """Train the learner of `trial` (or continue its interrupted run); return the run folder."""
    from agent_envs.training.commands.learner_runs import train_from_dict

    return train_from_dict({**trial.train, "out": str(out / "runs")})


def trial_log_path(trial: Trial, out: Path) -> Path:
    """Where a trial's stdout/stderr go: beside a learner's run folder (which `train` must
    create itself, exclusively), inside a reference trial's evaluation folder."""
    if trial.kind == LEARNER:
        run_dir = learner_run_dir(trial, out)
        return run_dir.parent / f"{run_dir.name}.{TRIAL_LOG}"
    return evaluation_dir(trial, out) / TRIAL_LOG


def execute_trial(trial: Trial, out: Path) -> dict[str, Any]:
    """Run one trial without Ray (the Tune trainable calls this); returns its metrics.

    A learner trial writes its log to ``{run folder}.sweep_trial.log`` beside its run folder
    (`train` creates the run folder itself, exclusively), a reference trial to
    ``sweep_trial.log`` in its evaluation folder.
    """
    from agent_envs.training.commands.evaluate import evaluate_policies
    from agent_envs.training.commands.learner_runs import evaluation_spec
    from agent_envs.training.defaults import GYM_ENV_ID
    from agent_envs.training.results.tables import EvaluationResults

    started = time.perf_counter()
    folder = evaluation_dir(trial, out)
    log_path = trial_log_path(trial, out)
    log_path.parent.mkdir(parents=True, exist_ok=True)
    with (
        open(log_path, "a", buffering=1) as log,
        contextlib.redirect_stdout(log),
        contextlib.redirect_stderr(log),
    ):
        print(f"trial {trial.trial_id} started {time.strftime('%Y-%m-%d %H:%M:%S')}")
        if trial.kind == LEARNER:
            run_dir = train_trial(trial, out)
            spec = evaluation_spec(run_dir)
        else:
            spec = trial.reference_spec()
            if trial.policy_kwargs:
                print(f"reference {trial.policy} built with {trial.policy_kwargs}")
        if _finished_evaluation(folder, trial):
            print(f"reusing the finished evaluation in {folder}")
            results = EvaluationResults.load(folder)
        else:
            results = evaluate_policies(
                {trial.policy: spec},
                env_id=GYM_ENV_ID,
                env_kwargs=trial.eval_env_kwargs,
                seeds=trial.test_seeds,
                progress=False,
                out_dir=folder,
            )
        print(f"trial {trial.trial_id} done in {time.perf_counter() - started:.1f} s")
    episodes = results.episodes
    return {
        "kind": trial.kind,
        "mean_cost": float(episodes["total_cost"].mean()),
        "divergence_rate": float(episodes["diverged"].astype(bool).mean()),
        "trial_wall_time_s": round(time.perf_counter() - started, 2),
    }


def tune_trainable(config: dict[str, Any]) -> None:
    """The Ray Tune function trainable: one trial, its metrics reported once at the end."""
    import ray
    from ray import tune

    trial = Trial.from_dict(config["trial"])
    metrics = execute_trial(trial, Path(config["out"]))
    tune.report({**metrics, "node_id": ray.get_runtime_context().get_node_id()})


def trial_dirname(trial: Any) -> str:
    """Tune's folder of a trial: the sweep's trial id (not Tune's long config string)."""
    return str(trial.config["trial"]["trial_id"])


# ---------------------------------------------------------------------------------------- Ray


def start_ray(config: RayArguments, out: Path) -> bool:
    """`ray.init`: join `config.address`, or start a local instance with `config.num_cpus`
    (without the dashboard) and record its session in `out` (`ray_session.record_session`).

    Returns False when Ray was already initialized in this process (nothing started).
    """
    import ray

    from agent_envs.training.ray_session import record_session

    if ray.is_initialized():
        return False
    env = {"env_vars": {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}}
    if config.address:
        ray.init(address=config.address, runtime_env=env, log_to_driver=False)
        return True
    context = ray.init(
        num_cpus=config.num_cpus or os.cpu_count() or 1,
        include_dashboard=False,
        runtime_env=env,
        log_to_driver=False,
    )
    record_session(out, context.address_info["session_dir"])
    return True


def run_tuner(config: SweepConfig, trials: list[Trial], out: Path):
    """Run (or, with `config.resume`, restore and finish) the Tune experiment; its ResultGrid."""
    from ray import tune

    trainable = tune.with_resources(tune_trainable, {"cpu": config.cpus_per_trial})
    path = out / TUNE_NAME
    if config.resume and tune.Tuner.can_restore(str(path)):
        tuner = tune.Tuner.restore(
            str(path), trainable=trainable, resume_unfinished=True, restart_errored=True
        )
    else:
        tuner = tune.Tuner(
            trainable,
            param_space={
                "trial": tune.grid_search([t.to_dict() for t in trials]),
                "out": str(out),
            },
            tune_config=tune.TuneConfig(
                trial_name_creator=trial_dirname, trial_dirname_creator=trial_dirname
            ),
            run_config=tune.RunConfig(
                name=TUNE_NAME,
                storage_path=str(out),
                verbose=1,
                failure_config=tune.FailureConfig(max_failures=0),
            ),
        )
    return tuner.fit()


# ------------------------------------------------------------------------------------ the run


def _load_or_save_grid(
    config: SweepConfig, out: Path, trials: list[Trial] | None = None
) -> tuple[SweepConfig, list[Trial], str]:
    """(config, trials, the starting command) of this sweep: saved in OUT/sweep.json at the
    first start (`trials`, or the grid built here), read back on resume (then only the Ray
    options come from `config`)."""
    path = out / SWEEP_FILE
    if config.resume:
        if not path.is_file():
            raise ValueError(f"--resume: no {SWEEP_FILE} in {out} (no sweep was started there)")
        saved = json.loads(path.read_text())
        stored = SweepConfig(**saved["config"])
        if stored.preset != config.preset:
            raise ValueError(
                f"--resume: {out} holds a sweep of the {stored.preset} preset, not {config.preset}"
            )
        keep = replace(
            stored,
            resume=True,
            num_cpus=config.num_cpus,
            address=config.address,
            cpus_per_trial=config.cpus_per_trial,
        )
        command = f"{saved['command']}  # resumed with --resume"
        return keep, [Trial.from_dict(t) for t in saved["trials"]], command
    if (out / TUNE_NAME).exists() or path.exists():
        raise ValueError(
            f"{out} already holds a sweep; pass --resume to continue it or choose another --out"
        )
    trials = config.trials() if trials is None else trials
    out.mkdir(parents=True, exist_ok=True)
    record = {
        "config": {f.name: getattr(config, f.name) for f in fields(config)},
        "command": config.command(),
        "trials": [t.to_dict() for t in trials],
    }
    path.write_text(json.dumps(record, indent=1) + "\n")
    return config, trials, record["command"]


def describe_trials(trials: list[Trial]) -> str:
    lines = []
    for t in trials:
        if t.kind == LEARNER:
            tc = t.train
            lines.append(
                f"{t.trial_id}: train {tc['algo']} on {tc['env_id']} for {budget(tc)} "
                f"(seed {t.seed}, env {tc['env_kwargs']}), evaluate on "
                f"{len(t.test_seeds)} test seeds"
            )
        else:
            lines.append(
                f"{t.trial_id}: evaluate {t.policy}"
                + (f" {t.policy_kwargs}" if t.policy_kwargs else "")
                + f" on {len(t.test_seeds)} test seeds "
                f"(env {t.eval_env_kwargs}; settings {', '.join(t.settings)})"
            )
    return "\n".join(lines)


def sweep(config: SweepConfig) -> dict[str, Any]:
    """Run the sweep of `config` and write its report; returns paths and tables."""
    from agent_envs.training.commands.sweep_report import write_sweep_report

    started = time.perf_counter()
    built = None if config.resume else config.trials()  # built (and validated) once
    config.validate(built)
    out = config.out_dir
    if config.dry_run:
        trials = built if built is not None else config.trials()
        print(describe_trials(trials))
        return {"trials": trials}
    config, trials, command = _load_or_save_grid(config, out, built)
    n_learn = sum(t.kind == LEARNER for t in trials)
    print(
        f"sweep --preset {config.preset}: {n_learn} learner trials and "
        f"{len(trials) - n_learn} reference trials; output {out}",
        flush=True,
    )
    from agent_envs.training.ray_session import clean_up_after_killed_driver, forget_session

    ended = clean_up_after_killed_driver(out)
    if ended:
        print(f"ended {ended} processes left by the Ray instance of a killed sweep in {out}")
    started_ray = start_ray(config, out)
    ray_started = time.perf_counter()
    try:
        grid = run_tuner(config, trials, out)
        tune_done = time.perf_counter()
    finally:
        if started_ray:
            import ray

            ray.shutdown()
            forget_session(out)
    missing = [t.trial_id for t in trials if not _finished_evaluation(evaluation_dir(t, out), t)]
    if grid.num_errors or missing:
        errors = [str(r.error).splitlines()[0] for r in grid if r.error is not None][:3]
        raise RuntimeError(
            f"{len(missing)} of {len(trials)} trials did not finish ({', '.join(missing[:5])}"
            f"{'...' if len(missing) > 5 else ''}); errors: {errors or 'none (interrupted)'}; "
            f"per-trial logs in {out}/runs/*.{TRIAL_LOG}; continue with: "
            f"agent-envs sweep --preset {config.preset} --out {shlex.quote(str(out))} --resume"
        )
    timing = {
        "ray_init_s": round(ray_started - started, 1),
        "tune_s": round(tune_done - ray_started, 1),
    }
    trial_times = {
        str(r.config["trial"]["trial_id"]): float(r.metrics["trial_wall_time_s"])
        for r in grid
        if r.config and r.metrics and "trial_wall_time_s" in r.metrics
    }
    nodes = {
        str(r.config["trial"]["trial_id"]): str(r.metrics["node_id"])
        for r in grid
        if r.config and r.metrics and "node_id" in r.metrics
    }
    paths = write_sweep_report(config, trials, out, timing, command, trial_times, nodes)
    total = time.perf_counter() - started
    print(f"report: {paths['markdown']} and {paths['html']} ({total:.0f} s in all)")
    return {"paths": paths, "trials": trials, "timing": timing, "nodes": nodes}


__all__ = ["SweepConfig", "execute_trial", "sweep"]
