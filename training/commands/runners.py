"""What each `agent-envs` subcommand runs: ``run_NAME(config) -> exit code``.

Each runner receives its subcommand's validated options dataclass (or, for `train`, the dict of
the options given), imports the modules of its command only when called (so that `agent-envs
reproduce uncontrolled` does not import torch), checks the output folder before any work, runs
the command and prints its table or summary. `cli.SUBCOMMANDS` names the runner of each.
"""

from __future__ import annotations

import json
import sys
from typing import Any

# ------------------------------------------------------------------------ reproduce (paper)


def run_uncontrolled(config: Any) -> int:
    from agent_envs.training.experiments.uncontrolled import markdown_table, reproduce
    from agent_envs.training.storage import check_output_dir

    check_output_dir(config.out)
    rows = reproduce(config.out, config.n_agents, config.n_paths, config.seed)
    print(markdown_table(rows))
    print(f"wrote {config.out}/results.md, results.json, results.csv and the figures")
    return 0


def run_turnpike(config: Any) -> int:
    from agent_envs.training.storage import check_output_dir

    check_output_dir(config.out)
    import pandas as pd

    from agent_envs.training.experiments.turnpike_controlled import TABLE_COLUMNS, reproduce

    table = reproduce(
        config.out,
        config.seeds,
        modes=config.modes,
        n_agents=config.n_agents,
        n_steps=config.n_steps,
        n_paths=config.n_paths,
        progress=config.progress,
    )
    cols = [c for c in TABLE_COLUMNS if c in table.columns]
    with pd.option_context(
        "display.width", 200, "display.max_columns", 30, "display.float_format", "{:.3g}".format
    ):
        print(table[cols].to_string(index=False))
    print(f"written: {config.out}/results.md, results.csv, results.json and PNGs")
    return 0


def run_turnpike_property(config: Any) -> int:
    import time

    from agent_envs.training.experiments.turnpike_property import reproduce
    from agent_envs.training.storage import check_output_dir

    check_output_dir(config.out)
    start = time.perf_counter()
    reproduce(config.out, config)
    seconds = time.perf_counter() - start
    print(f"wrote {config.out}/turnpike_property.png, .csv, .md ({seconds:.0f} s)")
    return 0


def run_cheap_control_bound(config: Any) -> int:
    import time

    from agent_envs.training.experiments.cheap_control_bound import SUMMARY, markdown, reproduce
    from agent_envs.training.storage import check_output_dir

    check_output_dir(config.out)
    start = time.perf_counter()
    rows, _ = reproduce(config.out, config)
    print(markdown(rows, SUMMARY))
    print((config.out / "cheap_control_bound.md").read_text().split("\n\n", 1)[1], end="")
    seconds = time.perf_counter() - start
    print(
        f"wrote {config.out}/cheap_control_bound.png, .csv, .md and contraction.csv, .md "
        f"({seconds:.0f} s)"
    )
    return 0


# ------------------------------------------------------------------------ evaluate, report


def _print_statistics_sources(meta: dict[str, Any]) -> None:
    """Which VecNormalize statistics each saved model was evaluated with, and why."""
    from agent_envs.training.learners.policies import STATISTICS_SOURCES

    for name, desc in meta["policies"].items():
        if desc.get("kind") == "sb3":
            used = desc.get("vecnormalize")
            source = STATISTICS_SOURCES.get(desc.get("vecnormalize_source"), "")
            print(
                f"{name}: VecNormalize statistics {used} ({source})"
                if used
                else f"{name}: no VecNormalize statistics (observations used as they are)"
            )


def run_evaluate(config: Any) -> int:
    if config.task is not None:  # the benchmark: core install only for callable policies
        from agent_envs.training.commands.task_evaluation import evaluate_task

        return evaluate_task(config)
    from agent_envs.training.storage import check_output_dir

    check_output_dir(config.out)
    config.check_models()  # the file, its algorithm, its statistics (nothing unpickled)
    import pandas as pd

    from agent_envs.training.commands.evaluate import evaluate_policies
    from agent_envs.training.results.report import build_report, display_table
    from agent_envs.training.results.tables import summarize

    policies: dict[str, Any] = dict(config.policy_specs())
    _objects_as_factories(policies)
    # evaluate_policies resolves every policy and makes every env before the first episode
    results = evaluate_policies(
        policies,
        config.env_id,
        config.env_kwargs,
        list(config.seeds),
        reset_options=config.reset_options(),
        baseline_kwargs={"beta": config.beta, "delta": config.delta},
        progress=config.progress,
        out_dir=config.out,
    )
    _print_statistics_sources(results.meta)
    reference = "turnpike" if "turnpike" in policies else None
    table = display_table(summarize(results.episodes, reference), reference)
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        print(table.to_string(index=False))
    print(f"results written to {config.out}")
    if config.report:
        paths = build_report([results], config.out / "report")
        print(f"report: {paths['markdown']} and {paths['html']}")
    return 0


def _objects_as_factories(policies: dict[str, Any]) -> None:
    """``module:attribute`` specs -> factories of `evaluate_policies` (imported here: named)."""
    from agent_envs.training.commands.evaluate_options import is_object_spec
    from agent_envs.training.commands.task_evaluation import import_policy, rowwise_factory

    for name, spec in policies.items():
        if isinstance(spec, str) and is_object_spec(spec):
            policies[name] = rowwise_factory(import_policy(spec)[0])


def run_leaderboard(config: Any) -> int:
    from agent_envs.training.commands.leaderboard import run_leaderboard as leaderboard

    return leaderboard(config)


def run_tables(config: Any) -> int:
    from agent_envs.training.commands.published import run_tables as tables

    return tables(config)


def run_tasks(config: Any) -> int:
    from agent_envs.training.commands.task_evaluation import run_tasks_command

    return run_tasks_command(config)


def run_report(config: Any) -> int:
    from agent_envs.training.storage import check_output_dir

    check_output_dir(config.out)
    import pandas as pd

    from agent_envs.training.results.report import build_report, display_table
    from agent_envs.training.results.tables import (
        DEFAULT_REFERENCE,
        EvaluationResults,
        merge_results,
    )

    loaded = [EvaluationResults.load(path) for path in config.results]
    merged = merge_results(loaded)
    if config.reference is not None and config.reference not in merged.policies:
        raise ValueError(
            f"--reference {config.reference!r} is not an evaluated policy; the results hold "
            f"{', '.join(merged.policies)}"
        )
    reference = config.reference or DEFAULT_REFERENCE
    paths = build_report(
        loaded,
        config.out,
        title=config.title,
        reference=reference,
        seed_index=config.seed_index,
    )
    summary = pd.read_csv(paths["summary"])
    shown = reference if reference in merged.policies else None
    print(display_table(summary, shown).to_string(index=False))
    print(f"report: {paths['markdown']} and {paths['html']}")
    return 0


# ------------------------------------------------------------------- train, compare, sweep


def run_train(options: dict[str, Any]) -> int:
    from agent_envs.training.commands.train import config_from_options, train
    from agent_envs.training.learners.apg_policy import is_apg_run

    if options.get("algo") == "apg" or (
        options.get("resume") and is_apg_run(options["resume"]) and "algo" not in options
    ):
        return run_train_apg(options)
    run_dir = train(config_from_options(options))
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


def run_train_apg(options: dict[str, Any]) -> int:
    """`agent-envs train --algo apg` (and --resume of an apg run): `apg.train_apg`."""
    from agent_envs.training.learners.apg import train_apg
    from agent_envs.training.learners.apg_config import from_train_options

    config, run_dir, resume = from_train_options(options)
    summary = train_apg(config, run_dir, resume=resume)
    print(f"run directory: {run_dir}")
    print(
        f"best validation cost {summary['best_validation_cost']:.4g} after "
        f"{summary['iterations']} iterations, {summary['cpu_time_s']:.0f} s CPU "
        f"({summary['wall_time_s']:.0f} s wall)"
    )
    return 0


def run_compare(config: Any) -> int:
    from agent_envs.training.commands.compare import compare

    try:  # compare() validates every option, the learners' configs and both envs first
        compare(config)
    except KeyboardInterrupt:
        print("\ninterrupted; run the same command again to resume", file=sys.stderr)
        raise
    return 0


def run_tune(config: Any) -> int:
    from agent_envs.training.commands.tune import tune_learner

    tune_learner(config)
    return 0


def run_sweep(config: Any) -> int:
    from agent_envs.training.commands.sweep import sweep

    try:
        sweep(config)
    except RuntimeError as exc:  # trials that did not finish: not a bad input
        print(f"agent-envs sweep: {exc}", file=sys.stderr)
        return 1
    return 0
