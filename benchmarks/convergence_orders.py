"""Print the measured orders of convergence that tests/test_integrators.py asserts.

Run:  python benchmarks/convergence_orders.py

Reuses the test module's problem and helpers (same N = 6, eps = 1, alpha = 0.5, T = 0.5,
m = 8 ... 64; strong errors on 200 shared Brownian paths against a Heun m = 2048 reference).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import test_integrators as problem

from agent_envs import SwarmModel, SwarmParams, make_integrator


def main() -> None:
    x0 = problem._x0()
    print("| scheme | Jacobian | deterministic order (sigma = 0) | strong order (sigma = 0.5) |")
    print("|---|---|---|---|")
    det = SwarmParams(**problem.PARAMS, sigma=0.0)
    sto = SwarmParams(**problem.PARAMS, sigma=0.5)
    det_model, sto_model = SwarmModel(det), SwarmModel(sto)
    ref_det = problem._ode_reference(det_model, x0, det.horizon)
    rng = np.random.default_rng(12345)
    m_fine = 2048
    dw = np.sqrt(sto.horizon / m_fine) * rng.standard_normal((200, m_fine, *x0.shape))
    ref_sto = problem._integrate(make_integrator("heun"), sto_model, x0, m_fine, dw, sto.horizon)
    zero = np.zeros((1, problem.STEPS[-1], *x0.shape))
    for name, jac in [
        ("em", "-"),
        ("heun", "-"),
        ("erb", "exact"),
        ("erb", "frozen"),
        ("serb", "exact"),
        ("serb", "frozen"),
    ]:
        scheme = make_integrator(name, jacobian="frozen" if jac == "-" else jac)
        e_det = [
            np.max(
                np.abs(problem._integrate(scheme, det_model, x0, m, zero, det.horizon)[0] - ref_det)
            )
            for m in problem.STEPS
        ]
        e_sto = [
            np.mean(
                np.max(
                    np.abs(problem._integrate(scheme, sto_model, x0, m, dw, sto.horizon) - ref_sto),
                    axis=(-2, -1),
                )
            )
            for m in problem.STEPS
        ]
        print(f"| {name} | {jac} | {problem._order(e_det):.2f} | {problem._order(e_sto):.2f} |")


if __name__ == "__main__":
    main()
