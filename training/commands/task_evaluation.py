"""`agent-envs evaluate --task ID` and `agent-envs tasks`: score policies on a benchmark task.

    agent-envs tasks                                                  # id, what it tests, N, V
    agent-envs evaluate --task agent_envs/StiffSwarm-v0 -p proportional \\
        -p mine=my_agent:policy --out scores-mine                     # core install suffices

Scoring needs the core install only (numpy; the references are shipped data): baseline names
and ``module:attribute`` policies are resolved here without torch; saved SB3 models and apg
runs need the ``train`` extra (`agent_envs.training.learners.policies.resolve_policy`). Each policy
is scored by `agent_envs.tasks.score` on the task's test seeds. A policy that fails (it raises,
returns a wrong shape or dtype, NaN or inf) is reported in one line naming the policy, the seed
and the step; the other policies are still scored and written, and the command exits 2.

Written to OUT (atomically): ``scores.csv`` (task, policy, seed, cost, value, zero_cost, gap,
score, diverged; one row per policy and test seed, the shipped references included with
``kind = reference``), ``summary.csv`` and ``scores.md`` (per policy: mean score with its 95%
t-interval, IQM with its bootstrap interval, mean gap, mean cost) and ``meta.json`` (the task,
the policies' specs, the interface, the references' hash). ``--report`` (train extra) also runs
the usual evaluation of `agent-envs evaluate` on the same seeds into OUT/report.
"""

from __future__ import annotations

import csv
import importlib
import io
import json
import os
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from agent_envs.tasks import (
    TASK_LIST,
    PolicyError,
    TaskReferences,
    TaskScore,
    get_task,
    load_references,
    score,
)
from agent_envs.tasks.scores import Summary
from agent_envs.training.commands.evaluate_options import (
    EvaluateConfig,
    is_object_spec,
    object_spec_parts,
)
from agent_envs.training.config import option_field
from agent_envs.training.storage import write_json_atomic, write_text_atomic

#: Columns of scores.csv.
SCORE_COLUMNS = (
    "task",
    "policy",
    "kind",
    "seed",
    "cost",
    "value",
    "zero_cost",
    "gap",
    "score",
    "diverged",
)


def import_policy(spec: str) -> tuple[Any, bool]:
    """(the object, per_agent) named by ``[per-agent:]module:attribute``.

    The module is imported from the working directory or PYTHONPATH: the user named it, so it
    is within the trust model (docs/trust-model.md). Raises ValueError naming the spec when the
    module does not import, the attribute is missing, or the object is neither callable nor
    has ``predict``.
    """
    module_name, attribute, per_agent = object_spec_parts(spec)
    cwd = os.getcwd()
    if cwd not in sys.path:
        sys.path.insert(0, cwd)
    try:
        obj: Any = importlib.import_module(module_name)
    except Exception as exc:  # any failure of the user's module is their input's error
        raise ValueError(
            f"--policy {spec}: module {module_name!r} does not import ({type(exc).__name__}: {exc})"
        ) from None
    for part in attribute.split("."):
        if not hasattr(obj, part):
            raise ValueError(f"--policy {spec}: {module_name!r} has no attribute {attribute!r}")
        obj = getattr(obj, part)
    if not (callable(obj) or hasattr(obj, "predict")):
        raise ValueError(
            f"--policy {spec}: {attribute!r} is a {type(obj).__name__}, neither callable nor an "
            "object with predict(obs, ...)"
        )
    return obj, per_agent


class RowwisePolicy:
    """A policy written for one observation, run on the batches `evaluate_policies` passes.

    The training layer's rollouts call ``predict`` the way SB3 calls it on a VecEnv, with a
    batch of observations; `agent_envs.tasks.score` passes one observation, as a user's loop
    does. This adapter calls the policy once per row, so it sees what scoring gave it.
    """

    def __init__(self, policy: Any) -> None:
        self.policy = policy

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        obs = np.asarray(observation)
        if obs.ndim == 1:
            return self.policy.predict(obs, state, episode_start, deterministic)
        actions = [
            np.asarray(self.policy.predict(row, state, episode_start, deterministic)[0])
            for row in obs
        ]
        return np.stack(actions), state


def rowwise_factory(obj: Any) -> Any:
    """A factory ``env -> policy`` for `evaluate_policies` from a user's object (`as_policy`)."""
    from agent_envs.tasks.scoring import as_policy

    def make(env: Any) -> RowwisePolicy:
        return RowwisePolicy(as_policy(obj, env))

    return make


def _factory(spec: str, baseline_kwargs: Mapping[str, Any]) -> Any:
    """A policy factory ``env -> policy`` for a baseline name, a saved model or an apg run."""
    from agent_envs.training.learners.policies import resolve_policy

    def make(env: Any) -> Any:
        return resolve_policy(spec, env, baseline_kwargs)[0]

    return make


def reference_scores(references: TaskReferences) -> list[TaskScore]:
    """The shipped references as scores (their costs are data: nothing is run)."""
    task = references.task
    return [
        TaskScore(
            task,
            name,
            list(references.seeds),
            [float(c) for c in references.costs[name]],
            [False] * len(references.seeds),
            references,
        )
        for name in task.references
    ]


def _summary_row(result: TaskScore, kind: str) -> dict[str, Any]:
    summary = result.summary()
    s: Summary = summary["score"]
    g: Summary = summary["gap"]
    return {
        "task": result.task.id,
        "policy": result.policy,
        "kind": kind,
        "seeds": s.n_seeds,
        "score_mean": s.mean,
        "score_low": s.mean_low,
        "score_high": s.mean_high,
        "score_iqm": s.iqm,
        "score_iqm_low": s.iqm_low,
        "score_iqm_high": s.iqm_high,
        "gap_mean": g.mean,
        "gap_low": g.mean_low,
        "gap_high": g.mean_high,
        "cost_mean": summary["cost"].mean,
        "diverged": int(np.sum(result.diverged)),
    }


def csv_text(rows: list[dict[str, Any]], columns: tuple[str, ...] | list[str]) -> str:
    """`rows` as CSV text with `columns` (floats written with repr: every digit kept)."""
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=list(columns), lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in row.items()})
    return out.getvalue()


def markdown_table(rows: list[dict[str, Any]]) -> str:
    """The summary rows as a Markdown table (score, IQM, gap, cost)."""
    lines = [
        "| policy | kind | score [95% CI] | IQM [95% CI] | gap to V [95% CI] | mean cost |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['policy']} | {r['kind']} | {r['score_mean']:.2f} [{r['score_low']:.2f}, "
            f"{r['score_high']:.2f}] | {r['score_iqm']:.2f} [{r['score_iqm_low']:.2f}, "
            f"{r['score_iqm_high']:.2f}] | {100 * r['gap_mean']:+.2f}% "
            f"[{100 * r['gap_low']:+.2f}%, {100 * r['gap_high']:+.2f}%] | {r['cost_mean']:.5g} |"
        )
    return "\n".join(lines)


def write_scores(
    out: Path,
    results: list[TaskScore],
    references: TaskReferences,
    meta: Mapping[str, Any],
) -> list[dict[str, Any]]:
    """Write scores.csv, summary.csv, scores.md and meta.json; return the summary rows."""
    out.mkdir(parents=True, exist_ok=True)
    refs = reference_scores(references)
    episodes = [dict(row, kind="reference") for r in refs for row in r.rows()]
    episodes += [dict(row, kind="policy") for r in results for row in r.rows()]
    summary = [_summary_row(r, "policy") for r in results]
    summary += [_summary_row(r, "reference") for r in refs]
    write_text_atomic(out / "scores.csv", csv_text(episodes, SCORE_COLUMNS))
    write_text_atomic(out / "summary.csv", csv_text(summary, list(summary[0])))
    task = references.task
    text = (
        f"# Scores on {task.id}\n\n{task.tests}.\n\nV = {task.yardstick} (per test seed); "
        "score = 100 (J_zero - J) / (J_zero - V), gap = (J - V) / V; intervals over the "
        f"{len(references.seeds)} test seeds.\n\n{markdown_table(summary)}\n"
    )
    write_text_atomic(out / "scores.md", text)
    write_json_atomic(out / "meta.json", dict(meta))
    return summary


def evaluate_task(config: EvaluateConfig) -> int:
    """`agent-envs evaluate --task`: score every --policy on the task (module docstring)."""
    from agent_envs.training.storage import check_output_dir

    check_output_dir(config.out)
    task = get_task(config.task)
    references = load_references(task)
    baseline_kwargs = {"beta": config.beta, "delta": config.delta}
    specs = config.policy_specs()
    resolved: dict[str, tuple[Any, bool]] = {}
    for name, spec in specs.items():  # every policy resolved before the first episode
        resolved[name] = (
            import_policy(spec)
            if is_object_spec(spec)
            else (
                _factory(spec, baseline_kwargs),
                False,
            )
        )
    config.check_models()
    results: list[TaskScore] = []
    failed: list[str] = []
    for name, (policy, per_agent) in resolved.items():
        try:
            result = score(
                policy,
                task,
                name=name,
                per_agent=per_agent,
                interface=config.env_kwargs,
                seeds=config.seeds,
                references=references,
            )
        except PolicyError as exc:
            print(f"agent-envs evaluate: error: {' '.join(str(exc).split())}", file=sys.stderr)
            failed.append(name)
            continue
        results.append(result)
    meta = {
        "task": task.id,
        "policies": specs,
        "failed": failed,
        "interface": dict(config.env_kwargs),
        "seeds": list(config.seeds),
        "references_sha256": references.sha256,
        "yardstick": task.yardstick,
    }
    summary = write_scores(config.out, results, references, meta)
    print(markdown_table(summary))
    print(f"scores written to {config.out}/scores.csv, summary.csv, scores.md")
    if config.report and results:
        _report(config, task.id, [r.policy for r in results], specs, resolved)
    return 2 if failed else 0


def _report(
    config: EvaluateConfig,
    task_id: str,
    names: list[str],
    specs: Mapping[str, str],
    resolved: Mapping[str, tuple[Any, bool]],
) -> None:
    """The usual evaluation report on the task env (train extra); per-agent policies left out."""
    from agent_envs.training.commands.evaluate import evaluate_policies
    from agent_envs.training.results.report import build_report

    policies: dict[str, Any] = {}
    for name in names:
        obj, per_agent = resolved[name]
        if per_agent:
            print(f"{name}: per-agent policy, not in the report (its scores are)")
            continue
        policies[name] = rowwise_factory(obj) if is_object_spec(specs[name]) else specs[name]
    task = get_task(task_id)
    results = evaluate_policies(
        policies,
        task_id,
        dict(config.env_kwargs),
        list(config.seeds),
        baseline_kwargs={"beta": config.beta, "delta": config.delta},
        progress=config.progress,
        out_dir=config.out / "evaluation",
    )
    paths = build_report([results], config.out / "report", title=f"Policies on {task.id}")
    print(f"report: {paths['markdown']} and {paths['html']}")


def task_table(with_values: bool = True) -> list[dict[str, Any]]:
    """One row per task: id, what it tests, N, d, m, yardstick, mean V (when shipped)."""
    from agent_envs.tasks.references import has_references

    rows = []
    for task in TASK_LIST:
        row: dict[str, Any] = {
            "id": task.id,
            "N": task.n_agents,
            "d": task.dim,
            "m": task.n_steps,
            "paths": int(task.env_kwargs.get("n_paths", 1)),
            "yardstick": task.yardstick,
            "V": None,
            "tests": task.tests,
        }
        if with_values and has_references(task):
            row["V"] = float(np.mean(load_references(task).yardstick))
        rows.append(row)
    return rows


def print_tasks() -> None:
    """`agent-envs tasks`: the task list."""
    for row in task_table():
        value = "not shipped" if row["V"] is None else f"{row['V']:.5g}"
        print(
            f"{row['id']}  N={row['N']} d={row['d']} m={row['m']} paths={row['paths']}  "
            f"V ({row['yardstick']}) = {value}\n    {row['tests']}"
        )


@dataclass(frozen=True, kw_only=True)
class TasksConfig:
    """The options of `agent-envs tasks` (list, regenerate, verify the benchmark's tasks)."""

    regenerate: tuple[str, ...] | None = option_field(
        None,
        "recompute the reference data of these task ids (all: 'all') and write them with their "
        "hash into the package's data folder (or --data-dir); needs the train extra (torch)",
        nargs="+",
        metavar="ID",
    )
    verify: tuple[str, ...] | None = option_field(
        None,
        "re-solve the solved references of these task ids ('all') on their first "
        "--verify-seeds test seeds and compare with the shipped costs (relative 1e-5)",
        nargs="+",
        metavar="ID",
    )
    verify_seeds: int = option_field(2, "test seeds per task that --verify re-solves")
    workers: int = option_field(1, "worker processes of --regenerate (one seed each)")
    work_dir: Path = option_field(
        Path(".task-work"), "per-seed records of --regenerate (an interrupted run resumes)"
    )
    data_dir: Path | None = option_field(
        None, "write regenerated files here instead of the installed package's data folder"
    )
    json: bool = option_field(False, "list the tasks as JSON", action="store_true")

    def __post_init__(self) -> None:
        from agent_envs.validation import check_int

        for option in ("regenerate", "verify"):
            ids = getattr(self, option)
            if ids is None:
                continue
            ids = tuple(t.id for t in TASK_LIST) if tuple(ids) == ("all",) else tuple(ids)
            object.__setattr__(self, option, tuple(get_task(i).id for i in ids))
        from agent_envs.training.storage import check_output_dir

        check_int("--verify-seeds", self.verify_seeds, 1, 20)
        check_int("--workers", self.workers, 1, 256)
        object.__setattr__(self, "work_dir", check_output_dir(self.work_dir, "--work-dir"))
        if self.data_dir is not None:
            object.__setattr__(self, "data_dir", check_output_dir(self.data_dir, "--data-dir"))


def run_tasks_command(config: TasksConfig) -> int:
    """`agent-envs tasks`: list; or regenerate / verify reference data."""
    if not config.regenerate and not config.verify:
        if config.json:
            print(json.dumps(task_table(), indent=1))
        else:
            print_tasks()
        return 0
    from agent_envs.training.commands import task_references

    for task_id in config.regenerate or ():
        path = task_references.regenerate(
            task_id, config.work_dir, workers=config.workers, out_dir=config.data_dir
        )
        print(f"wrote {path} and its hash")
    bad = 0
    for task_id in config.verify or ():
        for row in task_references.verify(task_id, config.verify_seeds):
            mark = "ok" if row["ok"] else "MISMATCH"
            print(
                f"{task_id} seed {row['seed']} {row['reference']}: shipped {row['shipped']:.10g}, "
                f"now {row['now']:.10g}, relative difference {row['relative_difference']:.2e} "
                f"{mark}"
            )
            bad += not row["ok"]
    return 1 if bad else 0


def reference_table_markdown() -> str:
    """The shipped references of every task as one Markdown table (docs/tasks.md shows it;
    tests/test_tasks.py recomputes it from the package data)."""
    lines = [
        "| task | N, d, m, paths | V: mean | optimal | MPC | proportional | turnpike | zero "
        "| lower bound / V |",
        "|---|---|---|---|---|---|---|---|---|",
    ]

    def cell(refs: TaskReferences, name: str) -> str:
        if name not in refs.costs or not np.all(np.isfinite(refs.costs[name])):
            return "-"
        s = float(np.mean(100 * (refs.zero - refs.costs[name]) / (refs.zero - refs.yardstick)))
        return f"{refs.mean(name):.4g} ({s:.1f})"

    for task in TASK_LIST:
        refs = load_references(task)
        ratio = "-"
        if "lower_bound" in refs.costs and task.yardstick != "lower_bound":
            r = refs.costs["lower_bound"] / refs.yardstick
            ratio = f"{r.min():.3f}-{r.max():.3f}"
        shape = f"{task.n_agents}, {task.dim}, {task.n_steps}, {task.env_kwargs.get('n_paths', 1)}"
        lines.append(
            f"| `{task.id}` | {shape} | {task.yardstick}: {float(np.mean(refs.yardstick)):.4g} | "
            f"{cell(refs, 'optimal')} | "
            f"{cell(refs, 'mpc')} | {cell(refs, 'proportional')} | {cell(refs, 'turnpike')} | "
            f"{cell(refs, 'zero')} | {ratio} |"
        )
    return "\n".join(lines)


__all__ = [
    "SCORE_COLUMNS",
    "TasksConfig",
    "csv_text",
    "evaluate_task",
    "import_policy",
    "markdown_table",
    "print_tasks",
    "reference_scores",
    "reference_table_markdown",
    "run_tasks_command",
    "task_table",
    "write_scores",
]
