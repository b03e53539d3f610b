"""How large does the turnpike cheap control get in the paper's settings? (sets `max_control`)

The env maps an action a in [-1, 1] to the control u = max_control * a, so `max_control` must
exceed the largest |u_k| the reference controller asks for, or that controller gets clipped.
This script runs the paper's turnpike experiments (Section `sec:numexptc`) with the core's
`simulate` and measures max_k,n |u_k^n| of the cheap control (`eq:cheap_ctr`)

    u_k^n = beta (xbar - E x_k^n) - E (1/N) sum_l p(x_k^n, x_l^n)(x_l^n - x_k^n)   (n tau < tbar)
    u_k^n = 0                                                                    (n tau >= tbar)

with beta = 12, delta = 2e-4 and the turnpike time tbar of `eq:tptime`
(||E x^0 - xbar||^2 summed over agents), the interaction drift from
`SwarmModel.interaction_drift`, E the mean over the Brownian paths. Settings: N = 100 agents
uniform on [-1, 1], T = 1, m = 50, sigma = 0.01, alpha = 0.1; symmetric kernel eps = 0.05 with
xbar = 0.7 and -1.7; non-symmetric kernel eps in [1e-2, 1e-1] with xbar = 2.3; integrators
SERB (the paper's) and EM; n_paths = 1 (the env's default) and 20 (the paper's). The initial
conditions come from the validation seeds 1000, 1001, ... (`training.defaults.DEFAULT_EVAL_SEED`,
also the tasks' validation seeds): this chooses a bound, so it never reads a test seed.

    OPENBLAS_NUM_THREADS=1 python benchmarks/max_control.py [--seeds 20]
"""

from __future__ import annotations

import argparse

import numpy as np

from agent_envs import SwarmModel, SwarmParams, simulate
from agent_envs.baselines import DEFAULT_BETA, DEFAULT_DELTA, turnpike_time
from agent_envs.simulator import DEFAULT_MAX_CONTROL

#: the first validation seed (`agent_envs.training.defaults.DEFAULT_EVAL_SEED`; this script
#: needs only the core, so the number is written here and a test checks that they agree)
VALIDATION_SEED = 1000
BETA = DEFAULT_BETA
DELTA = DEFAULT_DELTA
SETTINGS = (
    ("symmetric", 0.7),
    ("symmetric", -1.7),
    ("nonsymmetric", 2.3),
)


def peak_control(
    kernel: str, target: float, integrator: str, n_paths: int, seed: int
) -> tuple[float, float, float, bool]:
    """(max |u|, time of the max, tbar, diverged) of one turnpike-controlled run."""
    params = SwarmParams(kernel=kernel, target=target)
    model = SwarmModel(params)
    x0 = np.random.default_rng(seed).uniform(-1.0, 1.0, size=(params.n_agents, 1))
    tbar = turnpike_time(x0, target, BETA, DELTA, params.horizon)
    peak = [0.0, 0.0]

    def control(t: float, x: np.ndarray) -> np.ndarray:
        if t >= tbar - 1e-12:
            return np.zeros(x.shape[-2:])
        u = BETA * (target - x.mean(axis=0)) - model.interaction_drift(x).mean(axis=0)
        size = float(np.max(np.abs(u)))
        if size > peak[0]:
            peak[:] = [size, t]
        return u

    traj = simulate(
        params,
        integrator,
        n_steps=50,
        n_paths=n_paths,
        seed=seed,
        initial_positions=x0,
        control=control,
    )
    return peak[0], peak[1], tbar, traj.diverged


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20, help="initial conditions per setting")
    args = parser.parse_args()
    print(f"turnpike cheap control, beta={BETA}, delta={DELTA}, N=100, m=50, {args.seeds} seeds")
    header = f"{'kernel':>12} {'xbar':>5} {'integr':>6} {'paths':>5} | {'max|u|':>7} "
    header += f"{'median':>7} {'t(max)':>6} {'tbar':>5} {'div':>3}"
    print(header)
    overall = 0.0
    for kernel, target in SETTINGS:
        for integrator in ("serb", "em"):
            for n_paths in (1, 20):
                runs = [
                    peak_control(kernel, target, integrator, n_paths, seed)
                    for seed in range(VALIDATION_SEED, VALIDATION_SEED + args.seeds)
                ]
                peaks = np.array([r[0] for r in runs])
                worst = runs[int(np.argmax(peaks))]
                overall = max(overall, worst[0])
                print(
                    f"{kernel:>12} {target:>5} {integrator:>6} {n_paths:>5} | "
                    f"{worst[0]:7.2f} {np.median(peaks):7.2f} {worst[1]:6.2f} {worst[2]:5.3f} "
                    f"{sum(r[3] for r in runs):>3}"
                )
    verdict = "never clipped" if overall <= DEFAULT_MAX_CONTROL else "CLIPPED"
    print(f"largest |u| = {overall:.2f}; default max_control = {DEFAULT_MAX_CONTROL}: {verdict}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
