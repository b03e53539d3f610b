"""Headless matplotlib for the figures the reproductions and reports write."""

from __future__ import annotations

from typing import Any


def headless_pyplot() -> Any:
    """`matplotlib.pyplot` on the Agg backend (files only, no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt
