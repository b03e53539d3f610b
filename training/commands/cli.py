"""The `agent-envs` command line: its subcommands (`SUBCOMMANDS`), `main` and its one error path.

Each subcommand is a `parser.Subcommand`: a help line, its options dataclass and ``run(config)
-> int`` (the runners of `runners`). There is one route from the command line to a config: the
options are generated from the dataclass's fields (`parser.add_dataclass_arguments`: name, type,
default and --help from the field and its `config.option_field` metadata), the namespace becomes
the dataclass (`parser.config_from_namespace`), and the dataclass checks its values on
construction with the checks of `agent_envs.validation`. The dataclasses live next to the code
they configure (`experiments.uncontrolled.UncontrolledConfig`, `experiments.turnpike_controlled.
TurnpikeReproductionConfig`, `experiments.turnpike_property.TurnpikePropertyConfig`,
`evaluate_options.EvaluateConfig`, `task_evaluation.TasksConfig`, `report.ReportConfig`,
`config.TrainConfig`, `compare.CompareConfig`, `sweep.SweepConfig`,
`leaderboard.LeaderboardConfig`, `published.TablesConfig`) and are imported only when their
subcommand is chosen, so `agent-envs reproduce uncontrolled` does not pay for importing torch.

Conventions shared by every subcommand:

- ``--env-kwargs`` (and every other JSON-object option) is one JSON object, e.g.
  ``--env-kwargs '{"n_agents": 20, "integrator": "em"}'``
  (`agent_envs.training.defaults.parse_env_kwargs`);
- ``--seeds`` is a seed list of items ``N``, ``A-B`` (inclusive) or ``A:B`` (half-open),
  separated by commas or spaces, e.g. ``--seeds 0-4,10`` (`defaults.parse_seeds`);
- every subcommand checks all its inputs before it does any work (trains, simulates, writes);
- a bad input (an argparse error, a ValueError / TypeError / OSError, a gymnasium error) prints
  one line ``agent-envs COMMAND: error: ...`` on stderr and exits with 2, never a traceback;
- a subcommand that needs the ``train`` extra (torch, SB3, pandas, ...) on an install without
  it prints one line naming the extra and exits with 1; Ctrl-C exits with 130.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from agent_envs.training.commands import runners
from agent_envs.training.commands.parser import ArgumentParser, Subcommand, UsageError

#: Modules of the ``train`` extra: a missing one is reported as the missing extra.
TRAIN_EXTRA_MODULES = frozenset(
    {"torch", "stable_baselines3", "pandas", "tqdm", "supersuit", "tensorboard", "rich"}
)


# ------------------------------------------------------------------------------------ main

#: name -> subcommand, in the order `agent-envs --help` lists them
_T = "agent_envs.training."
SUBCOMMANDS: dict[str, Subcommand] = {
    "reproduce-uncontrolled": Subcommand(
        "paper Section 5.1 (Figs. 1-4 and the m = 1500 runs): uncontrolled runs, figures, table",
        _T + "experiments.uncontrolled:UncontrolledConfig",
        runners.run_uncontrolled,
    ),
    "reproduce-turnpike": Subcommand(
        "paper Section 5.2 (Figs. 5-6): turnpike-controlled runs, figures and a results table",
        _T + "experiments.turnpike_controlled:TurnpikeReproductionConfig",
        runners.run_turnpike,
    ),
    "reproduce-turnpike-property": Subcommand(
        "thm:turnpike_stochastic measured: optimal solutions for T = 0.5..8, arcs, rates, bounds",
        _T + "experiments.turnpike_property:TurnpikePropertyConfig",
        runners.run_turnpike_property,
    ),
    "reproduce-cheap-control-bound": Subcommand(
        "lem:cheap measured: its counterexamples, the noise floor, a corrected bound, L^n",
        _T + "experiments.cheap_control_config:CheapControlBoundConfig",
        runners.run_cheap_control_bound,
    ),
    "tasks": Subcommand(
        "the benchmark's tasks: list them (id, what it tests, N, d, m, V), regenerate or "
        "verify their reference data",
        _T + "commands.task_evaluation:TasksConfig",
        runners.run_tasks,
    ),
    "evaluate": Subcommand(
        "run policies on an env over fixed seeds, store results; --task ID scores them on a "
        "benchmark task against its shipped references",
        _T + "commands.evaluate_options:EvaluateConfig",
        runners.run_evaluate,
    ),
    "report": Subcommand(
        "write a Markdown/HTML report with plots from results",
        _T + "results.report:ReportConfig",
        runners.run_report,
    ),
    "train": Subcommand(
        "train a Stable-Baselines3 agent on a swarm env",
        _T + "config:TrainConfig",
        runners.run_train,
        description="Train a Stable-Baselines3 agent on a swarm env. The validation cost is "
        "logged next to the turnpike controller's on the same seeds (learning_curve.csv, "
        "TensorBoard).",
        given_only=True,
    ),
    "compare": Subcommand(
        "train learners and compare them with the turnpike controller",
        _T + "commands.compare:CompareConfig",
        runners.run_compare,
        description="Train the preset's learners (PPO and SAC on the single-controller env, "
        "parameter-shared PPO on the PettingZoo env) and compare them with the turnpike, "
        "proportional and zero controllers on the same held-out seeds; writes "
        "OUT/report/report.md and .html.",
    ),
    "sweep": Subcommand(
        "a grid of learners x training seeds x env settings on Ray Tune, with across-seed "
        "statistics",
        _T + "commands.sweep:SweepConfig",
        runners.run_sweep,
        description="Run a grid of (learner x training seed x env setting) as Ray Tune trials "
        "(each one train + evaluation on the held-out test seeds) and write "
        "OUT/report/report.md with across-seed statistics (needs the 'sweep' extra: pip "
        "install 'agent-envs[sweep]').",
    ),
    "leaderboard": Subcommand(
        "every benchmark task x every policy we ship (apg, SAC, the references), scored on the "
        "tasks' test seeds; resumable in parts",
        _T + "commands.leaderboard:LeaderboardConfig",
        runners.run_leaderboard,
    ),
    "tables": Subcommand(
        "re-render every published result table of README.md and docs/ from its committed "
        "files (no training); --check exits 1 naming each stale one",
        _T + "commands.published:TablesConfig",
        runners.run_tables,
    ),
    "tune": Subcommand(
        "hyperparameter search for one learner of a preset (Ray Tune + Optuna)",
        _T + "commands.tune:TuneConfig",
        runners.run_tune,
        description="Search the hyperparameters of one learner of a preset with Optuna's TPE "
        "sampler on Ray Tune (rl-zoo3's search spaces; ASHA or median early stopping on the "
        "validation cost, or on its worst, median or mean over several --seeds); writes "
        "OUT/tune_summary.md, OUT/trials.csv and OUT/best_hyperparams.yml (needs the 'sweep' "
        "extra).",
    ),
}
#: `agent-envs reproduce NAME` is an alias of `agent-envs reproduce-NAME`.
REPRODUCTIONS = ("uncontrolled", "turnpike", "turnpike-property", "cheap-control-bound")


def _normalise(argv: list[str]) -> list[str]:
    if len(argv) >= 2 and argv[0] == "reproduce" and argv[1] in REPRODUCTIONS:
        return [f"reproduce-{argv[1]}", *argv[2:]]
    return argv


def build_parser(selected: str | None = None) -> argparse.ArgumentParser:
    """The parser; only `selected`'s options are filled in (they may import its modules)."""
    parser = ArgumentParser(
        prog="agent-envs",
        description="Stochastic, stiff swarm environments, the turnpike controller and learners.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, command in SUBCOMMANDS.items():
        shown = "agent-envs " + name.replace("reproduce-", "reproduce ")  # the alias users type
        sp = sub.add_parser(name, help=command.help, description=command.help, prog=shown)
        if name == selected:
            command.add_arguments(sp)
    return parser


def user_error_types() -> tuple[type[BaseException], ...]:
    """The exceptions that mean "bad input": reported as one line with exit code 2."""
    import gymnasium

    return (ValueError, TypeError, OSError, gymnasium.error.Error)


def one_line(exc: BaseException) -> str:
    """An exception's message on one line (its type when it has none)."""
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


def missing_extra(exc: ModuleNotFoundError) -> str | None:
    """The one-line message for a module of the ``train`` extra that is not installed."""
    top = (exc.name or "").split(".")[0]
    if top not in TRAIN_EXTRA_MODULES:
        return None
    return (
        f"this command needs the 'train' extra (module {top!r} is not installed): "
        'pip install "agent-envs[train]"'
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `agent-envs` script (the one error path: see the module docstring)."""
    args_list = _normalise(list(sys.argv[1:] if argv is None else argv))
    if args_list and args_list[0] == "reproduce":
        print(
            f"agent-envs reproduce: error: name an experiment: agent-envs reproduce "
            f"{{{','.join(REPRODUCTIONS)}}} [--out DIR] ...",
            file=sys.stderr,
        )
        return 2
    selected = next((a for a in args_list if a in SUBCOMMANDS), None)
    command = selected or "agent-envs"
    try:
        parser = build_parser(selected)
        args = parser.parse_args(args_list)
        if args.command is None:
            parser.print_help()
            return 2
        command = args.command.replace("reproduce-", "reproduce ")
        subcommand = SUBCOMMANDS[args.command]
        return int(subcommand.run(subcommand.options(args)) or 0)
    except UsageError as exc:
        print(one_line(exc), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except ModuleNotFoundError as exc:
        message = missing_extra(exc)
        if message is None:
            raise
        print(f"agent-envs {command}: error: {message}", file=sys.stderr)
        return 1
    except Exception as exc:
        if not isinstance(exc, user_error_types()):
            raise
        print(f"agent-envs {command}: error: {one_line(exc)}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
