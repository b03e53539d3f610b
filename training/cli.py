"""The `agent-envs` command line: one subcommand per job, each in its own module.

Each subcommand module exposes ``add_arguments(parser)`` and ``run(args) -> int``. Only the
module of the chosen subcommand is imported, so `agent-envs reproduce uncontrolled` does not
pay for importing torch.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

#: subcommand -> (module, one-line help)
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "reproduce-uncontrolled": (
        "agent_envs.reproduction",
        "paper Section 5.1 (Figs. 1-4 and the m = 1500 runs): uncontrolled runs, figures, table",
    ),
    "reproduce-turnpike": (
        "agent_envs.training.reproduce_turnpike",
        "paper Section 5.2 (Figs. 5-6): turnpike-controlled runs, figures and a results table",
    ),
    "reproduce-turnpike-property": (
        "agent_envs.training.turnpike_property",
        "thm:turnpike_stochastic measured: optimal solutions for T = 0.5..8, arcs, rates, bounds",
    ),
    "evaluate": (
        "agent_envs.training.evaluate",
        "run policies on an env over fixed seeds, store results",
    ),
    "report": (
        "agent_envs.training.report",
        "write a Markdown/HTML report with plots from results",
    ),
    "train": ("agent_envs.training.train", "train a Stable-Baselines3 agent on a swarm env"),
    "compare": (
        "agent_envs.training.compare",
        "train learners and compare them with the turnpike controller",
    ),
}
#: `agent-envs reproduce NAME` is an alias of `agent-envs reproduce-NAME`.
REPRODUCTIONS = ("uncontrolled", "turnpike", "turnpike-property")


def _normalise(argv: list[str]) -> list[str]:
    if len(argv) >= 2 and argv[0] == "reproduce" and argv[1] in REPRODUCTIONS:
        return [f"reproduce-{argv[1]}", *argv[2:]]
    return argv


def build_parser(selected: str | None = None) -> argparse.ArgumentParser:
    """The parser; only `selected`'s module is imported to fill in its arguments."""
    parser = argparse.ArgumentParser(
        prog="agent-envs",
        description="Stochastic, stiff swarm environments, the turnpike controller and learners.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module_name, help_text) in SUBCOMMANDS.items():
        sp = sub.add_parser(name, help=help_text, description=help_text)
        if name == selected:
            importlib.import_module(module_name).add_arguments(sp)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `agent-envs` script."""
    args_list = _normalise(list(sys.argv[1:] if argv is None else argv))
    if args_list and args_list[0] == "reproduce":
        print(f"usage: agent-envs reproduce {{{','.join(REPRODUCTIONS)}}} [--out DIR] ...")
        return 2
    selected = next((a for a in args_list if a in SUBCOMMANDS), None)
    parser = build_parser(selected)
    args = parser.parse_args(args_list)
    if args.command is None:
        parser.print_help()
        return 2
    module = importlib.import_module(SUBCOMMANDS[args.command][0])
    return int(module.run(args) or 0)


if __name__ == "__main__":
    raise SystemExit(main())
