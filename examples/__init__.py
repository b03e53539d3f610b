"""Standalone example scripts (importable as ``examples.NAME`` from the repo root, for scoring)."""
