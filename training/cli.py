"""The `agent-envs` command line: all argparse of the project, and its one error path.

Each subcommand is a `Subcommand`: a help line, ``add_arguments(parser)`` and
``run(args) -> int``. The modules doing the work are imported inside ``run`` (and, for options
read from a dataclass, inside ``add_arguments`` of the chosen subcommand only), so
`agent-envs reproduce uncontrolled` does not pay for importing torch.

Conventions shared by every subcommand:

- ``--env-kwargs`` (and every other JSON-object option) is one JSON object, e.g.
  ``--env-kwargs '{"n_agents": 20, "integrator": "em"}'``
  (`agent_envs.training.defaults.parse_env_kwargs`);
- a bad input (ValueError, TypeError, a missing file) prints one line
  ``agent-envs COMMAND: error: ...`` on stderr and exits with 2; Ctrl-C exits with 130.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import re
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any


@dataclass(frozen=True)
class Subcommand:
    """One `agent-envs` subcommand: its help line, its options and what it runs."""

    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]


# ------------------------------------------------------------------ options from dataclasses


def add_dataclass_arguments(
    parser: argparse.ArgumentParser,
    cls: type,
    *,
    exclude: tuple[str, ...] = (),
    suppress_defaults: bool = False,
) -> None:
    """Add one `--field-name` option per dataclass field, with the field's metadata help.

    Booleans accept `--flag/--no-flag`; dict fields take a JSON object (parsed and checked by
    the dataclass). With `suppress_defaults`, options left out do not appear in the namespace
    (so a caller can tell "not given" from "given the default").
    """
    for f in dataclasses.fields(cls):
        if f.name in exclude:
            continue
        flag = "--" + f.name.replace("_", "-")
        meta = dict(f.metadata)
        help_text = meta.pop("help", "")
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        kwargs: dict[str, Any] = {"dest": f.name}
        kwargs["default"] = argparse.SUPPRESS if suppress_defaults else default
        shown = json.dumps(default) if isinstance(default, dict) else default
        mentioned = "default" in help_text
        kwargs["help"] = help_text if mentioned else f"{help_text} (default: {shown})"
        if f.type in ("bool", "bool | None", bool):
            kwargs["action"] = argparse.BooleanOptionalAction
        elif f.type in ("dict", dict):
            kwargs["metavar"] = "JSON"
            kwargs["type"] = str
        elif f.type in ("int", "int | None"):
            kwargs["type"] = int
        elif f.type == "float":
            kwargs["type"] = float
        else:
            kwargs["type"] = str
        kwargs.update(meta)
        parser.add_argument(flag, **kwargs)


def config_from_namespace(cls: type, args: argparse.Namespace, **overrides: Any) -> Any:
    """Build a dataclass from the namespace filled by `add_dataclass_arguments`."""
    names = {f.name for f in dataclasses.fields(cls)}
    values = {k: v for k, v in vars(args).items() if k in names}
    values.update(overrides)
    return cls(**values)


# ------------------------------------------------------------------------ reproduce (paper)


def _uncontrolled_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--out",
        type=Path,
        default=Path("out/uncontrolled"),
        help="output folder (default: out/uncontrolled)",
    )
    parser.add_argument("--n-agents", type=int, default=100, help="number of agents N (100)")
    parser.add_argument("--n-paths", type=int, default=20, help="Brownian paths (20)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the start and noise (0)")


def _run_uncontrolled(args: argparse.Namespace) -> int:
    from agent_envs.training.experiments.uncontrolled import markdown_table, reproduce

    rows = reproduce(args.out, args.n_agents, args.n_paths, args.seed)
    print(markdown_table(rows))
    print(f"wrote {args.out}/results.md, results.json and the figures")
    return 0


def _turnpike_arguments(parser: argparse.ArgumentParser) -> None:
    from agent_envs.training.experiments.turnpike_controlled import (
        MODES,
        N_AGENTS,
        N_PATHS,
        N_STEPS,
    )

    parser.add_argument(
        "--out",
        type=Path,
        default=Path("reproduction_turnpike"),
        help="output folder (default: reproduction_turnpike)",
    )
    parser.add_argument(
        "--seeds",
        type=int,
        nargs="+",
        default=[0],
        help="seeds of the initial positions and noise (default: 0)",
    )
    parser.add_argument(
        "--modes",
        nargs="+",
        choices=MODES,
        default=list(MODES),
        help="env (public API, zero-order hold) and/or closed-loop (paper)",
    )
    parser.add_argument("--n-agents", type=int, default=N_AGENTS)
    parser.add_argument("--n-paths", type=int, default=N_PATHS)
    parser.add_argument("--n-steps", type=int, default=N_STEPS)
    parser.add_argument("--no-progress", action="store_true")


def _run_turnpike(args: argparse.Namespace) -> int:
    import pandas as pd

    from agent_envs.training.experiments.turnpike_controlled import TABLE_COLUMNS, reproduce

    table = reproduce(
        args.out,
        tuple(args.seeds),
        modes=tuple(args.modes),
        n_agents=args.n_agents,
        n_steps=args.n_steps,
        n_paths=args.n_paths,
        progress=not args.no_progress,
    )
    cols = [c for c in TABLE_COLUMNS if c in table.columns]
    with pd.option_context(
        "display.width", 200, "display.max_columns", 30, "display.float_format", "{:.3g}".format
    ):
        print(table[cols].to_string(index=False))
    print(f"written: {args.out}/results.md, results.csv, results.json and PNGs")
    return 0


# -------------------------------------------------------------------------------- evaluate


def parse_seeds(items: Sequence[str] | None) -> list[int]:
    """Seeds from items like ``0 1 2``, ``0-19`` (inclusive) or ``0:20`` (half-open).

    None or no items: the held-out test seeds `defaults.DEFAULT_TEST_SEEDS`.
    """
    from agent_envs.training.defaults import DEFAULT_TEST_SEEDS

    if not items:
        return list(DEFAULT_TEST_SEEDS)
    seeds: list[int] = []
    for item in items:
        for part in str(item).split(","):
            part = part.strip()
            if not part:
                continue
            if ":" in part:
                a, b = part.split(":", 1)
                seeds.extend(range(int(a), int(b)))
            elif re.fullmatch(r"\d+-\d+", part):
                a, b = part.split("-", 1)
                seeds.extend(range(int(a), int(b) + 1))
            else:
                seeds.append(int(part))
    return seeds


def parse_policy_specs(items: Sequence[str] | None) -> dict[str, str]:
    """``NAME=SPEC`` or ``SPEC`` items -> {name: spec} (a bare path is named by its file stem).

    None or no items: the three reference controllers.
    """
    from agent_envs.training.defaults import BASELINE_POLICIES

    if not items:
        return {name: name for name in BASELINE_POLICIES}
    out: dict[str, str] = {}
    for item in items:
        if "=" in item:
            name, spec = item.split("=", 1)
        else:
            spec = item
            name = Path(item.split(":", 1)[-1]).stem if item not in BASELINE_POLICIES else item
        if name in out:
            raise ValueError(f"policy name {name!r} given twice; use NAME=SPEC to rename")
        out[name] = spec
    return out


def _evaluate_arguments(parser: argparse.ArgumentParser) -> None:
    from agent_envs.training.defaults import DEFAULT_BETA, DEFAULT_DELTA, GYM_ENV_ID

    parser.add_argument(
        "--policy",
        "-p",
        action="append",
        dest="policies",
        metavar="[NAME=]SPEC",
        help="a baseline (turnpike | proportional | zero) or a saved SB3 model PATH.zip "
        "(ALGO:PATH to name the algorithm); repeat for several. Default: turnpike, proportional, "
        "zero.",
    )
    parser.add_argument("--env-id", default=GYM_ENV_ID, help="Gymnasium env id")
    parser.add_argument(
        "--env-kwargs",
        default=None,
        metavar="JSON",
        help='env keyword arguments as a JSON object, e.g. \'{"n_agents": 20, "integrator": '
        "\"em\"}' (default: the env's defaults)",
    )
    parser.add_argument(
        "--seeds",
        nargs="*",
        default=None,
        help="reset seeds: '0 1 2', '0-19' or '0:20' (default 10000-10019)",
    )
    parser.add_argument("--target", type=float, default=None, help="reset option: the target")
    parser.add_argument(
        "--beta", type=float, default=DEFAULT_BETA, help=f"baselines' beta ({DEFAULT_BETA:g})"
    )
    parser.add_argument(
        "--delta", type=float, default=DEFAULT_DELTA, help=f"baselines' delta ({DEFAULT_DELTA:g})"
    )
    parser.add_argument("--out", required=True, type=Path, help="output folder")
    parser.add_argument("--report", action="store_true", help="also write a report in OUT/report")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def _run_evaluate(args: argparse.Namespace) -> int:
    import pandas as pd

    from agent_envs.training.defaults import parse_env_kwargs
    from agent_envs.training.evaluate import evaluate_policies
    from agent_envs.training.report import build_report, display_table
    from agent_envs.training.results import summarize

    policies = parse_policy_specs(args.policies)
    env_kwargs = parse_env_kwargs(args.env_kwargs)
    seeds = parse_seeds(args.seeds)
    options = {"target": args.target} if args.target is not None else None
    results = evaluate_policies(
        policies,
        args.env_id,
        env_kwargs,
        seeds,
        reset_options=options,
        baseline_kwargs={"beta": args.beta, "delta": args.delta},
        progress=not args.no_progress,
        out_dir=args.out,
    )
    reference = "turnpike" if "turnpike" in policies else None
    table = display_table(summarize(results.episodes, reference), reference)
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        print(table.to_string(index=False))
    print(f"results written to {args.out}")
    if args.report:
        paths = build_report([results], args.out / "report")
        print(f"report: {paths['markdown']} and {paths['html']}")
    return 0


# ---------------------------------------------------------------------------------- report


def _report_arguments(parser: argparse.ArgumentParser) -> None:
    from agent_envs.training.results import DEFAULT_REFERENCE

    parser.add_argument("results", nargs="+", type=Path, help="evaluation folder(s)")
    parser.add_argument("--out", required=True, type=Path, help="report folder")
    parser.add_argument("--title", default="Swarm control: policy evaluation")
    parser.add_argument(
        "--reference",
        default=DEFAULT_REFERENCE,
        help=f"policy the cost ratios refer to (default: {DEFAULT_REFERENCE})",
    )
    parser.add_argument("--seed-index", type=int, default=0, help="seed shown in trajectories")


def _run_report(args: argparse.Namespace) -> int:
    import pandas as pd

    from agent_envs.training.report import build_report, display_table

    paths = build_report(
        list(args.results),
        args.out,
        title=args.title,
        reference=args.reference,
        seed_index=args.seed_index,
    )
    summary = pd.read_csv(paths["summary"])
    print(display_table(summary, args.reference).to_string(index=False))
    print(f"report: {paths['markdown']} and {paths['html']}")
    return 0


# ----------------------------------------------------------------------------------- train


def _train_arguments(parser: argparse.ArgumentParser) -> None:
    from agent_envs.training.config import TrainConfig

    parser.description = (
        "Train a Stable-Baselines3 agent on a swarm env. The validation cost is logged next to "
        "the turnpike controller's on the same seeds (learning_curve.csv, TensorBoard)."
    )
    add_dataclass_arguments(parser, TrainConfig, suppress_defaults=True)


def _run_train(args: argparse.Namespace) -> int:
    from agent_envs.training.config import TrainConfig
    from agent_envs.training.train import config_from_options, train

    names = {f.name for f in dataclasses.fields(TrainConfig)}
    run_dir = train(config_from_options({k: v for k, v in vars(args).items() if k in names}))
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


# --------------------------------------------------------------------------------- compare


def _compare_arguments(parser: argparse.ArgumentParser) -> None:
    from agent_envs.training.compare import CompareConfig

    parser.description = (
        "Train the preset's learners (PPO and SAC on the single-controller env, parameter-shared "
        "PPO on the PettingZoo env) and compare them with the turnpike, proportional and zero "
        "controllers on the same held-out seeds; writes OUT/report/report.md and .html."
    )
    add_dataclass_arguments(parser, CompareConfig)


def _run_compare(args: argparse.Namespace) -> int:
    from agent_envs.training.compare import CompareConfig, compare

    config = config_from_namespace(CompareConfig, args)
    config.selected_learners()
    try:
        compare(config)
    except KeyboardInterrupt:
        print("\ninterrupted; run the same command again to resume", file=sys.stderr)
        raise
    return 0


# ----------------------------------------------------------------------------------- sweep


def _sweep_arguments(parser: argparse.ArgumentParser) -> None:
    from agent_envs.training.sweep import SweepConfig

    parser.description = (
        "Run a grid of (learner x training seed x env setting) as Ray Tune trials (each one "
        "train + evaluation on the held-out test seeds) and write OUT/report/report.md with "
        "across-seed statistics (needs the 'sweep' extra: pip install 'agent-envs[sweep]')."
    )
    add_dataclass_arguments(parser, SweepConfig)


def _run_sweep(args: argparse.Namespace) -> int:
    from agent_envs.training.sweep import SweepConfig, sweep

    config = config_from_namespace(SweepConfig, args)
    try:
        sweep(config)
    except RuntimeError as exc:  # trials that did not finish: not a bad input
        print(f"agent-envs sweep: {exc}", file=sys.stderr)
        return 1
    return 0


# ------------------------------------------------------------------------------------ main

#: name -> subcommand, in the order `agent-envs --help` lists them
SUBCOMMANDS: dict[str, Subcommand] = {
    "reproduce-uncontrolled": Subcommand(
        "paper Section 5.1 (Figs. 1-4 and the m = 1500 runs): uncontrolled runs, figures, table",
        _uncontrolled_arguments,
        _run_uncontrolled,
    ),
    "reproduce-turnpike": Subcommand(
        "paper Section 5.2 (Figs. 5-6): turnpike-controlled runs, figures and a results table",
        _turnpike_arguments,
        _run_turnpike,
    ),
    "evaluate": Subcommand(
        "run policies on an env over fixed seeds, store results",
        _evaluate_arguments,
        _run_evaluate,
    ),
    "report": Subcommand(
        "write a Markdown/HTML report with plots from results", _report_arguments, _run_report
    ),
    "train": Subcommand(
        "train a Stable-Baselines3 agent on a swarm env", _train_arguments, _run_train
    ),
    "compare": Subcommand(
        "train learners and compare them with the turnpike controller",
        _compare_arguments,
        _run_compare,
    ),
    "sweep": Subcommand(
        "a grid of learners x training seeds x env settings on Ray Tune, with across-seed "
        "statistics",
        _sweep_arguments,
        _run_sweep,
    ),
}
#: `agent-envs reproduce NAME` is an alias of `agent-envs reproduce-NAME`.
REPRODUCTIONS = ("uncontrolled", "turnpike")


def _normalise(argv: list[str]) -> list[str]:
    if len(argv) >= 2 and argv[0] == "reproduce" and argv[1] in REPRODUCTIONS:
        return [f"reproduce-{argv[1]}", *argv[2:]]
    return argv


def build_parser(selected: str | None = None) -> argparse.ArgumentParser:
    """The parser; only `selected`'s options are filled in (they may import its modules)."""
    parser = argparse.ArgumentParser(
        prog="agent-envs",
        description="Stochastic, stiff swarm environments, the turnpike controller and learners.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, command in SUBCOMMANDS.items():
        sp = sub.add_parser(name, help=command.help, description=command.help)
        if name == selected:
            command.add_arguments(sp)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `agent-envs` script (the one error path: see the module docstring)."""
    args_list = _normalise(list(sys.argv[1:] if argv is None else argv))
    if args_list and args_list[0] == "reproduce":
        print(
            f"usage: agent-envs reproduce {{{','.join(REPRODUCTIONS)}}} [--out DIR] ...",
            file=sys.stderr,
        )
        return 2
    selected = next((a for a in args_list if a in SUBCOMMANDS), None)
    parser = build_parser(selected)
    args = parser.parse_args(args_list)
    if args.command is None:
        parser.print_help()
        return 2
    try:
        return int(SUBCOMMANDS[args.command].run(args) or 0)
    except (ValueError, TypeError, FileNotFoundError) as exc:
        print(f"agent-envs {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
