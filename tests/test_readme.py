"""The README and docs cannot go stale: every `agent-envs ...` command they quote parses with
the CLI's own parser (nothing runs), and the published tables agree with the committed result
files they come from: the README's headline table is the benchmark leaderboard's first task
(docs/results/leaderboard/episodes.csv), the Results page's paper-scale tables the sweep's
(docs/results/paper-sweep/*.csv). The tables `agent-envs tables` renders (env options, the
shared policy across N, apg's, ...) are checked digit for digit in tests/test_published_tables.py.

A number in the README counts as agreeing when it is the source value rounded to the digits
printed (|printed - source| <= half a unit of the last printed digit).
"""

from __future__ import annotations

import csv
import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("**/*.md"))]
RESULTS = ROOT / "docs" / "results" / "paper-sweep"
APG_RESULTS = ROOT / "docs" / "results" / "apg" / "results.json"
#: where the sweep's full tables live (the README is a landing page with the headline table)
RESULTS_PAGE = ROOT / "docs" / "results.md"

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


def read_csv(name: str) -> list[dict[str, str]]:
    with open(RESULTS / name, newline="") as f:
        return list(csv.DictReader(f))


def agrees(printed: str, value: float, scale: float = 1.0) -> bool:
    """`printed` (e.g. "0.06419", "+309%", "3.30") is value * scale rounded to its digits."""
    text = printed.strip().replace("+", "").replace("%", "").replace("\u2212", "-")
    decimals = len(text.split(".")[1]) if "." in text else 0
    if "e" in text.lower():
        mantissa = text.lower().split("e")[0]
        decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
        exponent = int(text.lower().split("e")[1])
        return abs(float(text) - value * scale) <= 0.5 * 10.0 ** (exponent - decimals) * 1.0001
    return abs(float(text) - value * scale) <= 0.5 * 10.0 ** (-decimals) * 1.0001


def readme_table(
    after_heading: str, first_header_cell: str, page: Path = RESULTS_PAGE
) -> list[list[str]]:
    """The rows (cells stripped of ** and whitespace) of the first table of `page` under the
    heading `after_heading` whose header starts with `first_header_cell`."""
    text = page.read_text()
    section = text[text.index(after_heading) :]
    lines = section.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(f"| {first_header_cell} |"))
    rows = []
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        rows.append([cell.strip().replace("**", "") for cell in line.strip("|").split("|")])
    return rows


def _numbers(cell: str) -> list[str]:
    return re.findall(r"[+-]?\d+(?:\.\d+)?(?:e[+-]?\d+)?%?", cell)


def test_paper_sweep_main_table_matches_the_result_files():
    across = {(r["setting"], r["policy"]): r for r in read_csv("across_seeds.csv")}
    summary = {r["policy"]: r for r in read_csv("summary.csv")}
    walls: dict[str, list[float]] = {}
    for r in read_csv("trial_wall_times.csv"):
        if r["setting"] == "main":
            walls.setdefault(r["policy"], []).append(float(r["wall time [s]"]))
    rows = readme_table("## Results at the paper's scale", "policy")
    assert len(rows) == 11
    for cells in rows:
        policy = cells[0].split()[0]
        a = across[("main", policy)]
        assert agrees(cells[1], float(a["mean_cost"])), (policy, cells[1])
        # gap to optimal: a reference's own, or the mean (and range) of the seeds' gaps
        if policy in summary:
            gaps = [float(summary[policy]["gap_to_optimal"])]
        else:
            gaps = [float(summary[f"{policy} (seed {s})"]["gap_to_optimal"]) for s in range(3)]
        gap_numbers = _numbers(cells[2])
        pooled = sum(gaps) / len(gaps)
        if gap_numbers[0] not in ("0", "-0.00%"):
            assert agrees(gap_numbers[0], pooled, 100.0), (policy, cells[2], pooled)
        else:
            assert abs(pooled) < 5e-5, (policy, pooled)
        if len(gaps) == 3:
            assert agrees(gap_numbers[1], min(gaps), 100.0), (policy, cells[2])
            assert agrees(gap_numbers[2], max(gaps), 100.0), (policy, cells[2])
        iqm = _numbers(cells[3])
        assert agrees(iqm[0], float(a["iqm_cost"])), (policy, cells[3])
        if len(iqm) == 3:
            assert agrees(iqm[1], float(a["iqm_cost_ci_low"])), (policy, cells[3])
            assert agrees(iqm[2], float(a["iqm_cost_ci_high"])), (policy, cells[3])
        if cells[4] != "-":
            assert agrees(cells[4], float(a["poi_vs_proportional"])), (policy, cells[4])
        wall = [float(w) for w in _numbers(cells[5].split("s")[0].replace("-", " "))]
        assert agrees(f"{wall[0]:.0f}", min(walls[policy])), (policy, cells[5])
        assert agrees(f"{wall[-1]:.0f}", max(walls[policy])), (policy, cells[5])


def test_paper_sweep_contrast_costs_match_the_result_files():
    """The contrasts' mean costs (learner and optimum per setting) and the main setting's gaps."""
    across = {(r["setting"], r["policy"]): r for r in read_csv("across_seeds.csv")}
    summary = {r["policy"]: r for r in read_csv("summary.csv")}
    rows = readme_table("The contrasts (same test seeds", "setting")
    assert [cells[0].split(":")[0] for cells in rows] == [
        "main",
        "eps1",
        "bound150",
        "em-to-serb",
    ]
    for cells in rows:
        setting, learner = cells[0].split(":")[0], cells[1].split()[0]
        assert agrees(cells[2], float(across[(setting, learner)]["mean_cost"])), cells
        assert agrees(cells[3], float(across[(setting, "optimal")]["mean_cost"])), cells
    main = rows[0]
    learner = main[1].split()[0]
    gaps = [float(summary[f"{learner} (seed {s})"]["gap_to_optimal"]) for s in range(3)]
    assert agrees(_numbers(main[4])[0], sum(gaps) / 3, 100.0), main
    for cell, policy in zip(main[5:8], ("proportional", "turnpike", "zero"), strict=True):
        assert agrees(_numbers(cell)[0], float(summary[policy]["gap_to_optimal"]), 100.0), cell


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


def test_table_checker_can_fail():
    """`agrees` rejects a number off by one unit of its last digit (the 0.1092 vs 0.1041 kind
    of drift), so the table tests above are not vacuous."""
    assert agrees("0.1041", 0.10413) and not agrees("0.1092", 0.10413)
    assert agrees("+309%", 3.0899, 100.0) and not agrees("+310%", 3.0849, 100.0)
    assert agrees("3.30", 3.2984) and not agrees("3.30", 3.31)
