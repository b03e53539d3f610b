"""``benchmarks/max_control.py``'s per-seed file and the summary lines it prints from it.

One row per turnpike-controlled run (kernel, target xbar, integrator, paths, validation seed):
``peak`` max_{n,k} |u_k^n| of the cheap control, ``peak_time`` the t of that maximum,
``turnpike_time`` tbar of the run and ``diverged`` (0/1). `setting_lines` groups the rows by
setting (in the rows' order) and prints, per setting, the worst run's peak, the median peak
over the seeds, the worst run's t(max) and tbar, and how many runs diverged: the script's
output ``max_control.txt``, whose peaks docs/envs/gymnasium.md's table rounds to one decimal.
The script prints the same function of the same rows, so the file reproduces its output
character for character.
"""

from __future__ import annotations

import numpy as np

from agent_envs.training.results.episode_csv import Row

#: the per-seed file's name, written beside ``max_control.txt``
SEEDS_FILE = "episodes.csv"
#: the printed table's header line (after the script's first line)
HEADER = (
    f"{'kernel':>12} {'xbar':>5} {'integr':>6} {'paths':>5} | {'max|u|':>7} "
    f"{'median':>7} {'t(max)':>6} {'tbar':>5} {'div':>3}"
)


def seed_row(
    kernel: str, target: float, integrator: str, n_paths: int, seed: int, run: tuple
) -> Row:
    """The row of one run: `run` is ``peak_control``'s (peak, t of the peak, tbar, diverged)."""
    peak, peak_time, tbar, diverged = run
    return {
        "kernel": kernel,
        "target": float(target),
        "integrator": integrator,
        "n_paths": n_paths,
        "seed": seed,
        "peak": float(peak),
        "peak_time": float(peak_time),
        "turnpike_time": float(tbar),
        "diverged": int(bool(diverged)),
    }


def _settings(rows: list[Row]) -> dict[tuple, list[Row]]:
    settings: dict[tuple, list[Row]] = {}
    for row in rows:
        key = (row["kernel"], row["target"], row["integrator"], row["n_paths"])
        settings.setdefault(key, []).append(row)
    return settings


def setting_line(runs: list[Row]) -> str:
    """The printed line of one setting's runs: its worst (first largest) peak, the median
    peak, the worst run's t(max) and tbar, and the count of diverged runs."""
    first = runs[0]
    peaks = np.array([float(r["peak"]) for r in runs])
    worst = runs[int(np.argmax(peaks))]
    return (
        f"{first['kernel']:>12} {first['target']:>5} {first['integrator']:>6} "
        f"{first['n_paths']:>5} | {float(worst['peak']):7.2f} {np.median(peaks):7.2f} "
        f"{float(worst['peak_time']):6.2f} {float(worst['turnpike_time']):5.3f} "
        f"{sum(int(r['diverged']) for r in runs):>3}"
    )


def setting_lines(rows: list[Row]) -> list[str]:
    """The header and one `setting_line` per setting, in the rows' order."""
    return [HEADER, *(setting_line(runs) for runs in _settings(rows).values())]


def largest_peak(rows: list[Row]) -> float:
    """The largest |u| over every run."""
    return max(float(r["peak"]) for r in rows)


__all__ = ["HEADER", "SEEDS_FILE", "largest_peak", "seed_row", "setting_line", "setting_lines"]
