"""Test-session settings: one BLAS/OpenMP thread and a headless matplotlib backend.

The networks and matrices in the tests are small; on 2 shared cores a second thread only adds
contention (a 64x64 torch forward pass took 5.5 ms with 2 threads instead of 17 us with one).
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MPLBACKEND", "Agg")
