"""The reference controllers: the paper's turnpike controller and two baselines beside it.

- `TurnpikeController`: the cheap control `eq:cheap_ctr` until tbar (`eq:tptime`), then u = 0
  (`eq:stationary_solution`).
- `ZeroController`: the static control of `eq:stationary_solution`, u = 0 for the whole horizon
  (the uncontrolled swarm, which only reaches consensus at the mean of its start).
- `ProportionalController`: ``u_k = beta (xbar - E x_k)`` until tbar (`eq:tptime`), then u = 0;
  the turnpike control of `eq:cheap_ctr` without the cancellation of the interaction drift, so a
  report shows what the cancellation buys. Set ``switch_off=False`` to keep it on until T.

All are SB3 `PolicyPredictor`s with the observation/action handling of
`agent_envs.baselines.feedback.FeedbackController` (Gym vectors, VecEnv batches, PettingZoo
per-agent rows and dicts).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from agent_envs.baselines.feedback import FeedbackController
from agent_envs.baselines.turnpike import DEFAULT_BETA, DEFAULT_DELTA, cheap_control


class ZeroController(FeedbackController):
    """u = 0 at every step (`eq:stationary_solution`): the static control alone."""

    def __init__(self, env: Any = None, **kwargs: Any) -> None:
        kwargs.setdefault("switch_off", False)
        super().__init__(env, **kwargs)

    def control(self, positions, drift, target):
        return np.zeros(np.shape(positions))


class ProportionalController(FeedbackController):
    """``u_k = beta (xbar - E x_k)`` (no interaction cancellation) until tbar, then u = 0.

    Args:
        env: the env it acts on (see `TurnpikeController`).
        beta: the gain (default the paper's 12, as the turnpike controller).
        delta: the threshold of `eq:tptime` used for tbar (same tbar as the turnpike controller).
        switch_off: True (default) switches to u = 0 at tbar, as the turnpike controller does.
        **kwargs: turnpike_time, params, max_control, n_steps as in `TurnpikeController`.
    """

    def __init__(
        self,
        env: Any = None,
        *,
        beta: float = DEFAULT_BETA,
        delta: float = DEFAULT_DELTA,
        switch_off: bool = True,
        **kwargs: Any,
    ) -> None:
        super().__init__(env, beta=beta, delta=delta, switch_off=switch_off, **kwargs)

    def control(self, positions, drift, target):
        return cheap_control(positions, drift, target, self.beta, cancel_interaction=False)


class TurnpikeController(FeedbackController):
    """The paper's turnpike control: cheap control `eq:cheap_ctr` until tbar, then u = 0.

    ``u_k = beta (xbar - E x_k) - E[(1/N) sum_l p(x_k, x_l)(x_l - x_k)]`` for t_n < tbar
    (`eq:tptime`, computed per episode from the first observation), u = 0 afterwards
    (`eq:stationary_solution`). Returned actions are u / max_control clipped to [-1, 1].

    Args:
        env: the env it acts on (Gymnasium env, SB3 VecEnv, or PettingZoo parallel env); N, d,
            T, m and max_control are read from it.
        beta: decay rate of the cheap control (paper: 12).
        delta: threshold of the Lyapunov functional (paper: 2e-4).
        turnpike_time: a fixed tbar instead of `eq:tptime` per episode (e.g. the paper's 0.54).
        switch_off: False keeps the cheap control on for the whole horizon.
        params, max_control, n_steps: override what is read from env (or give them without env).
    """

    def control(self, positions, drift, target):
        return cheap_control(positions, drift, target, self.beta, cancel_interaction=True)
