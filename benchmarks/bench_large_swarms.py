"""Benchmark of large swarms: one SERB step, matrix-free vs dense, N = 10^3 .. 10^6.

Run:  python benchmarks/bench_large_swarms.py              (about 4 minutes on 2 cores)
      python benchmarks/bench_large_swarms.py --quick      (N <= 10^5, d = 2 at N = 2000,
                                                            mean field up to 10^4)

BLAS is pinned to one thread (OPENBLAS_NUM_THREADS overrides it). Every ratio is between two
timings of the same run. Tables:

1. One SERB step (frozen L, d = 1, eps = 0.05, alpha = 0.1, sigma = 0.01, tau = 0.02, 1 path):
   the median over the first `--steps` steps from x uniform on [-1, 1] ("spread"), and one
   step from x uniform on [-alpha/2, alpha/2] ("clustered": L(x) at its stiffest, the Krylov
   space largest), with the number of operator products of the step. The dense path where it
   fits (`--dense-max`), and the ratio dense / matrix-free. A size whose predicted time
   (the previous size's, scaled linearly) exceeds `--budget` seconds is skipped, and said so.
   Then the log-log slope of the spread step time from 10^4 to 10^6.
2. The crossover of "auto": the same spread step, dense vs matrix-free, N = 100 .. 1000.
3. d = 2, N = 2000 .. 10^5: one SERB step, the 2-D grid sum vs the chunked sum (N <= 2 10^4)
   vs dense (N <= `--dense-max`).
4. Why the grid sum and not a non-uniform FFT: the grid kernel sum at N = 10^6 (build and one
   product) next to one finufft type-1 + type-2 pair on the same points (tolerance 1e-12, 512
   modes, 1 thread), which a Fourier-based sum would need per product on top of its near-field
   correction. Skipped when finufft is not installed (``pip install finufft``).
5. Mean-field check: for N = 10^3 .. `--mean-field-max`, SERB (m = 50, T = 1, sigma = 0.01)
   from N points drawn uniform on [-1, 1] (a new sample per N): the Wasserstein-1 distance of
   the empirical distribution at t = 0, T/2 and T to that of the largest N, and the log-log
   slopes against N; `--figure PATH` saves the plot. eps = 10 here, not 0.05: at eps = 0.05
   the swarm collapses within a few steps and SERB's e^{tau L} (||tau L|| ~ 40 at consensus)
   damps the noise to ~1e-18, so every later distribution is a point mass whose W1 is just
   the distance of the means; eps = 10 keeps a spread-out density up to T.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import math
import time

import numpy as np

from agent_envs import SwarmModel, SwarmParams, make_integrator
from agent_envs.dynamics import operators
from agent_envs.dynamics.kernel_sums import GridKernelSum

ALPHA, EPS, SIGMA, TAU = 0.1, 0.05, 0.01, 0.02
MEAN_FIELD_EPS = 10.0


class _ProductCounter:
    """Counts `LinearizationOperator.matvec` calls (Krylov products and the noise term)."""

    def __init__(self) -> None:
        self.count = 0
        self.original = operators.LinearizationOperator.matvec

    def __enter__(self):
        counter = self

        def matvec(op, v):
            counter.count += 1
            return counter.original(op, v)

        operators.LinearizationOperator.matvec = matvec
        return self

    def __exit__(self, *exc):
        operators.LinearizationOperator.matvec = self.original


def _steps(n: int, dim: int, mode: str, x0: np.ndarray, n_steps: int, seed: int = 0):
    """Seconds of each of `n_steps` SERB steps from x0, and the operator products of each."""
    params = SwarmParams(n_agents=n, dim=dim, alpha=ALPHA, epsilon=EPS, sigma=SIGMA)
    model = SwarmModel(params, mode)
    serb = make_integrator("serb")
    rng = np.random.default_rng(seed)
    x = x0.copy()
    times, products = [], []
    for k in range(n_steps):
        dw = math.sqrt(TAU) * rng.standard_normal(x.shape)
        with _ProductCounter() as counter:
            start = time.perf_counter()
            x = serb.step(model, x, None, k * TAU, TAU, dw)
            times.append(time.perf_counter() - start)
        products.append(counter.count)
    return times, products


def _spread(n: int, dim: int = 1, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1.0, 1.0, (1, n, dim))


def _clustered(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-ALPHA / 2, ALPHA / 2, (1, n, 1))


def bench_scaling(sizes, steps: int, dense_max: int, budget: float) -> None:
    print("\n## 1. One SERB step, d = 1, eps = 0.05, 1 path")
    print(
        "| N | matrix-free spread [s] | products | clustered [s] | products | dense spread [s] "
        "| dense / matrix-free |"
    )
    print("|---|---|---|---|---|---|---|")
    measured: dict[int, float] = {}
    clustered: dict[int, float] = {}
    last = None
    for n in sizes:
        if last is not None:
            predicted = measured[last] * n / last * (steps + 1)
            if predicted > budget:
                print(
                    f"| {n:.0e} | skipped: predicted {predicted:.0f} s > budget {budget:.0f} s "
                    "| | | | | |"
                )
                continue
        t_free, p_free = _steps(n, 1, "matrix_free", _spread(n), steps)
        t_clu, p_clu = _steps(n, 1, "matrix_free", _clustered(n), 1)
        measured[n] = float(np.median(t_free))
        clustered[n] = t_clu[0]
        last = n
        dense = ratio = "-"
        if n <= dense_max:
            t_dense, _ = _steps(n, 1, "dense", _spread(n), steps)
            dense = f"{np.median(t_dense):.4f}"
            ratio = f"{np.median(t_dense) / measured[n]:.1f}"
        print(
            f"| {n:.0e} | {measured[n]:.4f} | {int(np.median(p_free))} | {t_clu[0]:.4f} "
            f"| {p_clu[0]} | {dense} | {ratio} |"
        )
    if 10**4 in measured and 10**6 in measured:
        for name, times in (("spread", measured), ("clustered", clustered)):
            slope = math.log(times[10**6] / times[10**4]) / math.log(100.0)
            print(f"\nlog-log slope of the {name} step time, N = 1e4 -> 1e6: {slope:.2f}")
    else:
        print("\nlog-log slope 1e4 -> 1e6: not measured (10^4 or 10^6 not run or skipped)")


def bench_crossover(sizes, steps: int, path_counts=(1, 20)) -> None:
    """Dense against matrix-free SERB steps from a spread start, d = 1, per path count: the
    crossover `AUTO_MATRIX_FREE_MIN_AGENTS[1]` is chosen from (the dense step's cost grows
    with the paths faster than the matrix-free one's)."""
    print("\n## 2. Crossover of linear_operator='auto' (spread step, d = 1)")
    print("| N | paths | dense [ms] | matrix-free [ms] | dense / matrix-free |")
    print("|---|---|---|---|---|")
    for n in sizes:
        for paths in path_counts:
            x0 = np.broadcast_to(_spread(n), (paths, n, 1)).copy()
            t_dense = np.median(_steps(n, 1, "dense", x0, steps)[0][1:])
            t_free = np.median(_steps(n, 1, "matrix_free", x0, steps)[0][1:])
            print(
                f"| {n} | {paths} | {1e3 * t_dense:.2f} | {1e3 * t_free:.2f} | "
                f"{t_dense / t_free:.2f} |"
            )
    print(f"(auto: matrix-free from N = {operators.AUTO_MATRIX_FREE_MIN_AGENTS[1]} for d = 1)")


def bench_two_dimensions(sizes, dense_max: int, chunked_max: int) -> None:
    print("\n## 3. d = 2: one SERB step from x uniform on [-1, 1]^2, 1 path")
    print("| N | grid [s] | products | chunked [s] | dense [s] | chunked / grid | dense / grid |")
    print("|---|---|---|---|---|---|---|")
    saved = operators.GRID_MIN_AGENTS[2]
    for n in sizes:
        try:
            operators.GRID_MIN_AGENTS[2] = 0
            t_grid, p_grid = _steps(n, 2, "matrix_free", _spread(n, 2), 1)
            chunked = dense = ratio_c = ratio_d = "-"
            if n <= chunked_max:
                operators.GRID_MIN_AGENTS[2] = 10**12
                t_chunked = _steps(n, 2, "matrix_free", _spread(n, 2), 1)[0][0]
                chunked, ratio_c = f"{t_chunked:.3f}", f"{t_chunked / t_grid[0]:.2f}"
        finally:
            operators.GRID_MIN_AGENTS[2] = saved
        if n <= dense_max:
            t_dense = _steps(n, 2, "dense", _spread(n, 2), 1)[0][0]
            dense, ratio_d = f"{t_dense:.3f}", f"{t_dense / t_grid[0]:.2f}"
        print(
            f"| {n:.0e} | {t_grid[0]:.3f} | {p_grid[0]} | {chunked} | {dense} | {ratio_c} "
            f"| {ratio_d} |"
        )
    print(
        f"(auto: matrix-free from N = {operators.AUTO_MATRIX_FREE_MIN_AGENTS[2]}, the grid from "
        f"N = {saved}, chunked below)"
    )


def bench_finufft(n: int) -> None:
    print(f"\n## 4. Grid kernel sum vs finufft transforms, N = {n}, 1 thread")
    try:
        import finufft
    except ImportError:
        print("finufft not installed: skipped (pip install finufft)")
        return
    rng = np.random.default_rng(0)
    x = rng.uniform(-1.0, 1.0, n)
    v = rng.standard_normal((n, 1))
    start = time.perf_counter()
    grid = GridKernelSum(x, [lambda r: 1.0 / (ALPHA**2 + r * r)], 1.0 / EPS, ALPHA)
    build = time.perf_counter() - start
    grid(v)
    start = time.perf_counter()
    for _ in range(3):
        grid(v)
    product = (time.perf_counter() - start) / 3
    theta = (x * (np.pi / 2.0)).astype(float)  # points scaled into [-pi, pi)
    c = v[:, 0].astype(complex)
    opts = dict(eps=1e-12, nthreads=1)
    finufft.nufft1d1(theta, c, 512, **opts)
    start = time.perf_counter()
    for _ in range(3):
        modes = finufft.nufft1d1(theta, c, 512, **opts)
        finufft.nufft1d2(theta, modes, **opts)
    pair = (time.perf_counter() - start) / 3
    print("| grid build [s] | grid product [s] | finufft type 1 + type 2 [s] | finufft / grid |")
    print("|---|---|---|---|")
    print(f"| {build:.3f} | {product:.4f} | {pair:.4f} | {pair / product:.1f} |")


#: columns of the mean-field check's CSV (`--mean-field-csv`): one row per N and time
MEAN_FIELD_COLUMNS = ("n_agents", "time", "w1_to_reference", "std", "reference_n", "wall_time_s")


def bench_mean_field(sizes, figure: str | None, csv_path: str | None = None) -> None:
    from scipy.stats import wasserstein_distance

    from agent_envs import simulate

    print(f"\n## 5. Mean-field check: W1 to the empirical distribution of N = {sizes[-1]:.0e}")
    starts, walls = {}, {}
    for n in sizes:
        params = SwarmParams(n_agents=n, alpha=ALPHA, epsilon=MEAN_FIELD_EPS, sigma=SIGMA)
        start = time.perf_counter()
        traj = simulate(params, "serb", n_steps=50, n_paths=1, seed=n)
        wall = time.perf_counter() - start
        assert not traj.diverged
        starts[n] = {t: traj.positions[k, 0, :, 0] for t, k in (("0", 0), ("T/2", 25), ("T", -1))}
        walls[n] = wall
        print(f"(N = {n:.0e}: 50 SERB steps in {wall:.1f} s)")
    ref = sizes[-1]
    print("| N | W1 at t = 0 | W1 at T/2 | W1 at T | std of x(T/2) | std of x(T) |")
    print("|---|---|---|---|---|---|")
    w = {t: {} for t in ("0", "T/2", "T")}
    for n in sizes[:-1]:
        for t in w:
            w[t][n] = wasserstein_distance(starts[n][t], starts[ref][t])
        print(
            f"| {n:.0e} | {w['0'][n]:.2e} | {w['T/2'][n]:.2e} | {w['T'][n]:.2e} "
            f"| {np.std(starts[n]['T/2']):.3f} | {np.std(starts[n]['T']):.3f} |"
        )
    print(
        f"| {ref:.0e} (reference) | 0 | 0 | 0 | {np.std(starts[ref]['T/2']):.3f} "
        f"| {np.std(starts[ref]['T']):.3f} |"
    )
    if csv_path:
        _write_mean_field(csv_path, sizes, starts, w, walls)
    if len(sizes) >= 3:
        ns = np.array(sizes[:-1], dtype=float)
        for t in w:
            slope = np.polyfit(np.log(ns), np.log([w[t][int(n)] for n in ns]), 1)[0]
            print(f"log-log slope of W1 at t = {t} against N: {slope:.2f}")
        print("(independent samples: about -0.5)")
    if figure:
        from matplotlib.figure import Figure

        fig = Figure(figsize=(8, 3.2))
        ax_cdf, ax_w = fig.subplots(1, 2)
        for n in sizes:
            xs = np.sort(starts[n]["T"])
            ax_cdf.plot(xs, np.linspace(0, 1, xs.size), label=f"N = {n:.0e}")
        ax_cdf.set(xlabel="x at T", ylabel="empirical CDF", title="SERB, eps = 10, m = 50, T = 1")
        ax_cdf.legend(fontsize=7)
        ns = sizes[:-1]
        for t in w:
            ax_w.loglog(ns, [w[t][n] for n in ns], "o-", label=f"W1 at t = {t}")
        ax_w.loglog(ns, [w["0"][ns[0]] * (n / ns[0]) ** -0.5 for n in ns], "k--", label="N^-1/2")
        ax_w.set(xlabel="N", ylabel=f"W1 to N = {ref:.0e}")
        ax_w.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(figure, dpi=110)
        print(f"figure: {figure}")


def _write_mean_field(path: str, sizes, starts, w, walls) -> None:
    """The mean-field check's rows (`MEAN_FIELD_COLUMNS`): per N (the reference's W1 is 0) and
    time t in {0, T/2, T}, W1 to the largest N and the sample's standard deviation, floats in
    repr (`episode_csv.write_rows`) so that docs/large-swarms.md's table renders from them."""
    from agent_envs.training.results.episode_csv import write_rows

    ref = sizes[-1]
    rows = [
        {
            "n_agents": n,
            "time": t,
            "w1_to_reference": 0.0 if n == ref else float(w[t][n]),
            "std": float(np.std(starts[n][t])),
            "reference_n": ref,
            "wall_time_s": round(walls[n], 1),
        }
        for n in sizes
        for t in ("0", "T/2", "T")
    ]
    assert tuple(rows[0]) == MEAN_FIELD_COLUMNS
    write_rows(path, rows)
    print(f"mean-field rows: {path}")


#: the benchmark's parts (`--parts`), in run order
PARTS = ("scaling", "crossover", "two-dimensions", "finufft", "mean-field")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="N <= 1e5, d = 2 at N = 2000")
    parser.add_argument("--steps", type=int, default=3, help="steps timed per size (median)")
    parser.add_argument("--dense-max", type=int, default=10**4, help="largest dense N")
    parser.add_argument("--budget", type=float, default=120.0, help="seconds per size")
    parser.add_argument("--mean-field-max", type=int, default=10**6, help="largest N of table 5")
    parser.add_argument("--figure", default=None, help="save the mean-field plot there")
    parser.add_argument(
        "--mean-field-csv", default=None, help="write the mean-field check's rows (CSV) there"
    )
    parser.add_argument(
        "--parts",
        nargs="+",
        choices=PARTS,
        default=list(PARTS),
        help="tables to run (default: all)",
    )
    args = parser.parse_args()
    sizes = [10**3, 10**4, 10**5] if args.quick else [10**3, 10**4, 10**5, 10**6]
    print(f"OPENBLAS_NUM_THREADS={os.environ['OPENBLAS_NUM_THREADS']}, cores={os.cpu_count()}")
    if "scaling" in args.parts:
        bench_scaling(sizes, args.steps, args.dense_max, args.budget)
    if "crossover" in args.parts:
        bench_crossover([100, 300, 500, 700, 800, 900, 1000, 1400], 4)
    if "two-dimensions" in args.parts and args.quick:
        bench_two_dimensions([2000], 2000, 2000)
    elif "two-dimensions" in args.parts:
        bench_two_dimensions([2000, 5000, 10**4, 10**5], args.dense_max, 20_000)
    if "finufft" in args.parts:
        bench_finufft(10**5 if args.quick else 10**6)
    if "mean-field" in args.parts:
        top = min(args.mean_field_max, 10**4 if args.quick else args.mean_field_max)
        sizes = [n for n in (10**3, 10**4, 10**5, 10**6) if n <= top]
        bench_mean_field(sizes, args.figure, args.mean_field_csv)


if __name__ == "__main__":
    main()
