"""Shared fixtures: BLAS threads pinned so that timings in benchmarks are comparable."""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MPLBACKEND", "Agg")
