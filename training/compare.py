"""Train learners, then compare them with the reference controllers (`agent-envs compare`).

    agent-envs compare --preset quick            # a few minutes on 2 CPU cores
    agent-envs compare --preset paper            # N = 100, stiff, SERB, m = 50; much longer

Steps: (1) train every learner of the preset (`agent_envs.training.train.train`; a finished run
of the same configuration in ``OUT/runs`` is reused, an interrupted one resumed from its last
checkpoint); (2) evaluate the learners' best models (chosen on the validation seeds) and the
turnpike, proportional and zero controllers on the same held-out test seeds
(`agent_envs.training.evaluate`), plus the parameter-shared policy agent by agent on the
PettingZoo env; (3) write the report of `agent_envs.training.report` with the learning curves
added (``OUT/report/report.md`` and ``.html``).

Seeds: the training envs start from the run seed; validation (best-model choice and the
learning curves, turnpike logged on the same seeds) uses seeds ``1000 + i``; the comparison uses
the held-out test seeds ``10000 + i`` (`agent_envs.training.defaults.DEFAULT_TEST_SEEDS`). Costs
are minus the episode return, i.e. the paper's discrete cost functional.

Train on one, evaluate on another: ``--eval-env-kwargs '{"integrator": "serb"}'`` evaluates
every policy also on that modified env, e.g. policies trained with Euler-Maruyama
(``--env-kwargs '{"integrator": "em"}'``) evaluated with SERB.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from agent_envs.training.config import Learner, TrainConfig, command_line, option_field
from agent_envs.training.defaults import (
    BASELINE_POLICIES,
    DEFAULT_TEST_SEED,
    FEEDBACK_BASELINES,
    GYM_ENV_ID,
    PETTINGZOO_ENV_ID,
    parse_env_kwargs,
)


@dataclass(frozen=True)
class Preset:
    """A comparison setting: env kwargs, learners, evaluation sizes."""

    name: str
    description: str
    env_kwargs: dict[str, Any]
    learners: tuple[Learner, ...]
    validation_episodes: int = 10
    evaluations: int = 8
    test_episodes: int = 20


def _sac_target_entropy(env_kwargs: dict[str, Any], per_dim: float = -5.0) -> float:
    n = int(env_kwargs.get("n_agents", 100))
    d = int(env_kwargs.get("dim", 1))
    return per_dim * n * d


_QUICK_ENV = {"n_agents": 10, "n_steps": 20}


def _default_learners(
    env_kwargs: dict[str, Any], *, ppo: int, sac: int, ppo_shared: int
) -> tuple[Learner, ...]:
    """PPO and SAC on the Gymnasium env and parameter-shared PPO on the PettingZoo env,
    with the given timestep budgets (the shared learner counts agent-steps)."""
    return (
        Learner("ppo", "ppo", GYM_ENV_ID, ppo, description="PPO, one controller"),
        Learner(
            "sac",
            "sac",
            GYM_ENV_ID,
            sac,
            {"target_entropy": _sac_target_entropy(env_kwargs)},
            description="SAC, one controller",
        ),
        Learner(
            "ppo-shared",
            "ppo",
            PETTINGZOO_ENV_ID,
            ppo_shared,
            description="parameter-shared PPO, one agent per swarm member (SuperSuit)",
        ),
    )


PRESETS: dict[str, Preset] = {
    "quick": Preset(
        name="quick",
        description=(
            "N = 10 agents, m = 20 steps, otherwise the paper's stiff setting (eps = 0.05, "
            "alpha = 0.1, sigma = 0.01, T = 1, target 0.7, SERB); a few minutes on 2 CPU cores"
        ),
        env_kwargs=_QUICK_ENV,
        learners=_default_learners(_QUICK_ENV, ppo=40_000, sac=20_000, ppo_shared=150_000),
    ),
    "paper": Preset(
        name="paper",
        description=(
            "the paper's setting: N = 100 agents, m = 50 steps, eps = 0.05, alpha = 0.1, "
            "sigma = 0.01, T = 1, target 0.7, SERB (the env defaults)"
        ),
        env_kwargs={},
        learners=_default_learners({}, ppo=400_000, sac=60_000, ppo_shared=3_000_000),
        validation_episodes=10,
        evaluations=10,
        test_episodes=20,
    ),
}


#: Largest --timesteps-scale (the paper preset's budgets times this stay far below 10**12).
MAX_TIMESTEPS_SCALE = 1000.0


#: the optimal-control references (`agent_envs.baselines.optimal_controllers`)
OPTIMUM_POLICIES = ("optimal", "mpc")


@dataclass
class CompareConfig:
    """Options of `agent-envs compare` (one field = one option)."""

    preset: str = option_field("quick", "comparison setting", choices=tuple(PRESETS))
    out: str | None = option_field(None, "output directory (default compare-{preset})")
    learners: str | None = option_field(
        None,
        "comma-separated learners to train (default: all of the preset: "
        + "; ".join(f"{k}: {','.join(x.name for x in p.learners)}" for k, p in PRESETS.items())
        + ")",
    )
    seed: int = option_field(0, "training seed of every learner")
    env_kwargs: dict = field(
        default_factory=dict,
        metadata={
            "help": "JSON object of env kwargs overriding the preset's, for training and "
            'evaluation, e.g. \'{"integrator": "em"}\''
        },
    )
    eval_env_kwargs: dict = field(
        default_factory=dict,
        metadata={
            "help": "JSON object: also evaluate every policy on the env with these kwargs "
            'changed (train on one, evaluate on another), e.g. \'{"integrator": "serb"}\''
        },
    )
    timesteps_scale: float = option_field(
        1.0, "multiply every learner's training timesteps (e.g. 0.1 for a smoke run)"
    )
    test_episodes: int | None = option_field(
        None, "held-out test episodes per policy (seeds 10000 + i; default: the preset's)"
    )
    retrain: bool = option_field(
        False, "train anew even when a finished run of the same setting exists"
    )
    progress_bar: bool = option_field(True, "progress bars")
    verbose: int = option_field(0, "SB3 verbosity")
    torch_threads: int = option_field(1, "torch threads (1 is fastest for these small networks)")
    optimum: str = option_field(
        ",".join(OPTIMUM_POLICIES),
        "comma-separated optimal-control references evaluated with the baselines (optimal = "
        "open-loop optimum, the V of the 'gap to optimal' column; mpc = receding horizon); '' "
        "for none. Seconds per episode at N = 10; at the paper's N = 100 an optimal episode "
        "takes tens of seconds and mpc far longer",
    )

    def __post_init__(self) -> None:
        self.env_kwargs = parse_env_kwargs(self.env_kwargs)
        self.eval_env_kwargs = parse_env_kwargs(self.eval_env_kwargs, "--eval-env-kwargs")
        if self.preset not in PRESETS:
            raise ValueError(f"--preset must be one of {', '.join(PRESETS)}; got {self.preset!r}")
        if not (
            isinstance(self.timesteps_scale, (int, float))
            and not isinstance(self.timesteps_scale, bool)
            and math.isfinite(self.timesteps_scale)
            and 0 < self.timesteps_scale <= MAX_TIMESTEPS_SCALE
        ):
            raise ValueError(
                f"--timesteps-scale must be a number in (0, {MAX_TIMESTEPS_SCALE}], "
                f"got {self.timesteps_scale!r}"
            )
        if not isinstance(self.optimum, str):
            raise TypeError(f"--optimum must be a comma-separated string, got {self.optimum!r}")
        unknown = [p for p in self.optimum_policies if p not in OPTIMUM_POLICIES]
        if unknown or len(set(self.optimum_policies)) != len(self.optimum_policies):
            raise ValueError(
                f"--optimum takes distinct names among {', '.join(OPTIMUM_POLICIES)} "
                f"(or '' for none), comma-separated; got {self.optimum!r}"
            )
        if self.test_episodes is not None and not 2 <= self.test_episodes <= 100_000:
            raise ValueError(
                f"--test-episodes must be an integer in [2, 100000], got {self.test_episodes}"
            )

    def validate(self) -> CompareConfig:
        """Check everything before the first learner trains; returns self.

        The output folder, every selected learner's training configuration (hyperparameters,
        seed, torch threads, ...), and the env with ``--env-kwargs`` and with
        ``--eval-env-kwargs`` (both are built once).
        """
        from agent_envs.training.environments import env_description
        from agent_envs.training.storage import check_output_dir

        check_output_dir(self.out_dir, "--out")
        learners = self.selected_learners()
        runs_dir = self.out_dir / "runs"
        for learner in learners:
            learner_config(self, learner, runs_dir)  # validates the TrainConfig
        env_kwargs = {**PRESETS[self.preset].env_kwargs, **self.env_kwargs}
        env_description(GYM_ENV_ID, env_kwargs)
        if self.eval_env_kwargs:
            env_description(GYM_ENV_ID, {**env_kwargs, **self.eval_env_kwargs}, "--eval-env-kwargs")
        return self

    @property
    def optimum_policies(self) -> list[str]:
        """The optimal-control references to evaluate (names in `OPTIMUM_POLICIES`)."""
        return [p.strip() for p in self.optimum.split(",") if p.strip()]

    @property
    def out_dir(self) -> Path:
        return Path(self.out or f"compare-{self.preset}")

    def selected_learners(self) -> list[Learner]:
        preset = PRESETS[self.preset]
        if self.learners is None:
            return list(preset.learners)
        by_name = {learner.name: learner for learner in preset.learners}
        names = [n.strip() for n in self.learners.split(",") if n.strip()]
        unknown = [n for n in names if n not in by_name]
        if unknown or not names or len(set(names)) != len(names):
            raise ValueError(
                f"--learners must list distinct learners of the {self.preset} preset "
                f"({', '.join(by_name)}), comma-separated; got {self.learners!r}"
            )
        return [by_name[n] for n in names]

    def command(self) -> str:
        """The `agent-envs compare` command line of this config (non-default options only)."""
        return command_line("compare", self)


# ------------------------------------------------------------------------------------ training


def scaled_timesteps(learner: Learner, scale: float) -> int:
    return max(round(learner.timesteps * scale), 1)


def learner_config(config: CompareConfig, learner: Learner, runs_dir: Path) -> TrainConfig:
    """The TrainConfig of one learner in this comparison."""
    preset = PRESETS[config.preset]
    timesteps = scaled_timesteps(learner, config.timesteps_scale)
    return TrainConfig(
        algo=learner.algo,
        env_id=learner.env_id,
        env_kwargs={**preset.env_kwargs, **config.env_kwargs},
        timesteps=timesteps,
        seed=config.seed,
        out=str(runs_dir),
        n_envs=learner.n_envs,
        hyperparams=dict(learner.hyperparams),
        eval_freq=max(timesteps // preset.evaluations, 1),
        eval_episodes=preset.validation_episodes,
        checkpoint_freq=max(timesteps // 4, 1),
        progress_bar=config.progress_bar,
        verbose=config.verbose,
        torch_threads=config.torch_threads,
    ).validate()


#: A run is reused or resumed only when all of these match, the budget included: a run resumed
#: with another budget would keep its old evaluation and checkpoint schedule.
_SAME_RUN_FIELDS = (
    "algo",
    "env_id",
    "env_kwargs",
    "seed",
    "n_envs",
    "hyperparams",
    "eval_seed",
    "timesteps",
)


def find_run(runs_dir: Path, wanted: TrainConfig) -> tuple[Path, bool] | None:
    """The newest run in `runs_dir` with the same setting: (run dir, finished with enough steps)."""
    candidates = []
    for cfg_path in runs_dir.glob("*/config.json"):
        try:
            saved = json.loads(cfg_path.read_text())
        except (OSError, json.JSONDecodeError):
            continue
        if any(saved.get(k) != getattr(wanted, k) for k in _SAME_RUN_FIELDS):
            continue
        run_dir = cfg_path.parent
        summary_path = run_dir / "summary.json"
        finished = False
        if summary_path.exists():
            summary = json.loads(summary_path.read_text())
            finished = int(summary.get("timesteps", 0)) >= wanted.timesteps
        candidates.append((cfg_path.stat().st_mtime, run_dir, finished))
    if not candidates:
        return None
    _, run_dir, finished = max(candidates)
    return run_dir, finished


def train_learner(config: CompareConfig, learner: Learner, runs_dir: Path) -> Path:
    """Train (or reuse / resume) one learner; return its run directory."""
    from agent_envs.training.train import train

    wanted = learner_config(config, learner, runs_dir)
    existing = None if config.retrain else find_run(runs_dir, wanted)
    if existing is not None:
        run_dir, finished = existing
        if finished:
            print(f"  reusing finished run {run_dir}")
            return run_dir
        print(f"  resuming {run_dir} from its last checkpoint")
        return train(replace(wanted, resume=str(run_dir)))
    return train(wanted)


# ---------------------------------------------------------------------------------- evaluation


def best_model_path(run_dir: Path) -> Path:
    """The model to compare: the best on the validation seeds, else the final one."""
    from agent_envs.training.checkpoints import BEST_MODEL, FINAL_MODEL

    best = run_dir / BEST_MODEL
    return best if best.exists() else run_dir / FINAL_MODEL


def evaluate_all(
    policies: dict[str, Any], env_kwargs: dict[str, Any], seeds: list[int], out_dir: Path, progress
):
    from agent_envs.training.evaluate import evaluate_policies

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
    from agent_envs.training.multiagent import evaluate_per_agent
    from agent_envs.training.policies import load_sb3_policy

    env = gym.make(GYM_ENV_ID, **env_kwargs)
    try:
        policy, _ = load_sb3_policy(best_model_path(run_dir), env)
    finally:
        env.close()
    inner = getattr(policy, "policy", policy)  # PerAgentPolicy -> the per-agent policy
    costs = evaluate_per_agent(inner, env_kwargs, seeds)  # (S, N)
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

    from agent_envs.training.callbacks import read_learning_curve

    fig = Figure(figsize=(11, 4.2))
    axes = fig.subplots(1, 2, sharey=True)
    for i, (name, run_dir) in enumerate(runs.items()):
        rows = read_learning_curve(run_dir / "learning_curve.csv")
        if not rows:
            continue
        env = json.loads((run_dir / "env.json").read_text())
        config = json.loads((run_dir / "config.json").read_text())
        per_step = env["n_agents"] if config["env_id"] == PETTINGZOO_ENV_ID else 1
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
    from agent_envs.training.callbacks import read_learning_curve

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

    from agent_envs.training.callbacks import read_learning_curve

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
                "SB3 timesteps": summary["timesteps"],
                "swarm steps": summary["swarm_steps"],
                "training wall time [s]": summary["train_wall_time_s"],
                "best validation cost": None if best is None else round(best["cost_mean"], 4),
                "at timesteps": None if best is None else best["timesteps"],
                "run": run_dir.name,
            }
        )
    return pd.DataFrame(rows)


def compare(config: CompareConfig) -> dict[str, Any]:
    """Run the whole comparison; returns paths and the summary table (see module docstring)."""
    from agent_envs.training.report import ReportSection, build_report, display_table
    from agent_envs.training.results import summarize
    from agent_envs.training.storage import write_json_atomic
    from agent_envs.training.train import torch_threads

    started = time.perf_counter()
    config.validate()
    preset = PRESETS[config.preset]
    learners = config.selected_learners()
    out = config.out_dir
    runs_dir = out / "runs"
    runs_dir.mkdir(parents=True, exist_ok=True)
    env_kwargs = {**preset.env_kwargs, **config.env_kwargs}
    n_test = config.test_episodes or preset.test_episodes
    seeds = list(range(DEFAULT_TEST_SEED, DEFAULT_TEST_SEED + n_test))
    print(f"compare --preset {config.preset}: {preset.description}")
    print(f"env kwargs {env_kwargs}; output {out}")

    run_dirs: dict[str, Path] = {}
    with torch_threads(config.torch_threads):
        for i, learner in enumerate(learners, 1):
            steps = scaled_timesteps(learner, config.timesteps_scale)
            print(
                f"[{i}/{len(learners)}] training {learner.name} ({learner.algo} on "
                f"{learner.env_id}, {steps} timesteps)",
                flush=True,
            )
            run_dirs[learner.name] = train_learner(config, learner, runs_dir)
        train_done = time.perf_counter()

        references = [*FEEDBACK_BASELINES, *config.optimum_policies]
        print(f"evaluating {len(references) + len(run_dirs)} policies on {n_test} seeds")
        policies: dict[str, Any] = {name: name for name in references}
        policies.update({name: str(best_model_path(d)) for name, d in run_dirs.items()})
        results = evaluate_all(policies, env_kwargs, seeds, out / "evaluation", config.progress_bar)
        transfer = None
        if config.eval_env_kwargs:
            transfer_kwargs = {**env_kwargs, **config.eval_env_kwargs}
            print(f"evaluating on the modified env {transfer_kwargs}")
            transfer = evaluate_all(
                policies, transfer_kwargs, seeds, out / "evaluation_transfer", config.progress_bar
            )
        shared = [
            n for n, lr in zip(run_dirs, learners, strict=True) if lr.env_id == PETTINGZOO_ENV_ID
        ]
        agent_tables = {name: per_agent_table(run_dirs[name], env_kwargs, seeds) for name in shared}

    sections = []
    sections.append(
        ReportSection(
            "Against the proportional controller",
            text=(
                "The same test episodes with the proportional controller beta (xbar - x_k) as "
                "the reference: the turnpike controller without the cancellation of the "
                "interaction drift. When it is cheaper than the turnpike controller (see the "
                "first table), it is the stronger yardstick for the learners."
            ),
            table=display_table(summarize(results.episodes, "proportional"), "proportional"),
        )
    )
    curves_png = out / "learning_curves.png"
    plot_learning_curves(run_dirs, _reference_costs(run_dirs), curves_png)
    sections.append(
        ReportSection(
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
            table=training_table(run_dirs, {lr.name: lr for lr in learners}),
            images=[curves_png],
            captions=["validation cost against swarm steps (left) and wall time (right)"],
        )
    )
    for name, (table, _) in agent_tables.items():
        sections.append(
            ReportSection(
                f"Per-agent costs of {name} (PettingZoo env)",
                text=(
                    f"The parameter-shared policy {name} run on `{PETTINGZOO_ENV_ID}` itself, one "
                    "action per agent from its own observation, on the test seeds. Agent k's "
                    "cost is minus its summed reward tau/N sum_n (|x_k - xbar|^2 + gamma "
                    "|u_k|^2); the agents' costs add up to the swarm's cost."
                ),
                table=table,
            )
        )
    if transfer is not None:
        tsum = summarize(transfer.episodes)
        sections.append(
            ReportSection(
                f"Evaluated on another env: {config.eval_env_kwargs}",
                text=(
                    f"The same policies (trained with env kwargs {env_kwargs}) evaluated with "
                    f"{config.eval_env_kwargs} changed, same test seeds."
                ),
                table=display_table(tsum, "turnpike"),
            )
        )
    total = time.perf_counter() - started
    sections.append(
        ReportSection(
            "Run",
            text=(
                f"Preset {config.preset}: {preset.description}; env kwargs used: {env_kwargs}. "
                "Wall time of this command "
                f"{total:.0f} s in all, {train_done - started:.0f} s of it training (a reused "
                "finished run costs no training time; see the table above for each run's own "
                "training time). "
                f"Learners: {', '.join(f'{lr.name} = {lr.description}' for lr in learners)}."
            ),
            code=config.command(),
        )
    )
    paths = build_report(
        results,
        out / "report",
        title=f"Learned policies vs the turnpike controller ({config.preset} preset)",
        extra_sections=sections,
        command=config.command(),
    )
    summary = summarize(results.episodes)
    table = display_table(summary, "turnpike")
    total = time.perf_counter() - started
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


__all__ = ["PRESETS", "CompareConfig", "Learner", "Preset", "compare"]
