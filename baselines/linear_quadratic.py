"""The exact finite-horizon LQ solution of the discrete problem for a position-independent kernel.

When the kernel p does not depend on the positions (e.g. a user `InteractionKernel` with
p = c), the frozen linearization L = (P - diag(P 1)) / N is a constant (N, N) matrix, the drift
F(x, u) = L x + u is linear, and the exact Jacobian equals L. The integrators then step

    EM / EE:             x+ = (I + tau L) x + tau u + sigma dW                   (`eq:eulermaru`)
    ERB / SERB (frozen   x+ = e^{tau L} x + tau phi1(tau L) u + noise             (`eq:serb`,
    or exact Jacobian):                                                          `eq:exp_int_discr`)

with noise sigma dW (EM, ERB) or e^{tau L} sigma dW (SERB: x + tau phi1(tau L)(sigma L dW) +
sigma dW). Every row of L sums to zero, so L 1 = 0 and the shifted state z = x - xbar obeys
z+ = A z + B u + w with the same (A, B), acting on each of the d coordinates alike.

The open-loop problem on K Brownian paths (`eq:discrete_cost_functional` with the sample mean)
splits, since u is the same on every path, into the path mean zm = mean_paths z and a spread
that u does not move:

    mean_paths tau sum_n (1/N)(|z^n|^2 + gamma |u^n|^2)
        = sum_n (zm^n' Q zm^n + u^n' R u^n) + (u-independent spread),
    Q = (tau/N) I,  R = (tau gamma / N) I,  zm+ = A zm + B u + w^n,

where w^n is the path mean of the noise term (zero for sigma = 0). The backward Riccati
recursion with terminal value 0 (x^m carries no cost under the left rectangle rule), for
V_n(z) = z' P_n z + 2 s_n' z + r_n,

    G = R + B' P B,  K = G^{-1} B' P A,  k = G^{-1} B' (P w + s),
    P_n = Q + A' P A - A' P B K,  s_n = (A - B K)' (P w + s),  r_n = r + w' P w + 2 s' w - k' G k,

gives the optimal open-loop control u^n = -K_n zm^n - k_n along the optimal path-mean state
and the optimal value V_0(zm^0) of the mean part. This is the reference the gradient solver
`agent_envs.baselines.optimal_control.solve_optimal_control` is tested against.

The matrices use scipy.linalg.expm (tau phi1(tau L) from the augmented matrix
[[tau L, tau I], [0, 0]]), independently of the core's `phi_action`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from agent_envs.dynamics.swarm import SwarmModel
from agent_envs.params import SwarmParams

#: integrator name -> whether its discrete map is the exponential one
_EXPONENTIAL = {"em": False, "ee": False, "erb": True, "serb": True}


def constant_linearization(params: SwarmParams) -> np.ndarray:
    """L = (P - diag(P 1)) / N, (N, N), for a kernel that does not depend on the positions.

    Evaluated at the origin; raises ValueError if L differs at a second (random) state, i.e.
    the kernel does depend on the positions and the dynamics are not linear.
    """
    model = SwarmModel(params)
    n, d = params.n_agents, params.dim
    lin = model.frozen_linearization(np.zeros((n, d)))
    probe = np.random.default_rng(0).uniform(-1.0, 1.0, size=(n, d))
    if not np.allclose(model.frozen_linearization(probe), lin, rtol=1e-12, atol=1e-12):
        raise ValueError(
            "params.kernel depends on the positions: the dynamics are not linear and the LQ "
            "reference does not apply (use a kernel with p = const)"
        )
    return lin


def discrete_linear_dynamics(
    linearization: np.ndarray, dt: float, integrator: str
) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) with x+ = A x + B u (+ noise) for constant L; see the module docstring.

    `integrator` is "em", "ee", "erb" or "serb" (Heun's map is quadratic in tau L and not
    offered here).
    """
    if integrator not in _EXPONENTIAL:
        raise ValueError(f"integrator must be one of {sorted(_EXPONENTIAL)}, got {integrator!r}")
    n = linearization.shape[0]
    eye = np.eye(n)
    if not _EXPONENTIAL[integrator]:
        return eye + dt * linearization, dt * eye
    aug = np.zeros((2 * n, 2 * n))
    aug[:n, :n] = dt * linearization
    aug[:n, n:] = dt * eye
    expo = scipy.linalg.expm(aug)
    return expo[:n, :n], expo[:n, n:]


@dataclass(frozen=True)
class LinearQuadraticSolution:
    """The Riccati solution of the open-loop LQ problem.

    Attributes:
        controls: (m, N, d) the optimal open-loop control u^0..u^{m-1}.
        mean_positions: (m + 1, N, d) the path-mean state under it (target added back).
        mean_cost: the optimal value of the path-mean part, V_0(zm^0); the full sample cost adds
            the u-independent spread of the paths around their mean (0 for sigma = 0).
        gains: (m, N, N) the feedback gains K_n.
    """

    controls: np.ndarray
    mean_positions: np.ndarray
    mean_cost: float
    gains: np.ndarray


def solve_linear_quadratic(
    transition: np.ndarray,
    input_matrix: np.ndarray,
    initial_positions: np.ndarray,
    target: np.ndarray,
    gamma: float,
    dt: float,
    n_steps: int,
    disturbance: np.ndarray | None = None,
) -> LinearQuadraticSolution:
    """Backward Riccati recursion and forward sweep (module docstring).

    Args:
        transition, input_matrix: A and B, (N, N).
        initial_positions: x^0, (N, d).
        target: xbar, (d,).
        gamma: the control weight (> 0).
        dt: tau.
        n_steps: m.
        disturbance: w^n, (m, N, d), the path mean of the noise terms (default 0).
    """
    a, b = np.asarray(transition, float), np.asarray(input_matrix, float)
    x0 = np.asarray(initial_positions, float)
    n, d = x0.shape
    if not gamma > 0:
        raise ValueError(f"gamma must be > 0 for the Riccati recursion, got {gamma}")
    w = np.zeros((n_steps, n, d)) if disturbance is None else np.asarray(disturbance, float)
    q = (dt / n) * np.eye(n)
    r = (dt * gamma / n) * np.eye(n)
    p_next, s_next, r_next = np.zeros((n, n)), np.zeros((n, d)), 0.0
    gains = np.zeros((n_steps, n, n))
    offsets = np.zeros((n_steps, n, d))
    for step in range(n_steps - 1, -1, -1):
        g = r + b.T @ p_next @ b
        pw_s = p_next @ w[step] + s_next
        gain = np.linalg.solve(g, b.T @ p_next @ a)
        offset = np.linalg.solve(g, b.T @ pw_s)
        closed = a - b @ gain
        p_now = q + a.T @ p_next @ a - a.T @ p_next @ b @ gain
        r_now = (
            r_next
            + np.sum(w[step] * (p_next @ w[step]))
            + 2.0 * np.sum(s_next * w[step])
            - np.sum(offset * (g @ offset))
        )
        s_next = closed.T @ pw_s
        p_next = 0.5 * (p_now + p_now.T)
        r_next = r_now
        gains[step], offsets[step] = gain, offset
    z = x0 - target
    mean_cost = float(np.sum(z * (p_next @ z)) + 2.0 * np.sum(s_next * z) + r_next)
    controls = np.zeros((n_steps, n, d))
    states = np.zeros((n_steps + 1, n, d))
    states[0] = z
    for step in range(n_steps):
        controls[step] = -gains[step] @ states[step] - offsets[step]
        states[step + 1] = a @ states[step] + b @ controls[step] + w[step]
    return LinearQuadraticSolution(controls, states + target, mean_cost, gains)
