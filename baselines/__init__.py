"""Reference controllers for the swarm envs, all SB3 `PolicyPredictor`s.

    from agent_envs.baselines import TurnpikeController
    ctrl = TurnpikeController(env)                    # beta = 12, delta = 2e-4 (paper)
    action, state = ctrl.predict(obs, state)          # actions in [-1, 1]

- `TurnpikeController`: cheap control `eq:cheap_ctr` until tbar (`eq:tptime`), then u = 0.
- `ProportionalController`: beta (xbar - x_k) until tbar, no interaction cancellation.
- `ZeroController`: u = 0 (static control, `eq:stationary_solution`).
- `turnpike_time`, `cheap_control`: the formulas on arrays (`turnpike`).
- `CheapClosedLoopModel`: the closed loop `eq:dyn_mean` as a drift model for the core's
  integrators (`closed_loop`).
- `solve_optimal_control`: the optimal open-loop control of `eq:discrete_cost_functional`
  (L-BFGS-B on autodiff gradients; needs torch, the `train` extra, when called).
- `OptimalController` (open loop) and `MPCController` (receding horizon): policies that plan
  with it.
"""

from __future__ import annotations

from typing import Any

from agent_envs.baselines.closed_loop import CheapClosedLoopModel
from agent_envs.baselines.controllers import (
    ProportionalController,
    TurnpikeController,
    ZeroController,
)
from agent_envs.baselines.feedback import FeedbackController
from agent_envs.baselines.optimal_control import OptimalControlResult, solve_optimal_control
from agent_envs.baselines.optimal_controllers import MPCController, OptimalController
from agent_envs.baselines.turnpike import (
    DEFAULT_BETA,
    DEFAULT_DELTA,
    cheap_control,
    cheap_control_from_model,
    turnpike_time,
)

#: name -> controller class (`make_baseline`, `agent-envs evaluate --policy NAME`)
BASELINES: dict[str, type] = {
    "turnpike": TurnpikeController,
    "proportional": ProportionalController,
    "zero": ZeroController,
    "optimal": OptimalController,
    "mpc": MPCController,
}


def make_baseline(name: str, env: Any, **kwargs: Any) -> Any:
    """Build the baseline registered under `name` (a key of `BASELINES`) for env."""
    if name not in BASELINES:
        raise ValueError(f"unknown baseline {name!r}; choose one of {sorted(BASELINES)}")
    return BASELINES[name](env, **kwargs)


__all__ = [
    "BASELINES",
    "DEFAULT_BETA",
    "DEFAULT_DELTA",
    "CheapClosedLoopModel",
    "FeedbackController",
    "MPCController",
    "OptimalControlResult",
    "OptimalController",
    "ProportionalController",
    "TurnpikeController",
    "ZeroController",
    "cheap_control",
    "cheap_control_from_model",
    "make_baseline",
    "solve_optimal_control",
    "turnpike_time",
]
