"""The turnpike (cheap) control of the paper, Section 4: its formulas on arrays.

Formulas (labels of the source paper):

- cheap control, `eq:cheap_ctr`, with the expectation taken over the simulated Brownian paths:

      u_k^n = E[ beta (xbar - x_k^n) - (1/N) sum_l p(x_k^n, x_l^n)(x_l^n - x_k^n) ]
            = beta (xbar - E x_k^n) - E[interaction drift on k].

  In continuous time it turns the mean dynamics into `eq:dyn_mean`,
  d/dt E x_k = beta (xbar - E x_k), whose exponential-integrator discretization
  `eq:expint_mean` is exact: E x^{n+1} - xbar = exp(-beta tau) (E x^n - xbar).
- turnpike time, `eq:tptime`: the Lyapunov functional L^n = ||E x^n - xbar||^2 (squared Euclidean
  norm of the whole N d vector, summed over agents and coordinates) decays like
  exp(-2 beta t_n) L^0, so L <= delta from

      tbar = ln(delta / ||E x^0 - xbar||^2) / (-2 beta).

- after tbar the static control of `eq:stationary_solution` is used: u = 0 (xtilde = xbar).

The controllers built on these formulas are in `agent_envs.baselines.controllers`, the closed
loop the paper integrates in [0, tbar] in `agent_envs.baselines.closed_loop`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: Paper values (Section 5.2).
DEFAULT_BETA = 12.0
DEFAULT_DELTA = 2e-4


def turnpike_time(
    mean_x0: np.ndarray,
    target: float | np.ndarray,
    beta: float = DEFAULT_BETA,
    delta: float = DEFAULT_DELTA,
    horizon: float | None = None,
) -> float | np.ndarray:
    """The turnpike time tbar of `eq:tptime`.

    ``tbar = ln(delta / ||E x^0 - xbar||^2) / (-2 beta)``, with ``||.||^2`` summed over all agents
    and coordinates. It is clamped below at 0 (a start already within delta of the target needs no
    cheap phase; this includes E x^0 = xbar exactly) and, when `horizon` is given, above at T.

    Args:
        mean_x0: path-mean initial positions, shape (N,) (d = 1) or (..., N, d) for a batch.
        target: xbar, a scalar or shape (d,) (or broadcastable to mean_x0).
        beta: beta > 0, the decay rate of the cheap control.
        delta: delta > 0, the threshold on the Lyapunov functional.
        horizon: T, the upper clamp (optional).

    Returns:
        a float for a single state, an array of shape (...) for a batch.
    """
    if not beta > 0:
        raise ValueError(f"beta must be > 0, got {beta}")
    if not delta > 0:
        raise ValueError(f"delta must be > 0, got {delta}")
    x = np.asarray(mean_x0, dtype=float)
    if x.ndim == 1:
        x = x[:, None]
    if x.ndim < 2:
        raise ValueError(f"mean_x0 must have shape (N,) or (..., N, d), got {np.shape(mean_x0)}")
    sq = np.sum((x - np.asarray(target, dtype=float)) ** 2, axis=(-2, -1))
    with np.errstate(divide="ignore"):
        tbar = np.log(delta / sq) / (-2.0 * beta)
    tbar = np.maximum(tbar, 0.0)
    if horizon is not None:
        tbar = np.minimum(tbar, float(horizon))
    return float(tbar) if np.ndim(tbar) == 0 else tbar


def cheap_control(
    mean_positions: np.ndarray,
    mean_interaction_drift: np.ndarray,
    target: np.ndarray,
    beta: float = DEFAULT_BETA,
    cancel_interaction: bool = True,
) -> np.ndarray:
    """The cheap control of `eq:cheap_ctr` from path means; shapes (..., N, d), target (..., d).

    ``u_k = beta (xbar - E x_k) - E[(1/N) sum_l p(x_k, x_l)(x_l - x_k)]``. With
    ``cancel_interaction=False`` the second term is dropped (the proportional baseline).
    The expectation is linear, so the path mean of the per-path control equals this expression
    evaluated on the path means of positions and interaction drift.
    """
    x = np.asarray(mean_positions, dtype=float)
    tgt = np.asarray(target, dtype=float)[..., None, :]
    u = beta * (tgt - x)
    if cancel_interaction:
        u = u - np.asarray(mean_interaction_drift, dtype=float)
    return u


def cheap_control_from_model(
    model: Any, positions: np.ndarray, target: np.ndarray, beta: float = DEFAULT_BETA
) -> np.ndarray:
    """`eq:cheap_ctr` for a batch of paths (n_paths, N, d) using a `SwarmModel`'s drift.

    Returns the path-mean control, shape (N, d): the same for every path.
    """
    x = np.asarray(positions, dtype=float)
    drift = model.interaction_drift(x)
    return cheap_control(x.mean(axis=0), drift.mean(axis=0), np.asarray(target, float), beta)
