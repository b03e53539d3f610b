"""References evaluated through a learner's interface: each learner's fair baseline.

A learner that sees the summary observation and moves one common control (`SUMMARY_COMMON` of
the presets: PPO and SAC of the quick and paper presets) cannot express the proportional
controller's per-agent law; its fair baseline is the best simple law *in its interface*, the
proportional law on the swarm's centre (`CENTRE_LAW`, also the leaderboard's yardstick for SAC):

    u_k = beta (xbar - c)  for every agent k,   c = (1/N) sum_k E x_k,   beta = 12,

read from the summary observation (its first d entries are c - xbar) and applied through the
common action basis (one action of d entries, u / max_control clipped to [-1, 1], broadcast to
the N agents); on for the whole horizon. It is evaluated as a learner trained in that interface
is: on the setting's default-interface env through `InterfacePolicy` (observations mapped to
the summary layout, the common control mapped back), so its cost is in the same units, on the
same test seeds, as every other policy's.

A learner whose interface can express the per-agent law (a per-agent policy: parameter-shared
PPO with the swarm observation, which holds each agent's offset, or `apg`; a single controller
that moves every agent) has the proportional controller itself as its fair baseline.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

#: The proportional law on the centre, in the summary/common interface.
CENTRE_LAW = "proportional-common"
#: name -> the env options (`agent_envs.envs.interface`) the reference acts through.
INTERFACE_REFERENCES: dict[str, dict[str, str]] = {
    CENTRE_LAW: {"observation": "summary", "action_basis": "common"},
}


class CentreLaw:
    """``a = clip(-beta (c - xbar) / max_control, -1, 1)``: the centre law's common action.

    An SB3 `PolicyPredictor` on summary observations (..., 3d + 1) (centre offset c - xbar,
    spread, target, t/T); returns float32 actions (..., d).
    """

    def __init__(self, dim: int, max_control: float, beta: float | None = None) -> None:
        from agent_envs.baselines import DEFAULT_BETA

        self.dim, self.max_control = int(dim), float(max_control)
        self.beta = DEFAULT_BETA if beta is None else float(beta)

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        offset = np.asarray(observation, dtype=np.float64)[..., : self.dim]
        action = np.clip(-self.beta * offset / self.max_control, -1.0, 1.0)
        return action.astype(np.float32), state


#: Observation layouts that show the swarm's centre offset to whoever acts (the summary and
#: modes observations of a single controller, the swarm row of each agent): the centre law is a
#: law of their interface.
CENTRE_OBSERVATIONS = ("summary", "modes", "swarm")


def fair_baseline(interface: Mapping[str, Any]) -> str:
    """The best simple law in a learner's interface (its env options): `CENTRE_LAW` (12 (xbar -
    c), one control for all) where the controller sees the centre or sends one common control,
    else the proportional controller 12 (xbar - x_k) (per-agent rows without the centre, the
    local row: the law is itself local). On every task measured the centre law costs less than
    the per-agent law at eps = 0.05 and more at eps = 1 (docs/leaderboard.md)."""
    observation = interface.get("observation", "absolute")
    if interface.get("action_basis") == "common" or observation in CENTRE_OBSERVATIONS:
        return CENTRE_LAW
    return "proportional"


def interface_reference(name: str, env: Any, **kwargs: Any) -> Any:
    """The reference `name` (a key of `INTERFACE_REFERENCES`) acting on `env`, a
    default-interface Gymnasium swarm env, through its interface; `kwargs`: the law's (beta)."""
    import gymnasium as gym

    from agent_envs.training.learners.policies import InterfacePolicy

    if name not in INTERFACE_REFERENCES:
        raise ValueError(
            f"unknown interface reference {name!r}; one of {list(INTERFACE_REFERENCES)}"
        )
    interface = INTERFACE_REFERENCES[name]
    inner = env.unwrapped
    n, d, bound = inner.params.n_agents, inner.params.dim, float(inner.max_control)
    # the interface's observation space (bounds of the clipping), from the env's own kwargs
    twin = gym.make(inner.spec.id, **{**inner.spec.kwargs, **interface})
    try:
        space = twin.observation_space
    finally:
        twin.close()
    law = CentreLaw(d, bound, **kwargs)
    layout, basis = interface["observation"], interface["action_basis"]
    return InterfacePolicy(law, n, d, layout, basis, bound, space)


__all__ = [
    "CENTRE_LAW",
    "INTERFACE_REFERENCES",
    "CentreLaw",
    "fair_baseline",
    "interface_reference",
]
