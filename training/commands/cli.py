"""The `agent-envs` command line: all argparse of the project, and its one error path.

Each subcommand is a `Subcommand`: a help line, its options dataclass and ``run(config) ->
int``. There is one route from the command line to a config: the options are generated from
the dataclass's fields (`add_dataclass_arguments`: name, type, default and --help from the field
and its `config.option_field` metadata), the namespace becomes the dataclass
(`config_from_namespace`), and the dataclass checks its values on construction with the checks
of `agent_envs.validation`. The dataclasses live next to the code they configure
(`experiments.uncontrolled.UncontrolledConfig`, `experiments.turnpike_controlled.
TurnpikeReproductionConfig`, `experiments.turnpike_property.TurnpikePropertyConfig`,
`evaluate_options.EvaluateConfig`, `task_evaluation.TasksConfig`, `report.ReportConfig`,
`config.TrainConfig`, `compare.CompareConfig`, `sweep.SweepConfig`,
`leaderboard.LeaderboardConfig`) and are imported only when their subcommand is chosen, so
`agent-envs reproduce uncontrolled` does not pay for importing torch.

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
import dataclasses
import importlib
import json
import re
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: Modules of the ``train`` extra: a missing one is reported as the missing extra.
TRAIN_EXTRA_MODULES = frozenset(
    {"torch", "stable_baselines3", "pandas", "tqdm", "supersuit", "tensorboard", "rich"}
)


#: Names kept importable from here, each from its home (imported when asked for):
#: ``cli.parse_seeds`` and ``cli.parse_policy_specs`` were defined here before.
_MOVED = {
    "parse_seeds": "agent_envs.training.defaults",
    "parse_policy_specs": "agent_envs.training.commands.evaluate_options",
    "MAX_SEEDS": "agent_envs.training.defaults",
}


def __getattr__(name: str) -> Any:
    """`_MOVED` names, imported from their home on first use (PEP 562)."""
    if name in _MOVED:
        return getattr(importlib.import_module(_MOVED[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class UsageError(Exception):
    """A command-line error: printed as one line, exit code 2."""


class ArgumentParser(argparse.ArgumentParser):
    """argparse with the project's one error path: an error is a `UsageError` (one line).

    argparse's own `error` prints the usage block and exits; here the message is raised so
    that `main` prints it as the one line ``agent-envs COMMAND: error: ...``. Subparsers are
    of this class too (argparse creates them with the parent's class).
    """

    def error(self, message: str):  # type: ignore[override]
        raise UsageError(f"{self.prog}: error: {message} (see {self.prog} --help)")


@dataclass(frozen=True)
class Subcommand:
    """One `agent-envs` subcommand: its help line, its options dataclass and what it runs.

    The options are generated from the dataclass `config` (``"module:Class"``, imported only
    when the subcommand is chosen) by `add_dataclass_arguments`; `run` is called with the
    dataclass built from them (which validates them), or, with `given_only`, with the dict of
    the options given on the command line (`train`: options left out come from a resumed run).
    """

    help: str
    config: str
    run: Callable[[Any], int]
    description: str = ""
    given_only: bool = False

    def config_class(self) -> type:
        """The options dataclass (its module is imported here)."""
        module, name = self.config.split(":")
        return getattr(importlib.import_module(module), name)

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """One option per field of the options dataclass."""
        if self.description:
            parser.description = self.description
        add_dataclass_arguments(parser, self.config_class(), suppress_defaults=self.given_only)

    def options(self, args: argparse.Namespace) -> Any:
        """What `run` is called with: the options dataclass, or the dict of given options."""
        cls = self.config_class()
        if self.given_only:
            names = {f.name for f in dataclasses.fields(cls)}
            return {k: v for k, v in vars(args).items() if k in names}
        return config_from_namespace(cls, args)


# ------------------------------------------------------------------ options from dataclasses

#: Field metadata read by `add_dataclass_arguments` only (every other key goes to argparse):
#: ``help``: the --help text; ``flags``: the option strings instead of ``--field-name`` (an
#: alias such as ``("--policy", "-p")``, or ``("--no-progress",)`` with
#: ``action="store_false"``); ``positional``: a positional argument named like the field.
_OWN_METADATA = ("help", "flags", "positional")
#: Element types of the fields, by annotation.
_TYPES: dict[str, type] = {"int": int, "float": float, "str": str, "Path": Path}


def _annotation(f: dataclasses.Field) -> tuple[str, bool]:
    """(element type name, list-valued) of a field: ``tuple[float, ...] | None`` -> float, True."""
    text = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", str(f.type))
    text = text.removesuffix(" | None")
    match = re.fullmatch(r"(?:tuple|list)\[(\w+)(?:, \.\.\.)?\]", text)
    return (match.group(1), True) if match else (text, False)


def _shown(default: Any) -> str:
    """A default as --help shows it: dicts as JSON, lists as their items."""
    if isinstance(default, dict):
        return json.dumps(default)
    if isinstance(default, (tuple, list)):
        return " ".join(map(str, default))
    return str(default)


def _argument_kwargs(f: dataclasses.Field, suppress_defaults: bool) -> dict[str, Any]:
    """argparse keyword arguments of a field (its metadata's argparse keys added last)."""
    meta = {k: v for k, v in f.metadata.items() if k not in _OWN_METADATA}
    help_text = f.metadata.get("help", "")
    if f.default is not dataclasses.MISSING:
        default = f.default
    elif f.default_factory is not dataclasses.MISSING:
        default = f.default_factory()
    else:
        default = dataclasses.MISSING
    kwargs: dict[str, Any] = {"dest": f.name, "help": help_text}
    if default is dataclasses.MISSING:
        kwargs["required"] = True
    else:
        kwargs["default"] = argparse.SUPPRESS if suppress_defaults else default
        if "default" not in help_text.lower() and "action" not in meta:
            kwargs["help"] = f"{help_text} (default: {_shown(default)})"
    name, many = _annotation(f)
    if name == "bool":
        if "action" not in meta:
            kwargs["action"] = argparse.BooleanOptionalAction
    elif name == "dict":
        kwargs.update(metavar="JSON", type=str)
    else:
        kwargs["type"] = _TYPES.get(name, str)
        if many and "action" not in meta:
            kwargs["nargs"] = "+"
    kwargs.update(meta)
    return kwargs


def add_dataclass_arguments(
    parser: argparse.ArgumentParser,
    cls: type,
    *,
    exclude: tuple[str, ...] = (),
    suppress_defaults: bool = False,
) -> None:
    """Add one `--field-name` option per dataclass field, with the field's metadata help.

    By the field's annotation: booleans accept `--flag/--no-flag` (or, with ``action`` in the
    metadata, are a `store_true`/`store_false` flag); dict fields take a JSON object (parsed
    and checked by the dataclass); ``int``, ``float``, ``Path`` and ``str`` fields are typed
    as annotated; ``tuple[X, ...]`` / ``list[X]`` fields take one or more X (``nargs="+"``); a
    field without a default is a required option. Metadata keys other than ``help``, ``flags``
    and ``positional`` (see `_OWN_METADATA`) are passed to argparse (``choices``, ``nargs``,
    ``type``, ``action``, ``metavar``). With `suppress_defaults`, options left out do not
    appear in the namespace (so a caller can tell "not given" from "given the default").
    """
    for f in dataclasses.fields(cls):
        if f.name in exclude or not f.init:
            continue
        kwargs = _argument_kwargs(f, suppress_defaults)
        if f.metadata.get("positional"):
            del kwargs["dest"]
            kwargs.pop("required", None)
            parser.add_argument(f.name, **kwargs)
        else:
            flags = f.metadata.get("flags", ("--" + f.name.replace("_", "-"),))
            parser.add_argument(*flags, **kwargs)


def config_from_namespace(cls: type, args: argparse.Namespace, **overrides: Any) -> Any:
    """Build a dataclass from the namespace filled by `add_dataclass_arguments`.

    Lists given to a tuple-valued field become tuples; the dataclass validates the values.
    """
    values: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        if not f.init or f.name not in vars(args):
            continue
        value = getattr(args, f.name)
        if isinstance(value, list) and _annotation(f)[1]:
            value = tuple(value)
        values[f.name] = value
    values.update(overrides)
    return cls(**values)


# ------------------------------------------------------------------------ reproduce (paper)


def _run_uncontrolled(config: Any) -> int:
    from agent_envs.training.experiments.uncontrolled import markdown_table, reproduce
    from agent_envs.training.storage import check_output_dir

    check_output_dir(config.out)
    rows = reproduce(config.out, config.n_agents, config.n_paths, config.seed)
    print(markdown_table(rows))
    print(f"wrote {config.out}/results.md, results.json and the figures")
    return 0


def _run_turnpike(config: Any) -> int:
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


def _run_turnpike_property(config: Any) -> int:
    import time

    from agent_envs.training.experiments.turnpike_property import reproduce
    from agent_envs.training.storage import check_output_dir

    check_output_dir(config.out)
    start = time.perf_counter()
    reproduce(config.out, config)
    seconds = time.perf_counter() - start
    print(f"wrote {config.out}/turnpike_property.png, .csv, .md ({seconds:.0f} s)")
    return 0


def _run_cheap_control_bound(config: Any) -> int:
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


def _run_evaluate(config: Any) -> int:
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


def _run_leaderboard(config: Any) -> int:
    from agent_envs.training.commands.leaderboard import run_leaderboard

    return run_leaderboard(config)


def _run_tasks(config: Any) -> int:
    from agent_envs.training.commands.task_evaluation import run_tasks_command

    return run_tasks_command(config)


def _run_report(config: Any) -> int:
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


def _run_train(options: dict[str, Any]) -> int:
    from agent_envs.training.commands.train import config_from_options, train
    from agent_envs.training.learners.apg_policy import is_apg_run

    if options.get("algo") == "apg" or (
        options.get("resume") and is_apg_run(options["resume"]) and "algo" not in options
    ):
        return _run_train_apg(options)
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


def _run_train_apg(options: dict[str, Any]) -> int:
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


def _run_compare(config: Any) -> int:
    from agent_envs.training.commands.compare import compare

    try:  # compare() validates every option, the learners' configs and both envs first
        compare(config)
    except KeyboardInterrupt:
        print("\ninterrupted; run the same command again to resume", file=sys.stderr)
        raise
    return 0


def _run_tune(config: Any) -> int:
    from agent_envs.training.commands.tune import tune_learner

    tune_learner(config)
    return 0


def _run_sweep(config: Any) -> int:
    from agent_envs.training.commands.sweep import sweep

    try:
        sweep(config)
    except RuntimeError as exc:  # trials that did not finish: not a bad input
        print(f"agent-envs sweep: {exc}", file=sys.stderr)
        return 1
    return 0


# ------------------------------------------------------------------------------------ main

#: name -> subcommand, in the order `agent-envs --help` lists them
_T = "agent_envs.training."
SUBCOMMANDS: dict[str, Subcommand] = {
    "reproduce-uncontrolled": Subcommand(
        "paper Section 5.1 (Figs. 1-4 and the m = 1500 runs): uncontrolled runs, figures, table",
        _T + "experiments.uncontrolled:UncontrolledConfig",
        _run_uncontrolled,
    ),
    "reproduce-turnpike": Subcommand(
        "paper Section 5.2 (Figs. 5-6): turnpike-controlled runs, figures and a results table",
        _T + "experiments.turnpike_controlled:TurnpikeReproductionConfig",
        _run_turnpike,
    ),
    "reproduce-turnpike-property": Subcommand(
        "thm:turnpike_stochastic measured: optimal solutions for T = 0.5..8, arcs, rates, bounds",
        _T + "experiments.turnpike_property:TurnpikePropertyConfig",
        _run_turnpike_property,
    ),
    "reproduce-cheap-control-bound": Subcommand(
        "lem:cheap measured: its counterexamples, the noise floor, a corrected bound, L^n",
        _T + "experiments.cheap_control_bound:CheapControlBoundConfig",
        _run_cheap_control_bound,
    ),
    "tasks": Subcommand(
        "the benchmark's tasks: list them (id, what it tests, N, d, m, V), regenerate or "
        "verify their reference data",
        _T + "commands.task_evaluation:TasksConfig",
        _run_tasks,
    ),
    "evaluate": Subcommand(
        "run policies on an env over fixed seeds, store results; --task ID scores them on a "
        "benchmark task against its shipped references",
        _T + "commands.evaluate_options:EvaluateConfig",
        _run_evaluate,
    ),
    "report": Subcommand(
        "write a Markdown/HTML report with plots from results",
        _T + "results.report:ReportConfig",
        _run_report,
    ),
    "train": Subcommand(
        "train a Stable-Baselines3 agent on a swarm env",
        _T + "config:TrainConfig",
        _run_train,
        description="Train a Stable-Baselines3 agent on a swarm env. The validation cost is "
        "logged next to the turnpike controller's on the same seeds (learning_curve.csv, "
        "TensorBoard).",
        given_only=True,
    ),
    "compare": Subcommand(
        "train learners and compare them with the turnpike controller",
        _T + "commands.compare:CompareConfig",
        _run_compare,
        description="Train the preset's learners (PPO and SAC on the single-controller env, "
        "parameter-shared PPO on the PettingZoo env) and compare them with the turnpike, "
        "proportional and zero controllers on the same held-out seeds; writes "
        "OUT/report/report.md and .html.",
    ),
    "sweep": Subcommand(
        "a grid of learners x training seeds x env settings on Ray Tune, with across-seed "
        "statistics",
        _T + "commands.sweep:SweepConfig",
        _run_sweep,
        description="Run a grid of (learner x training seed x env setting) as Ray Tune trials "
        "(each one train + evaluation on the held-out test seeds) and write "
        "OUT/report/report.md with across-seed statistics (needs the 'sweep' extra: pip "
        "install 'agent-envs[sweep]').",
    ),
    "leaderboard": Subcommand(
        "every benchmark task x every policy we ship (apg, SAC, the references), scored on the "
        "tasks' test seeds; resumable in parts",
        _T + "commands.leaderboard:LeaderboardConfig",
        _run_leaderboard,
    ),
    "tune": Subcommand(
        "hyperparameter search for one learner of a preset (Ray Tune + Optuna)",
        _T + "commands.tune:TuneConfig",
        _run_tune,
        description="Search the hyperparameters of one learner of a preset with Optuna's TPE "
        "sampler on Ray Tune (rl-zoo3's search spaces; ASHA or median early stopping on the "
        "validation cost); writes OUT/tune_summary.md, OUT/trials.csv and "
        "OUT/best_hyperparams.yml (needs the 'sweep' extra).",
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
