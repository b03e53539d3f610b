"""docs/benchmarks.md's current figures from the benchmarks' committed outputs."""

from __future__ import annotations

import pytest

from agent_envs.training.results.benchmark_figures import (
    FIGURES,
    SCRIPTS,
    cell,
    extract,
    printed_table,
)


def test_cell_is_the_median_run_with_the_range_as_printed():
    assert cell(["2.08", "1.94", "2.09"]) == "2.08 (1.94-2.09)"
    assert cell(["0.8", "0.8", "0.8"]) == "0.8"
    assert cell(["31", "28", "29"], " %") == "29 % (28-31 %)"
    assert cell(["1,579", "37,733", "2,000"]) == "2,000 (1,579-37,733)"  # numeric order


def test_extract_names_a_missing_figure():
    assert (
        extract(
            "| SERB env step / EM env step | 2.08 |", r"\| SERB env step / EM env step \| ([\d.]+)"
        )
        == "2.08"
    )
    with pytest.raises(ValueError, match="no match"):
        extract("nothing printed", r"ratio ([\d.]+)")


def test_every_figure_reads_a_script_of_the_table():
    scripts = {script for script, _ in SCRIPTS}
    assert all(script in scripts for figure in FIGURES for script, _ in figure.values)


def test_printed_table_is_the_nth_markdown_table_verbatim(tmp_path):
    out = tmp_path / "bench.txt"
    out.write_text("title\n\n| a | b |\n|---|---|\n| 1 | 2 |\n\nnote | not a row\n| c |\n|---|\n")
    assert printed_table(out) == "| a | b |\n|---|---|\n| 1 | 2 |"
    assert printed_table(out, 1) == "| c |\n|---|"
    with pytest.raises(ValueError, match="printed 2 tables"):
        printed_table(out, 2)
