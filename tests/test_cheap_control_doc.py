"""The figures docs/cheap-control-bound.md quotes in prose, recomputed from its own table."""

from __future__ import annotations

import re
from pathlib import Path

DOC = Path(__file__).resolve().parents[1] / "docs" / "cheap-control-bound.md"


def _table() -> list[dict[str, str]]:
    lines = [line for line in DOC.read_text().splitlines() if line.startswith("| ")]
    header = [cell.strip() for cell in lines[0].strip("|").split("|")]
    rows = []
    for line in lines[1:]:
        cells = [cell.strip() for cell in line.strip("|").split("|")]
        if len(cells) == len(header) and not set(cells[0]) <= {"-"}:
            rows.append(dict(zip(header, cells, strict=True)))
    return rows


def test_noise_part_over_the_floor_is_the_quoted_range():
    """'the noise part V(sigma) - V(0) is 0.92 to 1.19 times F for T = 1 .. 8' (section 4)."""
    ratios = [
        float(row["noise_part"]) / float(row["floor"])
        for row in _table()
        if row["case"] in ("V(T)", "x0=xbar") and float(row["sigma"]) > 0 and float(row["T"]) >= 1
    ]
    assert len(ratios) == 8
    quoted = re.search(
        r"noise part V\(sigma\) - V\(0\) is ([\d.]+) to ([\d.]+) times F", DOC.read_text()
    )
    assert quoted is not None
    assert (round(min(ratios), 2), round(max(ratios), 2)) == (
        float(quoted.group(1)),
        float(quoted.group(2)),
    )
    within = re.search(r"within (\d+)-(\d+)%; the `V\(T\)`", DOC.read_text())
    assert within is not None
    deviations = [abs(r - 1) * 100 for r in ratios]
    assert (round(min(deviations)), round(max(deviations))) == (
        int(within.group(1)),
        int(within.group(2)),
    )
