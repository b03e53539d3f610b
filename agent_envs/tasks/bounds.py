"""A certified lower bound on the cost of any policy: the clairvoyant problem of the centre.

For the symmetric kernel (`eq:symmker`) the interaction conserves the swarm's centre
c = (1/N) sum_k x_k: L(x) = (P - diag(P 1))/N is symmetric with zero row sums, so
1^T L = 0, 1^T phi_1(tau L) = 1^T, and one step of SERB with the frozen L (`eq:serb`), of ERB
or of Euler-Maruyama moves the centre of path p by

    c_p^{n+1} = c_p^n + tau ubar^n + w_p^n,      ubar^n = (1/N) sum_k u_k^n,

where w_p^n = sigma (1/N) sum_k dW_{p,k}^n is the noise's mean, whatever the control. Split the
running cost of `eq:running_cost` with S = (1/N) sum_k |x_k - c|^2 >= 0 and Jensen's
(1/N) sum_k |u_k|^2 >= |ubar|^2:

    c(x, u) >= |c - xbar|^2 + gamma |ubar|^2          (and = + S^0 at n = 0, S^0 fixed).

The control is one sequence for all of an env's paths (one action per step), so for one seed,
whose noise w is fixed, every policy's cost on that seed is at least

    LB = tau S^0 + min over ubar^0..ubar^{m-1} of
         tau sum_{n=0}^{m-1} [ (1/K) sum_p |c_p^n - xbar|^2 + gamma |ubar^n|^2 ],

a deterministic linear-quadratic problem that knows the whole noise path in advance
(clairvoyant), with the box |u_k| <= max_control dropped (relaxing a constraint only lowers a
minimum). Each coordinate is a least-squares problem in m - 1 unknowns (ubar^{m-1} only costs:
x^m carries no cost). The bound is exact arithmetic up to the integrator's own conservation of
the centre (round-off; the Krylov tolerance on the matrix-free path).

Where it is tight: the stiff swarm collapses onto its centre within a few steps, so the spread
term it drops is small after n = 0; how small is measured against the optimum on the tasks
where the optimum is solved (docs/tasks.md).
"""

from __future__ import annotations

import numpy as np


def centre_paths_cost_bound(
    centres: np.ndarray, spread0: float, target: np.ndarray, dt: float, gamma: float
) -> float:
    """LB of the module docstring from the centres of an episode under zero control.

    Args:
        centres: (m + 1, K, d) the centre of each path at steps 0..m of an episode run with
            u = 0 (so c_p^n - c^0 is the summed noise W_p^n of that seed; index m is unused).
        spread0: S^0 = (1/N) sum_k |x_k^0 - c^0|^2 of the initial positions.
        target: (d,) xbar.
        dt: tau.
        gamma: the control weight.

    Returns:
        The lower bound (a float).
    """
    centres = np.asarray(centres, dtype=np.float64)
    if centres.ndim != 3:
        raise ValueError(f"centres must have shape (m + 1, K, d), got {centres.shape}")
    m = centres.shape[0] - 1
    if m < 1:
        raise ValueError("centres must hold at least two steps (m >= 1)")
    target = np.asarray(target, dtype=np.float64).reshape(-1)
    # a_p^n = c_p^n - xbar under u = 0; its mean over the paths and the spread over them
    offsets = centres[:m] - target  # (m, K, d)
    mean_offset = offsets.mean(axis=1)  # (m, d)
    path_variance = float(
        ((offsets - mean_offset[:, None, :]) ** 2).sum(axis=-1).mean(axis=1).sum()
    )
    total = spread0 + float((mean_offset[0] ** 2).sum()) + path_variance
    if m > 1:
        # unknowns v = ubar^0..ubar^{m-2}; U^n = sum_{j<n} v_j for n = 1..m-1
        lower = np.tril(np.ones((m - 1, m - 1)))
        design = np.vstack([dt * lower, np.sqrt(gamma) * np.eye(m - 1)])
        for i in range(mean_offset.shape[1]):
            rhs = np.concatenate([-mean_offset[1:, i], np.zeros(m - 1)])
            v, *_ = np.linalg.lstsq(design, rhs, rcond=None)
            residual = design @ v - rhs
            total += float(residual @ residual)
    return dt * total


def centre_lower_bound(
    initial_positions: np.ndarray,
    zero_control_positions: np.ndarray,
    target: np.ndarray,
    dt: float,
    gamma: float,
) -> float:
    """LB of the module docstring for one seed.

    Args:
        initial_positions: (N, d) x^0, the same on every path.
        zero_control_positions: (m + 1, K, N, d) or (m + 1, K, d) the positions (or already
            the centres) of each path at steps 0..m under u = 0, on the seed's noise.
        target: (d,) xbar.
        dt: tau = T / m.
        gamma: the control weight of the running cost.
    """
    x0 = np.asarray(initial_positions, dtype=np.float64)
    if x0.ndim != 2:
        raise ValueError(f"initial_positions must have shape (N, d), got {x0.shape}")
    positions = np.asarray(zero_control_positions, dtype=np.float64)
    centres = positions.mean(axis=2) if positions.ndim == 4 else positions
    spread0 = float(((x0 - x0.mean(axis=0)) ** 2).sum(axis=1).mean())
    return centre_paths_cost_bound(centres, spread0, target, dt, gamma)


__all__ = ["centre_lower_bound", "centre_paths_cost_bound"]
