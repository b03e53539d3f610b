"""The README and docs cannot go stale: every `agent-envs ...` command they quote parses with
the CLI's own parser (nothing runs), and the published tables agree with the committed result
files they come from: the README's headline table is the benchmark leaderboard's first task
(docs/results/leaderboard/episodes.csv). The tables `agent-envs tables` renders (the paper
sweep's, env options, the shared policy across N, apg's, ...) are checked digit for digit in
tests/test_published_tables.py.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("**/*.md"))]

# ------------------------------------------------------------------ commands


def quoted_commands(text: str) -> list[str]:
    """`agent-envs ...` lines of fenced code blocks (continuations joined, comments kept for
    shlex to drop) and inline code spans outside them (whitespace collapsed)."""
    found = []
    for block in re.findall(r"```[^\n]*\n(.*?)```", text, flags=re.S):
        for line in re.sub(r"\\\n\s*", " ", block).splitlines():
            line = line.strip()
            if line.startswith("agent-envs "):
                found.append(line)
    prose = re.sub(r"```.*?```", "", text, flags=re.S)
    for span in re.findall(r"`(agent-envs [^`]*)`", prose):
        found.append(" ".join(span.split()))
    return found


def _cases() -> list:
    cases = []
    for path in DOCS:
        for command in quoted_commands(path.read_text()):
            cases.append(pytest.param(command, id=f"{path.name}: {command[:60]}"))
    return cases


def test_commands_are_found():
    """The extraction sees the README's commands (a broken regex would pass everything)."""
    commands = [c for path in DOCS for c in quoted_commands(path.read_text())]
    assert len(commands) >= 25
    assert any(c.startswith("agent-envs compare --preset quick") for c in commands)
    assert any(c.startswith("agent-envs evaluate") and "-p optimal" in c for c in commands)


def parse(command: str) -> None:
    """Parse `command` as `agent-envs` would (`cli.main` up to running the job)."""
    from agent_envs.training.commands import cli

    argv = cli._normalise(shlex.split(command, comments=True)[1:])
    selected = next((a for a in argv if a in cli.SUBCOMMANDS), None)
    args = cli.build_parser(selected).parse_args(argv)
    assert args.command in cli.SUBCOMMANDS


@pytest.mark.parametrize("command", _cases())
def test_quoted_command_parses(command):
    from agent_envs.training.commands import cli

    words = command.split()
    if words[1].startswith("{"):  # a synopsis: agent-envs {reproduce uncontrolled|evaluate|...}
        alternatives = " ".join(words[1:]).strip("{}").split("|")
        for alternative in alternatives:
            assert cli._normalise(alternative.split())[0] in cli.SUBCOMMANDS, alternative
        return
    if words[1].rstrip(":").isupper():  # a placeholder (`agent-envs COMMAND --help`, the
        return  # documented error format `agent-envs COMMAND: error: ...`), not a command
    # a token in capitals (NAME, X, DIR) is a placeholder: `agent-envs reproduce NAME`
    placeholder = any(re.fullmatch(r"[A-Z][A-Z_]*", w.split("-")[-1]) for w in words[1:])
    if len(words) == 2 or (len(words) == 3 and words[1] == "reproduce"):
        # a subcommand named in prose (`agent-envs evaluate`): it must exist
        assert placeholder or cli._normalise(words[1:])[0] in cli.SUBCOMMANDS, command
        return
    if words[-1] == "--help":
        with pytest.raises(SystemExit) as exit_info:
            parse(command)
        assert exit_info.value.code == 0
        return
    try:
        parse(command)
    except cli.UsageError as error:
        if placeholder:  # `agent-envs reproduce NAME`, `sweep --preset X`: a pattern, not a call
            return
        pytest.fail(f"{command!r} does not parse: {error}")


def test_the_gap_table_command_parses_and_the_old_quote_did_not():
    """The quote of issue 24 (`--env-kwargs n_agents=10 n_steps=20`) is rejected by the parser
    (`--env-kwargs` takes one JSON object), so the test above would catch it."""
    from agent_envs.training.commands import cli

    with pytest.raises(cli.UsageError):
        parse("agent-envs evaluate --env-kwargs n_agents=10 n_steps=20 -p optimal --out e")


def test_cli_error_battery_size_is_the_one_quoted():
    """Wherever the README or the docs quote the size of the CLI error battery."""
    import test_cli_errors

    pattern = r"tests/test_cli_errors.py` runs (\d+)\s+bad invocations"
    quoted = [n for path in DOCS for n in re.findall(pattern, path.read_text())]
    assert quoted and set(quoted) == {str(len(test_cli_errors.BATTERY))}, quoted


# ------------------------------------------------------------------- tables


def test_readme_headline_table_is_the_leaderboards_first_task():
    """The README's headline table: the StiffSwarm-v0 section of the leaderboard, rebuilt from
    the committed per-episode file (docs/results/leaderboard/episodes.csv)."""

    from agent_envs.training.commands.leaderboard import leaderboard_table, read_episodes

    text = (ROOT / "README.md").read_text()
    section = text.split("## The headline result: the benchmark's first task", 1)[1]
    match = re.search(
        r"<!-- leaderboard-table:start -->\n(.*?)<!-- leaderboard-table:end -->", section, re.S
    )
    assert match
    rows = read_episodes(ROOT / "docs" / "results" / "leaderboard" / "episodes.csv")
    expected = leaderboard_table(rows, tasks=["agent_envs/StiffSwarm-v0"]).strip()
    assert match.group(1).strip() == expected
    assert "| apg " in expected and "| sac " in expected and "| optimal " in expected
