"""MkDocs hook: the CLI reference page is generated from the parser, never copied by hand.

`docs/cli.md` holds the marker ``<!-- cli-reference -->``; at build time this hook replaces it
with the ``--help`` of ``agent-envs`` and of every subcommand in
`agent_envs.training.commands.cli.SUBCOMMANDS`, as `build_parser(name)` builds them (the same parser
the command runs). The help is formatted at a fixed width, so the page does not depend on the
terminal of whoever builds it. `cli_reference_markdown()` is importable on its own (the tests
call it).
"""

from __future__ import annotations

import argparse
import os
from contextlib import contextmanager

MARKER = "<!-- cli-reference -->"
HELP_WIDTH = 88


@contextmanager
def _columns(width: int):
    """argparse wraps help at $COLUMNS - 2: fix it for the duration of the build."""
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(width + 2)
    try:
        yield
    finally:
        if old is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = old


def _subparser(parser: argparse.ArgumentParser, name: str) -> argparse.ArgumentParser:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action.choices[name]
    raise LookupError(f"the agent-envs parser has no subcommand {name!r}")


def cli_reference_markdown() -> str:
    """One section per subcommand, each its `--help` as `agent-envs NAME --help` prints it."""
    from agent_envs.training.commands import cli

    with _columns(HELP_WIDTH):
        sections = ["## agent-envs\n", "```text", cli.build_parser().format_help().rstrip(), "```"]
        for name in cli.SUBCOMMANDS:
            shown = "agent-envs " + name.replace("reproduce-", "reproduce ")
            help_text = _subparser(cli.build_parser(name), name).format_help().rstrip()
            sections += [f"\n## {shown}\n", "```text", help_text, "```"]
    return "\n".join(sections) + "\n"


def on_page_markdown(markdown: str, page, config, files) -> str:
    if MARKER not in markdown:
        return markdown
    return markdown.replace(MARKER, cli_reference_markdown())
