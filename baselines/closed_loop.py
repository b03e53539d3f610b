"""The swarm under continuous cheap feedback: the closed loop the paper integrates in [0, tbar].

Why the closed loop (docs/paper.md, "Paper's controlled experiments", has the measurements): an env
holds each action constant over a time step (zero-order hold). With Euler-Maruyama the held cheap
control gives exactly the explicit Euler scheme of `eq:dyn_mean`. With SERB/ERB the exponential
integrator treats the interaction implicitly (phi1(tau L)) while the held control cancels it
only at the step's start, so in stiff directions the cheap phase barely contracts the spread of
the swarm. The paper's own procedure integrates the closed loop `eq:dyn_mean` in [0, tbar]
instead; `CheapClosedLoopModel` provides that closed loop to the core's integrators (used by
`agent_envs.training.experiments.turnpike_controlled`). With several paths, the env's control
(one for all paths, from path means) also cannot cancel each path's own stiff interaction:
single paths scatter under SERB.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from agent_envs.baselines.turnpike import DEFAULT_BETA


class CheapClosedLoopModel:
    """The swarm under continuous cheap feedback, a drift model for the core's integrators.

    The cheap control `eq:cheap_ctr` applied along each path, u(x) = beta (xbar - x) - L(x) x,
    turns the drift F(x, u) = L(x) x + u into beta (xbar - x): the closed loop is the linear SDE
    dx = beta (xbar - x) dt + sigma dW, whose mean obeys `eq:dyn_mean`. Its linearization is
    ``-beta I`` (per coordinate, symmetric), so ERB/SERB applied to it give `eq:expint_mean`,
    E x^{n+1} = E x^n + tau phi1(-beta tau) beta (xbar - E x^n), exact for the mean; EM gives the
    explicit Euler scheme of `eq:dyn_mean`. This is the paper's cheap integration on [0, tbar]
    (Section 5.2). The drift is evaluated through the wrapped `SwarmModel` (no copy of the
    kernel formulas).

    With `until` = tbar the feedback acts while t < tbar and the model is the open-loop swarm
    afterwards (drift F(t, x, u), the wrapped model's linearization): the paper's whole
    procedure is then one `simulate(..., model=...)` run.

    Why per path: cancelling only the path-mean interaction, with the per-path remainder
    L(x) x - E[L(x) x] left in a drift whose linearization is -beta I, integrates that stiff
    remainder explicitly; we measured it to blow up individual paths in the stiff setting
    (eps = 0.05, m = 50) while their mean still looked right.
    """

    def __init__(
        self,
        model: Any,
        target: np.ndarray,
        beta: float = DEFAULT_BETA,
        until: float = math.inf,
    ) -> None:
        self.model = model
        self.sigma = model.sigma
        self.n_agents = model.n_agents
        self.dim = model.dim
        self.target = np.asarray(target, dtype=float).reshape(model.dim)
        self.beta = float(beta)
        self.until = float(until)

    def feedback_on(self, t: float) -> bool:
        """True while t < `until` (the turnpike time tbar; up to 1e-9 of round-off).

        The switch is a function of t: a scheme that evaluates the drift at t + tau inside a
        step (Heun's predictor) sees the open loop there once t + tau >= tbar.
        """
        return t < self.until - 1e-9

    def control(self, x: np.ndarray) -> np.ndarray:
        """u(x) = beta (xbar - x) - L(x) x per path, same shape as x (..., N, d)."""
        x = np.asarray(x, dtype=float)
        return self.beta * (self.target - x) - self.model.interaction_drift(x)

    def drift(self, t: float, x: np.ndarray, u: np.ndarray | None = None) -> np.ndarray:
        """F(t, x, u + u_fb(x)) with the feedback u_fb while `feedback_on(t)`, else F(t, x, u)."""
        x = np.asarray(x, dtype=float)
        if not self.feedback_on(t):
            return self.model.drift(t, x, u)
        f = self.model.drift(t, x, self.control(x))
        return f if u is None else f + u

    def drift_and_linearization(self, t: float, x: np.ndarray, u: np.ndarray | None, kind: str):
        """(F, -beta I) while the feedback is on; the wrapped model's pair afterwards."""
        from agent_envs.dynamics.swarm import Linearization

        if not self.feedback_on(t):
            return self.model.drift_and_linearization(t, x, u, kind)
        x = np.asarray(x, dtype=float)
        eye = np.broadcast_to(np.eye(self.n_agents), (*x.shape[:-2], self.n_agents, self.n_agents))
        lin = Linearization(-self.beta * eye, per_coordinate=True, symmetric=True)
        return self.drift(t, x, u), lin
