"""Cost of a gradient through `simulate` on torch, per phi strategy (for optimal control).

Run:  python benchmarks/bench_gradient.py [--n-agents 100] [--n-paths 20] [--n-steps 10]

For each phi strategy ("expm", "eigh", "krylov") with SERB (frozen L(x)): the wall time of one
forward simulation on torch (no autograd), of one forward pass recording the graph plus its
backward (the gradient of sum |x|^2 with respect to the control), their ratio, and the numpy
forward simulation of the same run as the baseline. BLAS and torch run on one thread.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import time

import numpy as np
import torch

from agent_envs import SwarmParams, simulate


def _median_time(fn, reps: int) -> float:
    fn()
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n-agents", type=int, default=100)
    parser.add_argument("--n-paths", type=int, default=20)
    parser.add_argument("--n-steps", type=int, default=10)
    parser.add_argument("--reps", type=int, default=3)
    args = parser.parse_args()
    torch.set_num_threads(1)
    n, p, m = args.n_agents, args.n_paths, args.n_steps
    params = SwarmParams(n_agents=n, epsilon=0.05, sigma=0.01)
    x0 = np.random.default_rng(0).uniform(-1, 1, n)
    u0 = np.zeros((m, n, 1))
    kw = dict(integrator="serb", n_steps=m, n_paths=p, seed=0)
    print(f"## Gradient of sum |x|^2 w.r.t. u through SERB (frozen), N = {n}, {p} paths, m = {m}")
    print(
        "| phi | numpy forward [ms] | torch forward [ms] | torch forward+backward [ms] | "
        "(fwd+bwd) / torch fwd | (fwd+bwd) / numpy fwd |"
    )
    print("|---|---|---|---|---|---|")
    xt = torch.as_tensor(x0)
    for method in ("expm", "eigh", "krylov"):

        def numpy_forward(method=method):
            simulate(params, phi_method=method, initial_positions=x0, control=u0, **kw)

        def forward(method=method):
            with torch.no_grad():
                u = torch.as_tensor(u0)
                simulate(params, phi_method=method, initial_positions=xt, control=u, **kw)

        def gradient(method=method):
            u = torch.zeros((m, n, 1), dtype=torch.float64, requires_grad=True)
            traj = simulate(params, phi_method=method, initial_positions=xt, control=u, **kw)
            traj.positions.pow(2).sum().backward()

        t_np = _median_time(numpy_forward, args.reps)
        t_fwd = _median_time(forward, args.reps)
        t_grad = _median_time(gradient, args.reps)
        print(
            f"| {method} | {1e3 * t_np:.1f} | {1e3 * t_fwd:.1f} | {1e3 * t_grad:.1f} | "
            f"{t_grad / t_fwd:.2f} | {t_grad / t_np:.2f} |"
        )


if __name__ == "__main__":
    main()
