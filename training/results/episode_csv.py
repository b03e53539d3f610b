"""Per-episode CSV files that round-trip: floats written in repr, read back to the same bits.

The benchmark scripts whose published tables are means or extremes over episodes write one
row per episode (and, where a figure pools steps across episodes, one row per step) beside
their summary, so that the summary, and the table rendered from it, can be recomputed from
what is committed. ``repr(float)`` is the shortest string that parses back to the same
double, so an aggregate recomputed from the file equals the one computed in memory, bit for
bit, when it runs the same arithmetic in the same order.
"""

from __future__ import annotations

import csv
import io
import numbers
from collections.abc import Iterable, Mapping
from pathlib import Path

#: a cell: text, an integer (seeds, sizes, counts) or a float (costs, controls)
Cell = str | int | float
Row = dict[str, Cell]


def _text(value: object) -> str:
    if isinstance(value, bool):
        return str(int(value))
    if isinstance(value, numbers.Integral):
        return str(int(value))
    if isinstance(value, numbers.Real):  # numpy floats too, as the double they hold
        return repr(float(value))
    return "" if value is None else str(value)


def rows_text(rows: Iterable[Mapping[str, object]]) -> str:
    """`rows` (same keys, in the first row's order) as CSV text; floats in repr, booleans as
    0/1, None as an empty cell."""
    rows = list(rows)
    if not rows:
        raise ValueError("rows: no rows to write")
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=list(rows[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows({k: _text(v) for k, v in row.items()} for row in rows)
    return out.getvalue()


def write_rows(path: str | Path, rows: Iterable[Mapping[str, object]]) -> Path:
    """Write `rows` to the CSV `path` as `rows_text` writes them. Returns `path`."""
    rows = list(rows)
    if not rows:
        raise ValueError(f"{path}: no rows to write")
    path = Path(path)
    with open(path, "w", newline="") as handle:
        handle.write(rows_text(rows))
    return path


def _typed(text: str) -> Cell | None:
    if text == "":
        return None
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def read_rows(path: str | Path) -> list[dict[str, Cell | None]]:
    """The rows of a CSV written by `write_rows`, typed back: integers, floats (the same bits),
    text, and None for an empty cell."""
    with open(path, newline="") as handle:
        return [{k: _typed(v) for k, v in row.items()} for row in csv.DictReader(handle)]


__all__ = ["Cell", "Row", "read_rows", "rows_text", "write_rows"]
