"""Train learners, then compare them with the reference controllers (`agent-envs compare`).

    agent-envs compare --preset quick            # a few minutes on 2 CPU cores
    agent-envs compare --preset paper            # N = 100, stiff, SERB, m = 50; much longer
    agent-envs compare --preset paper --setting eps1 --learners ppo

The presets are the ones of `agent-envs sweep` (`agent_envs.training.commands.presets`): compare
runs one training seed (``--seed``, default the preset's first) of one env setting (``--setting``,
default the main one) in process; the runs come from the experiment builder
(`agent_envs.training.commands.experiment`), as the sweep's do.

Steps: (1) train every learner of the preset (`learner_runs.train_from_dict`; a finished run
of the same configuration in ``OUT/runs`` is reused, an interrupted one resumed from its last
checkpoint); (2) evaluate the learners' best models (chosen on the validation seeds) and the
turnpike, proportional and zero controllers on the same held-out test seeds
(`agent_envs.training.commands.evaluate`), plus the parameter-shared policy agent by agent on the
PettingZoo env; (3) write the report of `agent_envs.training.results.report` with the learning
curves added (``OUT/report/report.md`` and ``.html``).

Seeds: the training envs start from the run seed; validation (best-model choice and the
learning curves, turnpike logged on the same seeds) uses seeds ``1000 + i``; the comparison uses
the held-out test seeds ``10000 + i`` (`agent_envs.training.defaults.DEFAULT_TEST_SEEDS`). Costs
are minus the episode return, i.e. the paper's discrete cost functional.

Train on one, evaluate on another: a setting with ``eval_env_kwargs`` (the paper preset's
``em-to-serb``) evaluates on its evaluation env; ``--eval-env-kwargs '{"integrator": "serb"}'``
evaluates every policy also on that modified env, e.g. policies trained with Euler-Maruyama
(``--env-kwargs '{"integrator": "em"}'``) evaluated with SERB.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from agent_envs.training.commands.experiment import (
    LEARNER,
    ExperimentOptions,
    GridArguments,
    Trial,
    build_trials,
    check_envs,
    select,
)
from agent_envs.training.commands.interface_references import CENTRE_LAW, fair_baseline
from agent_envs.training.commands.learner_runs import budget, evaluation_spec, train_from_dict
from agent_envs.training.commands.presets import OPTIMUM_POLICIES, PRESETS, Learner, get_preset
from agent_envs.training.config import command_line, json_field, option_field
from agent_envs.training.defaults import (
    BASELINE_POLICIES,
    GYM_ENV_ID,
    PETTINGZOO_ENV_ID,
    parse_env_kwargs,
)
from agent_envs.validation import MAX_SEED, check_int


@dataclass
class CompareConfig(GridArguments):
    """Options of `agent-envs compare` (one field = one option): the shared experiment options
    (`GridArguments`) and compare's own."""

    preset: str = option_field("quick", "the experiment setting", choices=tuple(PRESETS))
    setting: str | None = option_field(
        None,
        "the preset's env setting to run (default: its main one; "
        + "; ".join(f"{k}: {','.join(s.name for s in p.settings)}" for k, p in PRESETS.items())
        + ")",
    )
    out: str | None = option_field(None, "output directory (default compare-{preset})")
    seed: int | None = option_field(
        None, "training seed of every learner (default: the preset's first training seed)"
    )
    eval_env_kwargs: dict = json_field(
        "JSON object: also evaluate every policy on the env with these kwargs "
        'changed (train on one, evaluate on another), e.g. \'{"integrator": "serb"}\''
    )
    retrain: bool = option_field(
        False, "train anew even when a finished run of the same setting exists"
    )
    progress_bar: bool = option_field(True, "progress bars")
    verbose: int = option_field(0, "SB3 verbosity")
    torch_threads: int = option_field(1, "torch threads (1 is fastest for these small networks)")
    optimum: str | None = option_field(
        None,
        "comma-separated optimal-control references evaluated with the baselines (optimal = "
        "open-loop optimum, the V of the 'gap to optimal' column; mpc = receding horizon); '' "
        "for none (default: the preset's). Seconds per episode at N = 10; at the paper's "
        "N = 100 an optimal episode takes tens of seconds and mpc far longer",
    )

    def __post_init__(self) -> None:
        super().__post_init__()
        self.eval_env_kwargs = parse_env_kwargs(self.eval_env_kwargs, "--eval-env-kwargs")
        get_preset(self.preset).setting(self.setting)  # ValueError naming --preset / --setting
        if self.seed is not None:
            check_int("--seed", self.seed, 0, MAX_SEED)
        if self.optimum is not None and not isinstance(self.optimum, str):
            raise TypeError(f"--optimum must be a comma-separated string, got {self.optimum!r}")
        wanted = self.optimum_policies
        if any(p not in OPTIMUM_POLICIES for p in wanted) or len(set(wanted)) != len(wanted):
            raise ValueError(
                f"--optimum takes distinct names among {', '.join(OPTIMUM_POLICIES)} "
                f"(or '' for none), comma-separated; got {self.optimum!r}"
            )
        self.options()  # ValueError naming --learners, --timesteps-scale, --test-episodes, ...

    def validate(self, trials: list[Trial] | None = None) -> CompareConfig:
        """Check everything before the first learner trains; returns self.

        The output folder, every selected learner's training configuration (hyperparameters,
        seed, torch threads, ...; built by the experiment builder, or `trials` when the caller
        built them already), and the env with ``--env-kwargs`` and with ``--eval-env-kwargs``
        (both are built once).
        """
        from agent_envs.training.learners.environments import env_description
        from agent_envs.training.storage import check_output_dir

        check_output_dir(self.out_dir, "--out")
        trials = self.trials() if trials is None else trials
        check_envs(trials)
        env_kwargs = trials[0].eval_env_kwargs
        if self.eval_env_kwargs:
            env_description(GYM_ENV_ID, {**env_kwargs, **self.eval_env_kwargs}, "--eval-env-kwargs")
        return self

    @property
    def optimum_policies(self) -> list[str]:
        """The optimal-control references to evaluate (default: the preset's)."""
        if self.optimum is None:
            return [p for p in get_preset(self.preset).references if p in OPTIMUM_POLICIES]
        return [p.strip() for p in self.optimum.split(",") if p.strip()]

    @property
    def out_dir(self) -> Path:
        return Path(self.out or f"compare-{self.preset}")

    def options(self) -> ExperimentOptions:
        """The experiment builder's options: one seed, one setting, the references asked for."""
        preset = get_preset(self.preset)
        setting = preset.setting(self.setting)
        references = [
            r for r in preset.references if r not in OPTIMUM_POLICIES
        ] + self.optimum_policies
        options = self.experiment_options(
            seeds=(preset.seeds[0] if self.seed is None else self.seed,),
            settings=(setting.name,),
            references=tuple(references),
            run_names=False,
            progress_bar=self.progress_bar,
            verbose=self.verbose,
            torch_threads=self.torch_threads,
        )
        options.check(preset)
        if options.learners is not None:  # only the setting's learners
            select(
                setting.learners or [lr.name for lr in preset.learners],
                options.learners,
                "--learners",
            )
        return options

    def trials(self) -> list[Trial]:
        """The runs of this comparison (the experiment builder's), every TrainConfig checked."""
        return build_trials(get_preset(self.preset), self.options(), self.out_dir / "runs")

    def selected_learners(self, trials: list[Trial] | None = None) -> list[Learner]:
        """The preset's learners that `trials` (default: this config's) train."""
        by_name = {lr.name: lr for lr in get_preset(self.preset).learners}
        trials = self.trials() if trials is None else trials
        return [by_name[t.policy] for t in trials if t.kind == LEARNER]

    def command(self) -> str:
        """The `agent-envs compare` command line of this config (non-default options only)."""
        return command_line("compare", self)


# ------------------------------------------------------------------------------------ training


def evaluate_all(
    policies: dict[str, Any], env_kwargs: dict[str, Any], seeds: list[int], out_dir: Path, progress
):
    from agent_envs.training.commands.evaluate import evaluate_policies

    return evaluate_policies(
        policies,
        env_id=GYM_ENV_ID,
        env_kwargs=env_kwargs,
        seeds=seeds,
        progress=progress,
        out_dir=out_dir,
    )


def per_agent_table(run_dir: Path, env_kwargs: dict[str, Any], seeds: list[int]):
    """Per-agent costs of a parameter-shared policy on the PettingZoo env (a DataFrame row)."""
    import gymnasium as gym
    import pandas as pd

    import agent_envs  # noqa: F401
    from agent_envs.training.learners.checkpoints import best_model_path
    from agent_envs.training.learners.multiagent import evaluate_per_agent
    from agent_envs.training.learners.policies import load_sb3_policy

    env = gym.make(GYM_ENV_ID, **env_kwargs)
    try:
        policy, _ = load_sb3_policy(best_model_path(run_dir), env)
    finally:
        env.close()
    inner = getattr(policy, "policy", policy)  # PerAgentPolicy -> the per-agent policy
    # the per-agent layout the policy was trained on (read by the loader from the run's
    # env.json); each agent's own reward (its own cost)
    agent_kwargs = {**env_kwargs, "observation": policy.layout, "agent_reward": "own"}
    costs = evaluate_per_agent(inner, agent_kwargs, seeds)  # (S, N)
    swarm = costs.sum(axis=1)
    per_agent_mean = costs.mean(axis=0)
    row = {
        "seeds": len(seeds),
        "swarm cost (sum over agents), mean": float(swarm.mean()),
        "agent cost, mean": float(per_agent_mean.mean()),
        "agent cost, lowest agent": float(per_agent_mean.min()),
        "agent cost, highest agent": float(per_agent_mean.max()),
    }
    return pd.DataFrame([row]), costs


def plot_learning_curves(runs: dict[str, Path], references: dict[str, float], path: Path) -> None:
    """Validation cost against swarm steps and wall time, one line per learner (log scale)."""
    from matplotlib.figure import Figure

    from agent_envs.training.learners.callbacks import read_learning_curve

    fig = Figure(figsize=(11, 4.2))
    axes = fig.subplots(1, 2, sharey=True)
    for i, (name, run_dir) in enumerate(runs.items()):
        rows = read_learning_curve(run_dir / "learning_curve.csv")
        if not rows:
            continue
        env = json.loads((run_dir / "env.json").read_text())
        trained_on = json.loads((run_dir / "summary.json").read_text())["env_id"]
        per_step = env["n_agents"] if trained_on == PETTINGZOO_ENV_ID else 1
        steps = np.array([r["timesteps"] for r in rows]) / per_step
        wall = np.array([r["wall_time_s"] for r in rows])
        mean = np.array([r["cost_mean"] for r in rows])
        ci = np.nan_to_num(np.array([r["cost_ci95"] for r in rows]))
        for ax, x in zip(axes, (steps, wall), strict=True):
            ax.plot(x, mean, "o-", color=f"C{i}", label=name, ms=3)
            ax.fill_between(x, np.maximum(mean - ci, 1e-12), mean + ci, color=f"C{i}", alpha=0.15)
    styles = {"turnpike": "k--", "proportional": "k-.", "zero": "k:"}
    for name, value in references.items():
        for ax in axes:
            ax.axhline(value, linestyle=styles.get(name, "k-")[1:], color="k", lw=1, label=name)
    axes[0].set_xlabel("swarm steps (env transitions)")
    axes[1].set_xlabel("training wall time [s]")
    axes[0].set_ylabel("validation cost (mean over validation seeds)")
    for ax in axes:
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    unique = dict(zip(labels, handles, strict=True))
    axes[1].legend(unique.values(), unique.keys(), fontsize=8, loc="best")
    fig.suptitle("Learning curves on the validation seeds (band: 95% CI)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def _reference_costs(run_dirs: dict[str, Path]) -> dict[str, float]:
    """The baselines' costs the eval callback logged on the validation seeds (same for all)."""
    from agent_envs.training.learners.callbacks import read_learning_curve

    for run_dir in run_dirs.values():
        rows = read_learning_curve(run_dir / "learning_curve.csv")
        if rows:
            return {
                name: float(rows[-1][f"{name}_cost"])
                for name in BASELINE_POLICIES
                if f"{name}_cost" in rows[-1]
            }
    return {}


def training_table(run_dirs: dict[str, Path], learners: dict[str, Learner]):
    import pandas as pd

    from agent_envs.training.learners.callbacks import read_learning_curve

    rows = []
    for name, run_dir in run_dirs.items():
        summary = json.loads((run_dir / "summary.json").read_text())
        curve = read_learning_curve(run_dir / "learning_curve.csv")
        best = min(curve, key=lambda r: r["cost_mean"]) if curve else None
        rows.append(
            {
                "learner": name,
                "algorithm": learners[name].description or learners[name].algo,
                "env": learners[name].env_id,
                "training timesteps": summary["timesteps"],
                "swarm steps": summary["swarm_steps"],
                "training wall time [s]": summary["train_wall_time_s"],
                "best validation cost": None if best is None else round(best["cost_mean"], 4),
                "at timesteps": None if best is None else best["timesteps"],
                "run": run_dir.name,
            }
        )
    return pd.DataFrame(rows)


def _train_all(config: CompareConfig, trials: list[Trial]) -> dict[str, Path]:
    """Train (or reuse / resume) every learner trial; {learner name: run directory}."""
    learners = [t for t in trials if t.kind == LEARNER]
    run_dirs: dict[str, Path] = {}
    for i, trial in enumerate(learners, 1):
        train = trial.train
        print(
            f"[{i}/{len(learners)}] training {trial.policy} ({train['algo']} on "
            f"{train['env_id']}, {budget(train)})",
            flush=True,
        )
        run_dirs[trial.policy] = train_from_dict(train, retrain=config.retrain)
    return run_dirs


def _evaluate(config: CompareConfig, trials: list[Trial], run_dirs: dict[str, Path]):
    """The held-out evaluation of the references and the learners' best models; and, with
    ``--eval-env-kwargs``, the same on the modified env (else None)."""
    references = [t for t in trials if t.kind != LEARNER]
    env_kwargs, seeds = trials[0].eval_env_kwargs, list(trials[0].test_seeds)
    print(f"evaluating {len(references) + len(run_dirs)} policies on {len(seeds)} seeds")
    policies: dict[str, Any] = {t.policy: t.reference_spec() for t in references}
    policies.update({name: evaluation_spec(d) for name, d in run_dirs.items()})
    out = config.out_dir
    results = evaluate_all(policies, env_kwargs, seeds, out / "evaluation", config.progress_bar)
    if not config.eval_env_kwargs:
        return results, None
    transfer_kwargs = {**env_kwargs, **config.eval_env_kwargs}
    print(f"evaluating on the modified env {transfer_kwargs}")
    transfer = evaluate_all(
        policies, transfer_kwargs, seeds, out / "evaluation_transfer", config.progress_bar
    )
    return results, transfer


def _proportional_section(results):
    from agent_envs.training.results.report import ReportSection, display_table
    from agent_envs.training.results.tables import summarize

    return ReportSection(
        "Against the proportional controller",
        text=(
            "The same test episodes with the proportional controller beta (xbar - x_k) as "
            "the reference: the turnpike controller without the cancellation of the "
            "interaction drift. When it is cheaper than the turnpike controller (see the "
            "first table), it is the stronger yardstick for the learners."
        ),
        table=display_table(summarize(results.episodes, "proportional"), "proportional"),
    )


def fair_baseline_table(episodes, learners: dict[str, Learner]):
    """One row per learner: its fair baseline (`interface_references.fair_baseline`, the best
    simple law in its interface) next to it, and the proportional controller, on the same test
    seeds. Ratios are paired: the mean over seeds of cost / the other's cost on that seed."""
    import pandas as pd

    costs = episodes.pivot(index="seed", columns="policy", values="total_cost")
    rows = []
    for name, learner in learners.items():
        fair = fair_baseline(learner.env_kwargs)
        row = {"learner": name, "interface": _interface_label(learner.env_kwargs)}
        row.update({"fair baseline": fair, "learner cost": costs[name].mean()})
        if fair in costs:
            row["fair baseline cost"] = costs[fair].mean()
            row["ratio to fair baseline"] = (costs[name] / costs[fair]).mean()
        if "proportional" in costs:
            row["ratio to proportional"] = (costs[name] / costs["proportional"]).mean()
        rows.append(row)
    return pd.DataFrame(rows).round(4)


def _interface_label(env_kwargs: dict[str, Any]) -> str:
    keys = ("observation", "action_basis", "agent_reward")
    return ", ".join(f"{k}={env_kwargs[k]}" for k in keys if k in env_kwargs) or "default"


def _fair_baseline_section(results, learners: dict[str, Learner]):
    from agent_envs.training.results.report import ReportSection

    return ReportSection(
        "Against each learner's fair baseline",
        text=(
            "Each learner next to the best simple law its own interface can express: where "
            "the learner sees the swarm's centre or sends one common control (the summary, "
            "modes and swarm observations), the proportional law on the centre "
            f"({CENTRE_LAW}: u = 12 (xbar - c) for every agent, evaluated through that "
            "interface); where its rows hold no centre (apg's features, the local row), the "
            "proportional controller. Same test "
            "seeds; ratios are the mean over seeds of the paired cost ratio (below 1: the "
            "learner is cheaper)."
        ),
        table=fair_baseline_table(results.episodes, learners),
    )


def _learning_curve_section(run_dirs: dict[str, Path], learners: dict[str, Learner], out: Path):
    from agent_envs.training.results.report import ReportSection

    curves_png = out / "learning_curves.png"
    plot_learning_curves(run_dirs, _reference_costs(run_dirs), curves_png)
    return ReportSection(
        "Learning curves",
        text=(
            "Validation cost of each learner during training on the validation seeds "
            "1000..1000+k (one fresh episode per seed at every evaluation; the best model "
            "on these seeds is the one compared above, on the held-out test seeds). The "
            "reference controllers' costs on the same validation seeds are the black lines "
            "(turnpike dashed, proportional dash-dotted, zero dotted). "
            "Swarm steps are env transitions: the parameter-shared learner gets N agent "
            "samples per swarm step."
        ),
        table=training_table(run_dirs, learners),
        images=[curves_png],
        captions=["validation cost against swarm steps (left) and wall time (right)"],
    )


def _per_agent_section(name: str, table):
    from agent_envs.training.results.report import ReportSection

    return ReportSection(
        f"Per-agent costs of {name} (PettingZoo env)",
        text=(
            f"The parameter-shared policy {name} run on `{PETTINGZOO_ENV_ID}` itself, one "
            "action per agent from its own observation, on the test seeds. Agent k's "
            "cost is minus its summed reward tau/N sum_n (|x_k - xbar|^2 + gamma "
            "|u_k|^2); the agents' costs add up to the swarm's cost."
        ),
        table=table,
    )


def _transfer_section(config: CompareConfig, env_kwargs: dict[str, Any], transfer):
    from agent_envs.training.results.report import ReportSection, display_table
    from agent_envs.training.results.tables import summarize

    return ReportSection(
        f"Evaluated on another env: {config.eval_env_kwargs}",
        text=(
            f"The same policies (trained with env kwargs {env_kwargs}) evaluated with "
            f"{config.eval_env_kwargs} changed, same test seeds."
        ),
        table=display_table(summarize(transfer.episodes), "turnpike"),
    )


def _run_section(config: CompareConfig, env_kwargs, learners, total: float, training: float):
    from agent_envs.training.results.report import ReportSection

    preset = get_preset(config.preset)
    return ReportSection(
        "Run",
        text=(
            f"Preset {config.preset}: {preset.description}; env kwargs used: {env_kwargs}. "
            "Wall time of this command "
            f"{total:.0f} s in all, {training:.0f} s of it training (a reused "
            "finished run costs no training time; see the table above for each run's own "
            "training time). "
            f"Learners: {', '.join(f'{lr.name} = {lr.description}' for lr in learners)}."
        ),
        code=config.command(),
    )


def compare(config: CompareConfig) -> dict[str, Any]:
    """Run the whole comparison; returns paths and the summary table (see module docstring)."""
    from agent_envs.training.commands.train import torch_threads

    started = time.perf_counter()
    trials = config.trials()  # the grid is built (every TrainConfig validated) once
    config.validate(trials)
    preset = get_preset(config.preset)
    learners = {lr.name: lr for lr in config.selected_learners(trials)}
    out = config.out_dir
    (out / "runs").mkdir(parents=True, exist_ok=True)
    env_kwargs = trials[0].eval_env_kwargs
    print(f"compare --preset {config.preset}: {preset.description}")
    print(f"env kwargs {env_kwargs}; output {out}")
    with torch_threads(config.torch_threads):
        run_dirs = _train_all(config, trials)
        train_done = time.perf_counter()
        results, transfer = _evaluate(config, trials, run_dirs)
        shared = [n for n in run_dirs if learners[n].env_id == PETTINGZOO_ENV_ID]
        seeds = list(trials[0].test_seeds)
        agent_tables = {name: per_agent_table(run_dirs[name], env_kwargs, seeds) for name in shared}
    sections = [
        _proportional_section(results),
        _fair_baseline_section(results, learners),
        _learning_curve_section(run_dirs, learners, out),
        *(_per_agent_section(name, table) for name, (table, _) in agent_tables.items()),
    ]
    if transfer is not None:
        sections.append(_transfer_section(config, env_kwargs, transfer))
    sections.append(
        _run_section(
            config,
            env_kwargs,
            learners.values(),
            time.perf_counter() - started,
            train_done - started,
        )
    )
    timing = (started, train_done)
    return _finish(config, results, sections, run_dirs, (env_kwargs, seeds), timing)


def _finish(config, results, sections, run_dirs, setting, timing) -> dict[str, Any]:
    """Write the report and ``comparison.json`` (`setting`: env kwargs and test seeds;
    `timing`: the start and end of training); print the table."""
    from agent_envs.training.results.report import build_report, display_table
    from agent_envs.training.results.tables import summarize
    from agent_envs.training.storage import write_json_atomic

    out = config.out_dir
    paths = build_report(
        results,
        out / "report",
        title=f"Learned policies vs the turnpike controller ({config.preset} preset)",
        extra_sections=sections,
        command=config.command(),
    )
    summary = summarize(results.episodes)
    table = display_table(summary, "turnpike")
    started, train_done = timing
    total = time.perf_counter() - started
    env_kwargs, seeds = setting
    record = {
        "preset": config.preset,
        "command": config.command(),
        "env_kwargs": env_kwargs,
        "seeds": seeds,
        "runs": {name: str(d) for name, d in run_dirs.items()},
        "wall_time_s": round(total, 1),
        "training_wall_time_s": round(train_done - started, 1),
        "summary": json.loads(summary.to_json(orient="records")),
    }
    write_json_atomic(out / "comparison.json", record)
    print(table.to_string(index=False))
    print(f"report: {paths['markdown']} and {paths['html']} ({total:.0f} s in all)")
    return {"paths": paths, "summary": summary, "table": table, "record": record, "runs": run_dirs}


# --------------------------------------------------------------------------------------- CLI


__all__ = ["CompareConfig", "compare", "fair_baseline_table"]
