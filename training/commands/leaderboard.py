"""`agent-envs leaderboard`: every benchmark task x every policy we ship, scored on its test seeds.

    agent-envs leaderboard --out leaderboard                       # all tasks, 3 training seeds
    agent-envs leaderboard --out leaderboard --tasks agent_envs/NoisySwarm-v0   # one part
    agent-envs leaderboard --out leaderboard --table docs/leaderboard-table.md  # table only

Units of work. For each trainable task (every task but `LargeSwarm`) and each learner of
`LEARNERS` and each training seed, one *unit*: train the learner on the task's env (the paper
preset's hyperparameters and budgets, `agent_envs.training.commands.presets`; its validation during
training on the task's validation seeds 1000..), then score its best model on the task's 20 test
seeds with `agent_envs.tasks.score`. `LargeSwarm` (N = 10^4) trains nothing: its units score the
policies trained on `StiffSwarm` (the same dynamics at N = 100), a transfer to 100 times more
agents. The references (the optimum, MPC, the lower bound, proportional, turnpike, zero) are
the task's shipped data: nothing is re-solved.

Resumable in parts: each unit writes ``OUT/units/TASK__LEARNER__SEED.csv`` (its per-episode
scores) when it is done, and a unit whose file exists is skipped; training itself reuses a
finished run and resumes an interrupted one (`learner_runs.train_from_dict`). ``--tasks`` runs
part of the grid; ``--workers`` runs units in parallel processes (one torch and BLAS thread
each). When every unit of the selected tasks is done, ``OUT/episodes.csv`` (every unit and the
references, one row per policy x training seed x test seed) and ``OUT/leaderboard.md`` are
written; ``--table`` rebuilds the table from an episodes file alone (no training).
"""

from __future__ import annotations

import csv
import json
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from agent_envs.tasks import TASK_LIST, TaskScore, TaskSpec, get_task, load_references, score
from agent_envs.tasks.scores import summarize
from agent_envs.training.commands.interface_references import (
    CENTRE_LAW,
    INTERFACE_REFERENCES,
    CentreLaw,
)
from agent_envs.training.commands.task_evaluation import SCORE_COLUMNS, csv_text, reference_scores
from agent_envs.training.config import option_field
from agent_envs.training.storage import write_text_atomic

#: The learners of the leaderboard, by their name in the paper preset: `apg` (a per-agent
#: feedback law trained through SERB), SAC with the summary observation and one common
#: control, the best SB3 learner of the paper study (docs/results.md), and the two
#: parameter-shared PPO learners of the PettingZoo env: `ppo-shared` (swarm observation, team
#: reward) and `ppo-local` (local observation: own offset and K nearest neighbours, team reward).
LEARNERS = ("apg", "sac", "ppo-shared", "ppo-local")
#: BenchMARL's MAPPO and IPPO (`agent_envs.training.learners.benchmarl_runs`): opt-in
#: (``--learners mappo ippo``), since they need the `marl` extra, which the leaderboard does not.
MARL_LEARNERS = ("mappo", "ippo")
#: Training seeds of every learner.
TRAINING_SEEDS = (0, 1, 2)
#: Tasks whose learners are not trained there but transferred from another task.
TRANSFERS = {"agent_envs/LargeSwarm-v0": "agent_envs/StiffSwarm-v0"}
#: The tasks a learner is run on where not every task: the parameter-shared learners are run on
#: the paper's two stiffness regimes, and transferred from the stiff one to N = 10^4; the
#: BenchMARL learners on the two regimes only.
LEARNER_TASKS = {
    **{
        name: (
            "agent_envs/StiffSwarm-v0",
            "agent_envs/WeakCouplingSwarm-v0",
            "agent_envs/LargeSwarm-v0",
        )
        for name in ("ppo-shared", "ppo-local")
    },
    **{
        name: ("agent_envs/StiffSwarm-v0", "agent_envs/WeakCouplingSwarm-v0")
        for name in MARL_LEARNERS
    },
}


def runs_on(learner: str, task_id: str) -> bool:
    """Whether the leaderboard runs `learner` on `task_id` (`LEARNER_TASKS`; else every task)."""
    return task_id in LEARNER_TASKS.get(learner, (task_id,))


#: The best simple law in SAC's interface (its fair baseline, docs/env-options.md): the
#: proportional law on the swarm's centre (`interface_references.CentreLaw`), scored live
CENTRE_LAW_INTERFACE = INTERFACE_REFERENCES[CENTRE_LAW]
#: Columns of a unit's file and of episodes.csv: scores.csv's with the training seed.
EPISODE_COLUMNS = (*SCORE_COLUMNS[:3], "training_seed", *SCORE_COLUMNS[3:])


@dataclass(frozen=True)
class Unit:
    """One learner x training seed on one task (trained there, or transferred from `source`)."""

    task: str
    learner: str
    seed: int
    source: str

    @property
    def stem(self) -> str:
        return f"{get_task(self.task).file_stem}__{self.learner}__{self.seed}"


def task_preset(task: TaskSpec, timesteps_scale: float = 1.0) -> Any:
    """A `Preset` that trains the leaderboard's learners on `task` (paper hyperparameters)."""
    from agent_envs.training.commands.presets import PRESETS, EnvSetting, Preset

    paper = PRESETS["paper"]
    learners = tuple(
        lr for lr in paper.learners if lr.name in LEARNERS and runs_on(lr.name, task.id)
    )
    return Preset(
        name=f"task-{task.file_stem}",
        description=f"the learners of the leaderboard on {task.id}",
        env_kwargs=dict(task.env_kwargs),
        settings=(EnvSetting(task.file_stem, task.tests),),
        learners=learners,
        seeds=TRAINING_SEEDS,
        references=(),
        test_episodes=len(task.test_seeds),
        validation_episodes=paper.validation_episodes,
        evaluations=paper.evaluations,
        vec_env=paper.vec_env,
    )


def units(
    tasks: Sequence[str],
    seeds: Sequence[int] = TRAINING_SEEDS,
    learners: Sequence[str] = LEARNERS,
) -> list[Unit]:
    """Every unit of `tasks` x `learners` x `seeds` that the leaderboard runs (`runs_on`;
    transfers after the units they read)."""
    out = []
    for task_id in tasks:
        source = TRANSFERS.get(task_id, task_id)
        out += [
            Unit(task_id, lr, s, source) for lr in learners if runs_on(lr, task_id) for s in seeds
        ]
    return sorted(out, key=lambda u: u.task != u.source)


def _train(unit: Unit, out: Path, timesteps_scale: float) -> Path:
    """Train (or reuse) the unit's learner on its source task; the run directory."""
    from agent_envs.training.commands.experiment import ExperimentOptions, learner_config
    from agent_envs.training.commands.learner_runs import train_from_dict
    from agent_envs.training.config import TrainConfig

    source = get_task(unit.source)
    preset = task_preset(source)
    learner = next(lr for lr in preset.learners if lr.name == unit.learner)
    options = ExperimentOptions(timesteps_scale=timesteps_scale, torch_threads=1)
    config = learner_config(
        preset, preset.settings[0], learner, unit.seed, options, out / "runs" / source.file_stem
    )
    if isinstance(config, TrainConfig):  # validated on the task's validation seeds 1000..
        config = config.to_dict()
    return train_from_dict(config)


def _csv(rows: list[dict[str, Any]]) -> str:
    return csv_text(rows, EPISODE_COLUMNS)


def episode_rows(result: TaskScore, kind: str, training_seed: int | str = "") -> list[dict]:
    """A `TaskScore`'s per-seed rows as episodes.csv rows (`EPISODE_COLUMNS`)."""
    return [
        {
            **{k: row[k] for k in EPISODE_COLUMNS if k in row},
            "kind": kind,
            "training_seed": training_seed,
        }
        for row in result.rows()
    ]


def _write_unit(path: Path, rows: list[dict[str, Any]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, _csv(rows))


def _score_sb3_or_apg(unit: Unit, out: Path, timesteps_scale: float) -> TaskScore:
    from agent_envs.training.commands.learner_runs import evaluation_spec
    from agent_envs.training.learners.policies import resolve_policy

    run_dir = _train(unit, out, timesteps_scale)
    spec = evaluation_spec(run_dir)

    def make(env: Any) -> Any:
        return resolve_policy(spec, env)[0]

    return score(make, unit.task, name=unit.learner)


def _score_marl(unit: Unit, out: Path, timesteps_scale: float) -> TaskScore:
    """A BenchMARL unit: `benchmarl_runs.train_run` (its default budget x `timesteps_scale`,
    validated on the task's validation seeds) in OUT/runs, then its best policy, actions x s,
    scored per agent on the task's PettingZoo twin with the run's interface."""
    from agent_envs.training.learners.benchmarl_runs import (
        MarlRun,
        default_frames,
        policy_factory,
        train_run,
    )

    frames = max(1, round(default_frames(unit.learner) * timesteps_scale))
    run = MarlRun(unit.source, unit.learner, unit.seed, frames=frames)
    folder = train_run(run, out / "runs")
    make = policy_factory(folder)
    return score(make, unit.task, name=unit.learner, per_agent=True, interface=run.interface)


def run_unit(unit: Unit, out: Path, timesteps_scale: float = 1.0) -> Path:
    """Train and score one unit; write and return its file."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        import torch

        torch.set_num_threads(1)
        train_and_score = _score_marl if unit.learner in MARL_LEARNERS else _score_sb3_or_apg
        result = train_and_score(unit, out, timesteps_scale)
    path = out / "units" / f"{unit.stem}.csv"
    _write_unit(path, episode_rows(result, "learner", unit.seed))
    return path


def centre_law(env: Any) -> CentreLaw:
    """`CENTRE_LAW` for `env` (summary observation, common action): u = beta (xbar - c),
    beta = 12, as an action u / max_control clipped to [-1, 1] (a factory ``env -> policy``)."""
    inner = env.unwrapped
    return CentreLaw(inner.params.dim, float(inner.max_control))


def centre_law_rows(task_id: str, out: Path) -> list[dict[str, Any]]:
    """`CENTRE_LAW`'s episodes on the task (cached in OUT/units)."""

    path = out / "units" / f"{get_task(task_id).file_stem}__{CENTRE_LAW}.csv"
    if not path.is_file():
        result = score(centre_law, task_id, name=CENTRE_LAW, interface=CENTRE_LAW_INTERFACE)
        _write_unit(path, episode_rows(result, "law"))
    return read_episodes(path)


def reference_rows(task_id: str) -> list[dict[str, Any]]:
    """The task's shipped references as episode rows (training seed empty)."""
    results = reference_scores(load_references(task_id))
    return [row for result in results for row in episode_rows(result, "reference")]


def read_episodes(path: Path) -> list[dict[str, Any]]:
    """Rows of an episodes file, numbers parsed."""
    rows = []
    with open(path, newline="") as handle:
        for row in csv.DictReader(handle):
            for key in ("cost", "value", "zero_cost", "gap", "score"):
                row[key] = float(row[key])
            row["seed"] = int(row["seed"])
            row["diverged"] = row["diverged"] == "True"
            rows.append(row)
    return rows


#: Display names of the policies in the table.
POLICY_LABELS = {
    "apg": "apg (per-agent feedback, trained through SERB)",
    "sac": "sac (summary observation, common control)",
    "ppo-shared": "ppo-shared (parameter-shared PPO: swarm observation, team reward)",
    "ppo-local": "ppo-local (parameter-shared PPO: own offset and 6 nearest neighbours)",
    "mappo": "mappo (BenchMARL MAPPO: swarm observation, team reward, centralised critic)",
    "ippo": "ippo (BenchMARL IPPO: swarm observation, team reward, per-agent critic)",
    "optimal": "optimal (open-loop plan, 20 paths)",
    "mpc": "mpc (re-solve every step)",
    "lower_bound": "lower bound (certified, not a policy)",
    "proportional": "proportional (12 (xbar - x_k), per agent)",
    CENTRE_LAW: "proportional on the centre (12 (xbar - c), one control for all: the fair "
    "baseline of SAC and ppo-shared)",
    "turnpike": "turnpike (the paper's controller)",
    "zero": "zero",
}


def leaderboard_table(rows: list[dict[str, Any]], tasks: Sequence[str] | None = None) -> str:
    """The leaderboard in Markdown from episode rows: one section per task, one row per policy.

    Score and gap: mean over the test seeds with a 95% t-interval (a learner: of the per-seed
    mean over its training seeds), IQM over every episode; a learner's mean score and mean gap
    per training seed are listed too.
    """
    out = []
    order = {name: i for i, name in enumerate(POLICY_LABELS)}
    for task in TASK_LIST:
        if tasks is not None and task.id not in tasks:
            continue
        task_rows = [r for r in rows if r["task"] == task.id]
        if not task_rows:
            continue
        trained = TRANSFERS.get(task.id)
        note = f" (learners trained on {trained}, N = 100)" if trained else ""
        out.append(f"### {task.id}{note}\n\n{task.tests}. V = {task.yardstick}.\n")
        out.append(
            "| policy | score [95% CI] | IQM | gap to V [95% CI] | score by training seed "
            "| gap by training seed | mean cost |\n|---|---|---|---|---|---|---|"
        )
        names = sorted({r["policy"] for r in task_rows}, key=lambda n: (order.get(n, 99), n))
        for name in names:
            mine = [r for r in task_rows if r["policy"] == name]
            runs = sorted({r["training_seed"] for r in mine})
            seeds = sorted({r["seed"] for r in mine})
            cell = {(r["training_seed"], r["seed"]): r for r in mine}
            scores = np.array([[cell[(t, s)]["score"] for s in seeds] for t in runs])
            gaps = np.array([[cell[(t, s)]["gap"] for s in seeds] for t in runs])
            costs = np.array([[cell[(t, s)]["cost"] for s in seeds] for t in runs])
            s, g = summarize(scores), summarize(gaps)
            has_runs = runs != [""]
            by_seed = ", ".join(f"{v:.2f}" for v in scores.mean(axis=1)) if has_runs else "-"
            gap_by_seed = (
                ", ".join(f"{100 * v:+.2f}%" for v in gaps.mean(axis=1)) if has_runs else "-"
            )
            out.append(
                f"| {POLICY_LABELS.get(name, name)} | {s.mean:.2f} [{s.mean_low:.2f}, "
                f"{s.mean_high:.2f}] | {s.iqm:.2f} | {100 * g.mean:+.2f}% "
                f"[{100 * g.mean_low:+.2f}%, {100 * g.mean_high:+.2f}%] | {by_seed} "
                f"| {gap_by_seed} | {costs.mean():.5g} |"
            )
        out.append("")
    return "\n".join(out)


def collect(out: Path, tasks: Sequence[str]) -> list[dict[str, Any]]:
    """Every row of `tasks`: the units' files that exist and the shipped references."""
    rows: list[dict[str, Any]] = []
    for task_id in tasks:
        rows += reference_rows(task_id)
        rows += centre_law_rows(task_id, out)
    for path in sorted((out / "units").glob("*.csv")):
        if path.stem.endswith(CENTRE_LAW):
            continue
        unit_rows = read_episodes(path)
        rows += [r for r in unit_rows if r["task"] in tasks]
    return rows


@dataclass(frozen=True, kw_only=True)
class LeaderboardConfig:
    """The options of `agent-envs leaderboard`."""

    out: Path = option_field(Path("leaderboard"), "output folder (units, runs, episodes.csv)")
    tasks: tuple[str, ...] | None = option_field(
        None, "task ids to run (default: all)", nargs="+", metavar="ID"
    )
    seeds: tuple[int, ...] = option_field(TRAINING_SEEDS, "training seeds of every learner")
    learners: tuple[str, ...] = option_field(
        LEARNERS,
        "learners to run (default: all but the opt-in mappo and ippo, which need the marl extra)",
        nargs="+",
        metavar="NAME",
    )
    workers: int = option_field(1, "units run in parallel processes")
    timesteps_scale: float = option_field(1.0, "multiply every training budget (a smoke run: 0.01)")
    table: Path | None = option_field(
        None,
        "write the Markdown table of OUT/episodes.csv to this file and stop (no training)",
    )

    def __post_init__(self) -> None:
        from agent_envs.training.storage import check_output_dir
        from agent_envs.validation import check_int, check_positive

        object.__setattr__(self, "out", check_output_dir(self.out, "--out"))
        if self.table is not None:
            object.__setattr__(self, "table", Path(self.table))
            check_output_dir(self.table.parent, "--table")
        ids = self.tasks or tuple(t.id for t in TASK_LIST)
        object.__setattr__(self, "tasks", tuple(get_task(i).id for i in ids))
        for task_id in self.tasks:
            source = TRANSFERS.get(task_id)
            if source and source not in self.tasks:
                object.__setattr__(self, "tasks", (source, *self.tasks))
        object.__setattr__(self, "seeds", tuple(int(s) for s in self.seeds))
        object.__setattr__(self, "learners", tuple(self.learners))
        known = (*LEARNERS, *MARL_LEARNERS)
        for name in self.learners:
            if name not in known:
                raise ValueError(f"--learners must be among {', '.join(known)}; got {name!r}")
        check_marl_extra(self.learners)
        for s in self.seeds:
            check_int("--seeds", s, 0, 999)
        check_int("--workers", self.workers, 1, 64)
        check_positive("--timesteps-scale", self.timesteps_scale)


def check_marl_extra(learners: Sequence[str]) -> None:
    """ValueError naming the `marl` extra when a BenchMARL learner is asked for without it."""
    import importlib.util

    marl = [name for name in learners if name in MARL_LEARNERS]
    if marl and importlib.util.find_spec("benchmarl") is None:
        raise ValueError(
            f"--learners {' '.join(marl)} needs BenchMARL, the `marl` extra: "
            "pip install -c constraints.txt -e '.[marl]'"
        )


def run_leaderboard(config: LeaderboardConfig) -> int:
    """`agent-envs leaderboard` (module docstring)."""
    episodes = config.out / "episodes.csv"
    if config.table is not None:
        if not episodes.is_file():
            raise ValueError(f"--table: {episodes} does not exist; run the leaderboard first")
        write_text_atomic(config.table, leaderboard_table(read_episodes(episodes)) + "\n")
        print(f"wrote {config.table}")
        return 0
    todo = [
        u
        for u in units(config.tasks, config.seeds, config.learners)
        if not (config.out / "units" / f"{u.stem}.csv").is_file()
    ]
    total = len(units(config.tasks, config.seeds, config.learners))
    print(f"{len(todo)} units to run ({total - len(todo)} done)")
    direct = [u for u in todo if u.task == u.source]
    transfer = [u for u in todo if u.task != u.source]
    for batch in (direct, transfer):
        if not batch:
            continue
        with ProcessPoolExecutor(max_workers=config.workers) as pool:
            futures = {
                pool.submit(run_unit, u, config.out, config.timesteps_scale): u for u in batch
            }
            for future in as_completed(futures):
                print(f"done: {future.result()}", flush=True)
    rows = collect(config.out, config.tasks)
    write_text_atomic(episodes, _csv(rows))
    table = leaderboard_table(rows)
    write_text_atomic(config.out / "leaderboard.md", table + "\n")
    print(table)
    meta = {
        "tasks": list(config.tasks),
        "seeds": list(config.seeds),
        "learners": list(config.learners),
        "timesteps_scale": config.timesteps_scale,
    }
    write_text_atomic(config.out / "leaderboard.json", json.dumps(meta, indent=1) + "\n")
    return 0


__all__ = [
    "EPISODE_COLUMNS",
    "LEARNERS",
    "LEARNER_TASKS",
    "MARL_LEARNERS",
    "TRAINING_SEEDS",
    "TRANSFERS",
    "LeaderboardConfig",
    "Unit",
    "collect",
    "leaderboard_table",
    "read_episodes",
    "run_leaderboard",
    "run_unit",
    "runs_on",
    "task_preset",
    "units",
]
