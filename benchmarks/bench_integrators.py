"""Benchmark of the numerical core: phi strategies, per-step cost, batching, time-to-accuracy.

Run:  python benchmarks/bench_integrators.py            (about 2 minutes on 2 cores)
      python benchmarks/bench_integrators.py --quick    (N = 100 only)

Every number is printed next to a baseline measured in the same run (a ratio), never against a
fixed threshold. BLAS is pinned to one thread (numpy and scipy each ship an OpenBLAS pool, and
with 2 threads a small stiff expm was 6x slower here); set OPENBLAS_NUM_THREADS to override.

Tables:
1. phi1(tau L) v by each strategy (expm = augmented-matrix Pade, eigh, krylov).
2. Per-step cost of each integrator at N = 100 / 1000 with 1 and 20 batched paths, as a ratio to
   EM on the same (N, paths), and the cost of 20 batched paths relative to 1 path.
3. Time-to-accuracy (eps = 0.05, sigma = 0.01, 1 path): the error of SERB (frozen J) at m = 25,
   the smallest m = 25 * 2^k at which EM is at least as accurate, and the wall-time ratio, for
   two errors against a Heun reference with m_ref steps on the same Brownian path: the
   trajectory error (max over the m = 25 grid times of the RMS over agents) and the error at T
   (RMS over agents).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import time

import numpy as np

from agent_envs import SwarmModel, SwarmParams, make_integrator
from agent_envs.integrators.phi_functions import phi_action

SCHEMES = [
    ("em", "frozen"),
    ("heun", "frozen"),
    ("erb", "frozen"),
    ("serb", "frozen"),
    ("serb", "exact"),
]


def _timeit(fn, min_time: float = 0.3, max_reps: int = 200) -> float:
    """Median seconds per call over repeated calls (at least 3, about `min_time` in total)."""
    fn()
    times = []
    start = time.perf_counter()
    while (len(times) < 3 or time.perf_counter() - start < min_time) and len(times) < max_reps:
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def bench_phi(sizes) -> None:
    print("\n## 1. phi1(tau L(x)) v, eps = 0.05, tau = 0.04, x uniform on [-1, 1], 1 path")
    print("| N | expm [ms] | eigh [ms] | krylov [ms] | expm / krylov |")
    print("|---|---|---|---|---|")
    for n in sizes:
        model = SwarmModel(SwarmParams(n_agents=n))
        x = np.random.default_rng(0).uniform(-1, 1, (n, 1))
        a = 0.04 * model.frozen_linearization(x)
        v = model.drift(0.0, x)
        res = {
            m: _timeit(lambda m=m, a=a, v=v: phi_action(a, v, 1, method=m, symmetric=True))
            for m in ("expm", "eigh", "krylov")
        }
        print(
            f"| {n} | {1e3 * res['expm']:.2f} | {1e3 * res['eigh']:.2f} | "
            f"{1e3 * res['krylov']:.2f} | {res['expm'] / res['krylov']:.1f} |"
        )


def bench_steps(sizes, paths_list) -> None:
    print("\n## 2. Cost of one step, eps = 0.05, sigma = 0.01, x uniform on [-1, 1]")
    print("| N | paths | scheme | ms/step | ratio to EM | 20 paths / 1 path |")
    print("|---|---|---|---|---|---|")
    for n in sizes:
        params = SwarmParams(n_agents=n)
        model = SwarmModel(params)
        single: dict[str, float] = {}
        for paths in paths_list:
            rng = np.random.default_rng(1)
            x = rng.uniform(-1, 1, (paths, n, 1))
            dw = 0.2 * rng.standard_normal(x.shape)
            base = None
            for name, jac in SCHEMES:
                if jac == "exact" and n * paths > 2000:
                    # (20, 1000, 1000) dense Jacobians: skipped, ~3 GB of temporaries.
                    continue
                scheme = make_integrator(name, jacobian=jac)
                label = f"{name} ({jac})" if scheme.needs_jacobian else name
                t = _timeit(
                    lambda s=scheme, md=model, x=x, dw=dw: s.step(md, x, None, 0.0, 0.04, dw)
                )
                base = t if base is None else base
                batch = "" if paths == 1 else f"{t / single[label]:.1f}"
                if paths == 1:
                    single[label] = t
                print(f"| {n} | {paths} | {label} | {1e3 * t:.2f} | {t / base:.2f} | {batch} |")


def _run(scheme, model, x0, dw_fine, m):
    dt = 1.0 / m
    dw = dw_fine.reshape(m, -1, *dw_fine.shape[1:]).sum(axis=1)
    x = x0.copy()
    out = [x]
    for n in range(m):
        x = scheme.step(model, x, None, n * dt, dt, dw[n])
        out.append(x)
    return np.array(out)


def _error(traj, ref, coarse=25):
    """Max over the coarse grid of the RMS over agents of traj - ref."""
    m, m_ref = traj.shape[0] - 1, ref.shape[0] - 1
    a = traj[:: m // coarse]
    b = ref[:: m_ref // coarse]
    return float(np.max(np.sqrt(np.mean((a - b) ** 2, axis=(-2, -1)))))


def _final_error(traj, ref):
    """RMS over agents of traj(T) - ref(T)."""
    return float(np.sqrt(np.mean((traj[-1] - ref[-1]) ** 2)))


def bench_accuracy(n: int, m_ref: int) -> None:
    params = SwarmParams(n_agents=n, epsilon=0.05, sigma=0.01)
    model = SwarmModel(params)
    rng = np.random.default_rng(2)
    x0 = rng.uniform(-1, 1, (1, n, 1))
    dw_fine = np.sqrt(1.0 / m_ref) * rng.standard_normal((m_ref, 1, n, 1))
    ref = _run(make_integrator("heun"), model, x0, dw_fine, m_ref)
    serb = make_integrator("serb", jacobian="frozen")
    t0 = time.perf_counter()
    serb_traj = _run(serb, model, x0, dw_fine, 25)
    t_serb = time.perf_counter() - t0
    err_serb, fin_serb = _error(serb_traj, ref), _final_error(serb_traj, ref)
    print(f"\n## 3. Time-to-accuracy, N = {n}, 1 path, reference Heun m = {m_ref}")
    print(
        f"SERB (frozen J), m = 25: trajectory error {err_serb:.3e}, error at T "
        f"{fin_serb:.3e}, {1e3 * t_serb:.1f} ms"
    )
    print("| EM m | trajectory error | error at T | wall [ms] | EM wall / SERB(25) wall |")
    print("|---|---|---|---|---|")
    em = make_integrator("em")
    found: dict[str, tuple[int, float]] = {}
    m = 25
    while m <= m_ref // 2:
        t0 = time.perf_counter()
        traj = _run(em, model, x0, dw_fine, m)
        t_em = time.perf_counter() - t0
        err, fin = _error(traj, ref), _final_error(traj, ref)
        print(f"| {m} | {err:.3e} | {fin:.3e} | {1e3 * t_em:.1f} | {t_em / t_serb:.1f} |")
        if err <= err_serb:
            found.setdefault("trajectory error", (m, t_em / t_serb))
        if fin <= fin_serb:
            found.setdefault("error at T", (m, t_em / t_serb))
        m *= 2
    for metric in ("trajectory error", "error at T"):
        if metric in found:
            m_eq, ratio = found[metric]
            print(f"{metric}: EM needs m = {m_eq} to match SERB(25): {ratio:.1f}x the wall time")
        else:
            print(f"{metric}: EM did not reach SERB(25)'s value up to m = {m_ref // 2}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="N = 100 only")
    args = parser.parse_args()
    sizes = [100] if args.quick else [100, 1000]
    print(f"OPENBLAS_NUM_THREADS={os.environ['OPENBLAS_NUM_THREADS']}")
    bench_phi(sizes)
    bench_steps(sizes, [1, 20])
    bench_accuracy(100, 6400)
    if not args.quick:
        bench_accuracy(1000, 6400)


if __name__ == "__main__":
    main()
