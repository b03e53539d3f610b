"""docs/benchmarks.md's "Current figures", read from the committed outputs of the benchmarks.

Each benchmark script prints its ratios (every one measured against a baseline in the same
process); three runs of each, one after the other on one machine, are committed as
``docs/results/benchmarks/runR/SCRIPT.txt`` (R = 1, 2, 3). A figure of the table is one
printed number per run, found by a regular expression in that script's output (`FIGURES`);
its cell is the median of the three runs with their range, ``median (low-high)``, as printed
(the median run's own digits). Timings are the machine's: another machine gives other digits,
which is why the table is rendered from the outputs of one session instead of typed.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

#: the scripts of the table, in its order (each with its command-line options)
SCRIPTS = (
    ("bench_cold_start", ""),
    ("bench_step_floor", ""),
    ("bench_kernel_pass", ""),
    ("bench_phi_actions", ""),
    ("bench_vector_batching", ""),
    ("bench_vector_env", " --skip-ppo"),
    ("bench_threads", ""),
    ("bench_step_breakdown", ""),
    ("bench_large_swarms", " --quick"),
)
RUNS = ("run1", "run2", "run3")

#: an extractor: the script and a pattern whose first group is the number, or a function of
#: the output text giving the number as text
Extract = tuple[str, str | Callable[[str], str]]


@dataclass(frozen=True)
class Figure:
    """One row: the question (empty: the row above's), what is measured, the extractors of
    its values (cells joined by "; "), a suffix printed after each value (" %")."""

    question: str
    figure: str
    values: tuple[Extract, ...]
    suffix: str = ""


def _row(label: str, column: int = 1) -> str:
    """A Markdown table row starting with `label`: the number in its `column`-th value cell."""
    cells = r"\|[^|\n]*" * (column - 1)
    return rf"^\| {re.escape(label)} {cells}\| ([\d.,]+)"


def _matrix_free_scaling(text: str) -> str:
    """The matrix-free step's time at N = 1e5 over N = 1e4 (section 1 of the large swarms)."""
    times: dict[str, str] = {}
    for size, seconds in re.findall(r"^\| (1e\+0[45]) \| ([\d.]+) \|", text, re.M):
        times.setdefault(size, seconds)  # table 1's row (table 3, d = 2, repeats the sizes)
    return f"{float(times['1e+05']) / float(times['1e+04']):.1f}"


def _native_compiled_share(text: str) -> str:
    """The compiled calls' share in the step breakdown's second table (the native env)."""
    shares = re.findall(r"^\| compiled \| (\d+) %", text, re.M)
    if len(shares) < 2:
        raise ValueError("the step breakdown printed no native env table")
    return shares[1]


FIGURES = (
    Figure(
        "Are an env's first steps slower in a fresh process?",
        "cold / warm, first 100 steps, paper SERB; paper EM",
        (("bench_cold_start", _row("paper | serb")), ("bench_cold_start", _row("paper | em"))),
    ),
    Figure(
        "",
        "the same, quick setting (N = 10, m = 20) SERB; EM",
        (("bench_cold_start", _row("quick | serb")), ("bench_cold_start", _row("quick | em"))),
    ),
    Figure(
        "How fast is one env step against its floor?",
        "SERB env step / EM env step, paper",
        (("bench_step_floor", _row("SERB env step / EM env step")),),
    ),
    Figure(
        "",
        "the same with no interpreter time beyond EM's",
        (("bench_step_floor", r"no interpreter time beyond EM's: ([\d.]+)"),),
    ),
    Figure(
        "",
        "EM env step / the env's compiled kernel pass (kernel matrix + drift, 20 paths)",
        (("bench_step_floor", _row("EM env step / the env's kernel pass")),),
    ),
    Figure(
        "",
        "EM env step / the same floor in in-place numpy; in plain numpy",
        (
            ("bench_step_floor", _row("EM env step / in-place numpy kernel + drift")),
            ("bench_step_floor", _row("EM env step / plain numpy kernel + drift")),
        ),
    ),
    Figure(
        "",
        "one bare SERB step / one bare EM step, N = 100, 1 path",
        (("bench_step_floor", _row("one bare SERB step / one bare EM step (N = 100, 1 path)")),),
    ),
    Figure(
        "",
        "SERB / EM in a native vector env of 16 paper envs",
        (("bench_step_floor", _row("SERB / EM, native vector env of 16 paper envs")),),
    ),
    Figure(
        "How fast is the compiled kernel pass?",
        "in-place numpy pass / compiled pass, per member, N = 100",
        (("bench_kernel_pass", _row("100", 1)),),
    ),
    Figure(
        "",
        "numpy `P @ q` / compiled symmetric product (`lower_product`), N = 100",
        (("bench_kernel_pass", _row("100", 3)),),
    ),
    Figure(
        "",
        "two products / one pair pass (`lower_product_pair`, d > 1), N = 30; 100; 300",
        tuple(("bench_kernel_pass", _row(n, 4)) for n in ("30", "100", "300")),
    ),
    Figure(
        "Which phi-action strategy for SERB?",
        "fused compiled step (the default) / EM env step",
        (("bench_phi_actions", _row("fused compiled step | fused-lanczos; fallbacks: none")),),
    ),
    Figure(
        "",
        "compiled Lanczos; numpy Lanczos / fused step",
        (
            ("bench_phi_actions", _row("compiled Lanczos | compiled-lanczos; fallbacks: none", 2)),
            ("bench_phi_actions", _row("numpy Lanczos | lanczos; fallbacks: none", 2)),
        ),
    ),
    Figure(
        "",
        '`phi_method="eigh"`; `"expm"` / fused step',
        (
            ("bench_phi_actions", _row("eigh per member | eigh; fallbacks: none", 2)),
            ("bench_phi_actions", _row("expm per member | expm; fallbacks: none", 2)),
        ),
    ),
    Figure(
        "Does the native vector env beat single envs?",
        "native / B single envs in a loop, SERB, 1 path: B = 16; 64",
        (
            ("bench_vector_batching", _row("1 | 16")),
            ("bench_vector_batching", _row("1 | 64")),
        ),
    ),
    Figure(
        "",
        "the same at 20 paths: B = 16; 64",
        (
            ("bench_vector_batching", _row("20 | 16")),
            ("bench_vector_batching", _row("20 | 64")),
        ),
    ),
    Figure(
        "",
        "native / SyncVectorEnv, B = 64, 1 path",
        (("bench_vector_batching", r"native / SyncVectorEnv = ([\d.]+)"),),
    ),
    Figure(
        "",
        "native with its compiled step / with it off (numpy step), B = 64, 1 path",
        (
            (
                "bench_vector_batching",
                r"compiled step / numpy step \(compiled step off\) = ([\d.]+)",
            ),
        ),
    ),
    Figure(
        "",
        "kernel + drift share of the native step, B = 64, 1 path",
        (("bench_vector_batching", r"^\| 1 \| 64 \| [\d.]+ \| (\d+) %"),),
        " %",
    ),
    Figure(
        "The same against SyncVectorEnv, per CPU second",
        "native / Sync, SERB, B = 16; 64; 256",
        tuple(("bench_vector_env", _row(f"serb (auto) | {b}", 3)) for b in (16, 64, 256)),
    ),
    Figure(
        "",
        'the same with `phi_method="eigh"`, B = 16; 256; EM, B = 16; 256',
        tuple(
            ("bench_vector_env", _row(f"{name} | {b}", 3))
            for name in ("serb (eigh)", "em")
            for b in (16, 256)
        ),
    ),
    Figure(
        "What do numba threads add?",
        "2 threads / 1 thread: native SERB B = 64, 1 path; B = 16, 20 paths; paper single env",
        (
            ("bench_threads", _row("serb | 1 | 64 | SyncVectorEnv", 3)),
            ("bench_threads", _row("serb | 20 | 16 | 16 single envs in a loop", 3)),
            ("bench_threads", r"2 threads / 1: SERB ([\d.]+)"),
        ),
    ),
    Figure(
        "Where does a step's time go?",
        "compiled calls' share of the step: paper single env SERB; EM; native env B = 64, 1 path",
        (
            ("bench_step_breakdown", r"^\| compiled \| (\d+) % \| \d+ %"),
            ("bench_step_breakdown", r"^\| compiled \| \d+ % \| (\d+) %"),
            ("bench_step_breakdown", _native_compiled_share),
        ),
        " %",
    ),
    Figure(
        "How far do large swarms go matrix-free? (`--quick`)",
        "one SERB step, d = 1, 1 path: dense / matrix-free at N = 1,000; 10,000",
        (
            ("bench_large_swarms", _row("1e+03", 6)),
            ("bench_large_swarms", _row("1e+04", 6)),
        ),
    ),
    Figure(
        "",
        "matrix-free step at N = 100,000 / at N = 10,000 (10x the agents)",
        (("bench_large_swarms", _matrix_free_scaling),),
    ),
)


def extract(text: str, how: str | Callable[[str], str]) -> str:
    """The number `how` finds in one output `text`, as printed (thousands separators kept)."""
    if callable(how):
        return how(text)
    match = re.search(how, text, re.M)
    if match is None:
        raise ValueError(f"no match for {how!r} in a benchmark output")
    return match.group(1)


def _value(number: str) -> float:
    return float(number.replace(",", ""))


def cell(printed: list[str], suffix: str = "") -> str:
    """``median (low-high)`` of the runs' printed numbers (just the number when they agree)."""
    ordered = sorted(printed, key=_value)
    median, low, high = ordered[len(ordered) // 2], ordered[0], ordered[-1]
    if low == high:
        return f"{median}{suffix}"
    return f"{median}{suffix} ({low}-{high}{suffix})"


def benchmark_figures_table(*files: Path) -> str:
    """The table from the outputs ``.../runR/SCRIPT.txt`` (every script of every run)."""
    outputs: dict[tuple[str, str], str] = {
        (path.parent.name, path.stem): path.read_text() for path in files
    }
    runs = sorted({run for run, _ in outputs})
    commands = {script: f"`python benchmarks/{script}.py{options}`" for script, options in SCRIPTS}
    lines = [
        "| question | figure (ratio in the same run) | value | command |",
        "|---|---|---|---|",
    ]
    last_command = None
    for figure in FIGURES:
        cells = []
        for script, how in figure.values:
            printed = [extract(outputs[run, script], how) for run in runs]
            cells.append(cell(printed, figure.suffix))
        command = commands[figure.values[0][0]]
        shown = command if command != last_command else ""
        last_command = command
        lines.append(f"| {figure.question} | {figure.figure} | {'; '.join(cells)} | {shown} |")
    return "\n".join(lines)


def printed_tables(text: str) -> list[str]:
    """The Markdown tables a benchmark printed, in order: runs of lines starting with "|"."""
    tables: list[list[str]] = []
    previous = False
    for line in text.splitlines():
        is_row = line.startswith("|")
        if is_row and not previous:
            tables.append([])
        if is_row:
            tables[-1].append(line.rstrip())
        previous = is_row
    return ["\n".join(rows) for rows in tables if len(rows) >= 2]


def printed_table(path: Path, index: int = 0) -> str:
    """The `index`-th Markdown table of a committed benchmark output, verbatim: a section of
    docs/benchmarks.md or docs/large-swarms.md that quotes one run of a script."""
    tables = printed_tables(Path(path).read_text())
    if not -len(tables) <= index < len(tables):
        raise ValueError(f"{path}: printed {len(tables)} tables, no table {index}")
    return tables[index]


def printed_text(path: Path) -> str:
    """A committed benchmark output whose figures are lines, not a table: verbatim, fenced."""
    return "```text\n" + Path(path).read_text().strip() + "\n```"


def benchmark_files(root: str) -> tuple[str, ...]:
    """The committed outputs under `root` (``docs/results/benchmarks``), run by run."""
    return tuple(f"{root}/{run}/{script}.txt" for run in RUNS for script, _ in SCRIPTS)


__all__ = [
    "FIGURES",
    "Figure",
    "benchmark_figures_table",
    "benchmark_files",
    "cell",
    "extract",
    "printed_table",
    "printed_tables",
    "printed_text",
]
