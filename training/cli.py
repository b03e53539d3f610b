"""The `agent-envs` command line: all argparse of the project, and its one error path.

Each subcommand is a `Subcommand`: a help line, ``add_arguments(parser)`` and
``run(args) -> int``. The modules doing the work are imported inside ``run`` (and, for options
read from a dataclass, inside ``add_arguments`` of the chosen subcommand only), so
`agent-envs reproduce uncontrolled` does not pay for importing torch.

Conventions shared by every subcommand:

- ``--env-kwargs`` (and every other JSON-object option) is one JSON object, e.g.
  ``--env-kwargs '{"n_agents": 20, "integrator": "em"}'``
  (`agent_envs.training.defaults.parse_env_kwargs`);
- every subcommand checks all its inputs before it does any work (trains, simulates, writes);
- a bad input (an argparse error, a ValueError / TypeError / OSError, a gymnasium error) prints
  one line ``agent-envs COMMAND: error: ...`` on stderr and exits with 2, never a traceback;
- a subcommand that needs the ``train`` extra (torch, SB3, pandas, ...) on an install without
  it prints one line naming the extra and exits with 1; Ctrl-C exits with 130.
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

#: Modules of the ``train`` extra: a missing one is reported as the missing extra.
TRAIN_EXTRA_MODULES = frozenset(
    {"torch", "stable_baselines3", "pandas", "tqdm", "supersuit", "tensorboard", "rich"}
)
#: The most seeds one command line may list (a typo like 0:10**12 is an error, not an OOM).
MAX_SEEDS = 100_000


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


def _check_sizes(args: argparse.Namespace) -> None:
    """--n-agents, --n-paths (and --n-steps) within the core's accepted sizes."""
    from agent_envs.validation import MAX_AGENTS, MAX_BATCH_SIZE, MAX_PATHS, MAX_STEPS, check_int

    check_int("--n-agents", args.n_agents, 1, MAX_AGENTS)
    check_int("--n-paths", args.n_paths, 1, MAX_PATHS)
    if getattr(args, "n_steps", None) is not None:
        check_int("--n-steps", args.n_steps, 1, MAX_STEPS)
    if args.n_agents * args.n_paths > MAX_BATCH_SIZE:
        raise ValueError(
            f"--n-agents times --n-paths must be <= {MAX_BATCH_SIZE}, got "
            f"{args.n_agents} x {args.n_paths}"
        )


def _run_uncontrolled(args: argparse.Namespace) -> int:
    from agent_envs.training.storage import check_output_dir

    _check_sizes(args)
    if args.seed < 0:
        raise ValueError(f"--seed must be an integer >= 0, got {args.seed}")
    check_output_dir(args.out)
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


def _turnpike_property_arguments(parser: argparse.ArgumentParser) -> None:
    from agent_envs.training.experiments.turnpike_property import (
        DELTA,
        EPSILONS,
        HORIZONS,
        KERNELS,
        SIGMAS,
    )

    parser.add_argument("--out", type=Path, default=Path("reproduction_turnpike_property"))
    parser.add_argument("--n-agents", type=int, default=20, help="N (paper: 100)")
    parser.add_argument("--n-paths", type=int, default=10, help="K for sigma > 0 (paper: 20)")
    parser.add_argument("--tau", type=float, default=0.05, help="time step (paper: 0.02)")
    parser.add_argument("--horizons", type=float, nargs="+", default=list(HORIZONS))
    parser.add_argument("--sigmas", type=float, nargs="+", default=list(SIGMAS))
    parser.add_argument("--epsilons", type=float, nargs="+", default=list(EPSILONS))
    parser.add_argument("--kernels", nargs="+", choices=KERNELS, default=list(KERNELS))
    parser.add_argument("--delta", type=float, default=DELTA, help="turnpike band (eq:tptime)")
    parser.add_argument("--seed", type=int, default=0, help="x^0 and the noise")
    parser.add_argument("--max-control", type=float, default=150.0)
    parser.add_argument("--gtol", type=float, default=1e-6, help="relative gradient tolerance")
    parser.add_argument("--max-iterations", type=int, default=500)
    parser.add_argument("--no-progress", dest="progress", action="store_false")


def _run_turnpike_property(args: argparse.Namespace) -> int:
    import time

    from agent_envs.training.experiments.turnpike_property import (
        TurnpikePropertyConfig,
        reproduce,
    )
    from agent_envs.training.storage import check_output_dir
    from agent_envs.validation import (
        EPSILON_RANGE,
        HORIZON_RANGE,
        MAX_CONTROL_RANGE,
        SIGMA_RANGE,
        check_positive,
        check_real,
    )

    _check_sizes(args)
    if args.n_agents < 2:
        raise ValueError(f"--n-agents must be an integer >= 2, got {args.n_agents}")
    if args.seed < 0:
        raise ValueError(f"--seed must be an integer >= 0, got {args.seed}")
    for h in args.horizons:
        check_positive("--horizons", h, HORIZON_RANGE)
    check_positive("--tau", args.tau, HORIZON_RANGE)
    for s in args.sigmas:
        check_real("--sigmas", s, SIGMA_RANGE)
    for e in args.epsilons:
        check_positive("--epsilons", e, EPSILON_RANGE)
    check_positive("--delta", args.delta)
    check_positive("--max-control", args.max_control, MAX_CONTROL_RANGE)
    check_positive("--gtol", args.gtol)
    if not 1 <= args.max_iterations <= 1_000_000:
        raise ValueError(f"--max-iterations must be in [1, 1000000], got {args.max_iterations}")
    names = {f.name for f in dataclasses.fields(TurnpikePropertyConfig)}
    values = {k: v for k, v in vars(args).items() if k in names}
    config = TurnpikePropertyConfig(
        **{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()}
    )  # ValueError naming tau when it does not divide a horizon
    check_output_dir(args.out)
    start = time.perf_counter()
    reproduce(args.out, config)
    seconds = time.perf_counter() - start
    print(f"wrote {args.out}/turnpike_property.png, .csv, .md ({seconds:.0f} s)")
    return 0


def _run_turnpike(args: argparse.Namespace) -> int:
    from agent_envs.training.storage import check_output_dir

    _check_sizes(args)
    for seed in args.seeds:
        if seed < 0:
            raise ValueError(f"--seeds must be integers >= 0, got {seed}")
    if len(set(args.seeds)) != len(args.seeds):
        raise ValueError(f"--seeds lists a seed twice: {args.seeds}")
    check_output_dir(args.out)
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

    None or no items: the held-out test seeds `defaults.DEFAULT_TEST_SEEDS`. Raises ValueError
    naming --seeds for anything else, a negative seed, an empty range or more than `MAX_SEEDS`.
    """
    from agent_envs.training.defaults import DEFAULT_TEST_SEEDS

    if items is None:
        return list(DEFAULT_TEST_SEEDS)
    seeds: list[int] = []
    for item in items:
        for part in str(item).split(","):
            part = part.strip()
            if not part:
                continue
            match = re.fullmatch(r"(\d+)(?:([-:])(\d+))?", part)
            if match is None:
                raise ValueError(
                    f"--seeds: {part!r} is not a seed (an integer >= 0), a range A-B (inclusive) "
                    "or A:B (half-open)"
                )
            low = int(match.group(1))
            if match.group(2) is None:
                span = range(low, low + 1)
            else:
                high = int(match.group(3)) + (1 if match.group(2) == "-" else 0)
                span = range(low, high)
                if not span:
                    raise ValueError(f"--seeds: the range {part!r} is empty")
            if len(seeds) + len(span) > MAX_SEEDS:
                raise ValueError(f"--seeds: more than {MAX_SEEDS} seeds")
            seeds.extend(span)
    if not seeds:
        raise ValueError("--seeds: no seed given (leave the option out for 10000-10019)")
    if len(set(seeds)) != len(seeds):
        raise ValueError("--seeds lists a seed twice")
    return seeds


def parse_policy_specs(items: Sequence[str] | None) -> dict[str, str]:
    """``NAME=SPEC`` or ``SPEC`` items -> {name: spec} (a bare path is named by its file stem).

    A SPEC is a baseline name or ``[ALGO:]MODEL.zip[:STATS.pkl]``. None or no items: the three
    reference controllers.
    """
    from agent_envs.training.defaults import BASELINE_POLICIES, FEEDBACK_BASELINES
    from agent_envs.training.policies import ModelSpec

    if not items:
        return {name: name for name in FEEDBACK_BASELINES}
    out: dict[str, str] = {}
    for item in items:
        if "=" in item:
            name, spec = item.split("=", 1)
        else:
            spec = item
            name = item if item in BASELINE_POLICIES else ModelSpec.parse(item).path.stem
        if not name or not spec:
            raise ValueError(f"--policy {item!r}: write NAME=SPEC or SPEC")
        if name in out:
            raise ValueError(f"--policy name {name!r} given twice; use NAME=SPEC to rename")
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
        help="a baseline (turnpike | proportional | zero | optimal | mpc) or a saved SB3 model "
        "PATH.zip "
        "(ALGO:PATH to name the algorithm, PATH.zip:STATS.pkl to name its VecNormalize "
        "statistics; statistics are found by themselves only in a run folder of agent-envs "
        "train, checked against its manifest.json, or of rl-zoo3); repeat for several. Default: "
        "turnpike, proportional, zero.",
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
    from agent_envs.training.defaults import BASELINE_POLICIES, check_env_id, parse_env_kwargs
    from agent_envs.training.storage import check_output_dir
    from agent_envs.validation import check_positive, check_real

    policies = parse_policy_specs(args.policies)
    env_kwargs = parse_env_kwargs(args.env_kwargs)
    seeds = parse_seeds(args.seeds)
    check_env_id(args.env_id)
    if args.target is not None:
        check_real("--target", args.target)
    check_positive("--beta", args.beta)
    check_positive("--delta", args.delta)
    check_output_dir(args.out)
    if any(spec not in BASELINE_POLICIES for spec in policies.values()):
        from agent_envs.training.policies import check_model

        for spec in policies.values():
            if spec not in BASELINE_POLICIES:
                check_model(spec)  # the file, its algorithm, its statistics (nothing unpickled)
    import pandas as pd

    from agent_envs.training.evaluate import evaluate_policies
    from agent_envs.training.report import build_report, display_table
    from agent_envs.training.results import summarize

    options = {"target": args.target} if args.target is not None else None
    # evaluate_policies resolves every policy and makes every env before the first episode
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
    for name, desc in results.meta["policies"].items():
        if desc.get("kind") == "sb3":
            from agent_envs.training.policies import STATISTICS_SOURCES

            used = desc.get("vecnormalize")
            source = STATISTICS_SOURCES.get(desc.get("vecnormalize_source"), "")
            print(
                f"{name}: VecNormalize statistics {used} ({source})"
                if used
                else f"{name}: no VecNormalize statistics (observations used as they are)"
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
        default=None,
        help=f"policy the cost ratios refer to (default: {DEFAULT_REFERENCE} when evaluated)",
    )
    parser.add_argument(
        "--seed-index",
        type=int,
        default=0,
        help="which of the evaluated seeds (0 = the first) the trajectory plot shows",
    )


def _run_report(args: argparse.Namespace) -> int:
    from agent_envs.training.storage import check_output_dir

    check_output_dir(args.out)
    import pandas as pd

    from agent_envs.training.report import build_report, display_table
    from agent_envs.training.results import DEFAULT_REFERENCE, EvaluationResults, merge_results

    loaded = [EvaluationResults.load(path) for path in args.results]
    merged = merge_results(loaded)
    if args.reference is not None and args.reference not in merged.policies:
        raise ValueError(
            f"--reference {args.reference!r} is not an evaluated policy; the results hold "
            f"{', '.join(merged.policies)}"
        )
    reference = args.reference or DEFAULT_REFERENCE
    paths = build_report(
        loaded,
        args.out,
        title=args.title,
        reference=reference,
        seed_index=args.seed_index,
    )
    summary = pd.read_csv(paths["summary"])
    shown = reference if reference in merged.policies else None
    print(display_table(summary, shown).to_string(index=False))
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
    try:  # compare() validates every option, the learners' configs and both envs first
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
    "reproduce-turnpike-property": Subcommand(
        "thm:turnpike_stochastic measured: optimal solutions for T = 0.5..8, arcs, rates, bounds",
        _turnpike_property_arguments,
        _run_turnpike_property,
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
REPRODUCTIONS = ("uncontrolled", "turnpike", "turnpike-property")


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
        return int(SUBCOMMANDS[args.command].run(args) or 0)
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
