"""Cost of the optimal-control solve in the paper's setting, against one forward simulation.

Setting (default): N = 100 agents, m = 50 steps, K = 20 Brownian paths, the symmetric stiff
kernel (eps = 0.05, alpha = 0.1), sigma = 0.01, T = 1, xbar = 0.7, gamma = 0.01, SERB with the
frozen linearization, |u| <= 150, x^0 uniform on [-1, 1] from seed 0 (`simulate`'s draw).

Measured in one run (best of `--repeats`, one BLAS/torch thread unless `--threads`):

- forward (numpy):   `simulate(...)` with a fixed control, the core's default path;
- forward (torch):   the same simulation on torch tensors without autograd;
- cost + gradient:   `DiscreteCostObjective` (torch forward with autograd + backward), the
                     solver's one evaluation (phi strategy `differentiated_phi_method`: eigh
                     for the symmetric kernel);

their ratios (target: gradient <= 4x one forward), then one full solve from u = 0 to a relative
projected gradient norm of `--gtol` (default 1e-6): wall time, iterations, evaluations, the
value V and the cost of u = 0 for scale (target: < 60 s on 2 cores).

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_optimal.py [--n-agents 100] [--device cuda]
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from collections.abc import Callable

import numpy as np

from agent_envs.baselines.optimal_control import (
    DiscreteCostObjective,
    differentiated_phi_method,
    solve_optimal_control,
)
from agent_envs.costs import discrete_cost
from agent_envs.params import SwarmParams
from agent_envs.simulator import simulate


def best_time(fn: Callable[[], object], repeats: int) -> float:
    """Best wall time of `repeats` calls (seconds)."""
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n-agents", type=int, default=100)
    parser.add_argument("--n-steps", type=int, default=50)
    parser.add_argument("--n-paths", type=int, default=20)
    parser.add_argument("--integrator", default="serb")
    parser.add_argument("--epsilon", type=float, default=0.05)
    parser.add_argument("--gtol", type=float, default=1e-6)
    parser.add_argument("--max-iterations", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads")
    parser.add_argument("--device", default="cpu", help="torch device of the solve (cpu, cuda)")
    args = parser.parse_args()

    import torch

    torch.set_num_threads(args.threads)
    params = SwarmParams(n_agents=args.n_agents, epsilon=args.epsilon, sigma=0.01)
    x0 = simulate(params, n_steps=1, n_paths=1, seed=0).positions[0, 0]
    shape = (args.n_steps, args.n_agents, 1)
    u = np.random.default_rng(1).uniform(-20.0, 20.0, size=shape)
    common = {
        "n_steps": args.n_steps,
        "n_paths": args.n_paths,
        "seed": 0,
        "initial_positions": x0,
    }
    objective = DiscreteCostObjective(
        params,
        args.integrator,
        "frozen",
        differentiated_phi_method(params, "frozen", None),
        args.n_steps,
        args.n_paths,
        0,
        x0,
        device=args.device,
    )

    def forward_torch() -> None:
        with torch.no_grad():
            objective.cost(torch.as_tensor(u, device=objective.device))

    times = {
        "forward (numpy simulate)": best_time(
            lambda: simulate(params, args.integrator, control=u, **common), args.repeats
        ),
        "forward (torch, no autograd)": best_time(forward_torch, args.repeats),
        "cost + gradient (torch)": best_time(lambda: objective(u.reshape(-1)), args.repeats),
    }
    print(
        f"N = {args.n_agents}, m = {args.n_steps}, K = {args.n_paths}, {args.integrator} (frozen),"
        f" eps = {args.epsilon}; device {args.device}, torch threads {args.threads}, "
        f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}, "
        f"{platform.processor() or platform.machine()}"
    )
    for name, seconds in times.items():
        print(f"  {name:32s} {seconds * 1e3:9.1f} ms")
    grad = times["cost + gradient (torch)"]
    print(f"  gradient / forward (numpy)       {grad / times['forward (numpy simulate)']:9.2f} x")
    print(
        f"  gradient / forward (torch)       {grad / times['forward (torch, no autograd)']:9.2f} x"
    )

    start = time.perf_counter()
    res = solve_optimal_control(
        params,
        args.integrator,
        max_control=150.0,
        gtol=args.gtol,
        max_iterations=args.max_iterations,
        threads=args.threads,
        device=args.device,
        **common,
    )
    wall = time.perf_counter() - start
    zero = simulate(params, args.integrator, **common)
    dt = params.horizon / args.n_steps
    zero_cost = float(np.mean(discrete_cost(zero.positions, zero.controls, 0.7, params.gamma, dt)))
    print(
        f"  solve to relative gradient {args.gtol:g}: {wall:.1f} s, {res.iterations} iterations, "
        f"{res.evaluations} evaluations, converged={res.converged}, "
        f"relative gradient {res.relative_gradient_norm:.2e}"
    )
    print(f"  V = {res.cost:.6f}   (u = 0: {zero_cost:.6f})   {res.message}")


if __name__ == "__main__":
    main()
