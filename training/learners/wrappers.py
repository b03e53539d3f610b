"""Gymnasium wrappers used for training only."""

from __future__ import annotations

from typing import Any

import gymnasium as gym


class HorizonAsTermination(gym.Wrapper):
    """The end of the horizon T is a terminal state for the learner.

    The swarm env reports the end of its m steps as `truncated` (Gymnasium's time-limit
    convention), but the control problem has a finite horizon and t/T is part of the
    observation, so nothing follows step m. Left as a truncation, SB3 bootstraps
    r + gamma V(s_T) there with a V(s_T) it never learns; the parameter-shared learner
    (SuperSuit) already sees a termination. With this wrapper both kinds of learner optimize the
    same finite-horizon objective. Evaluation is unaffected (it stops at either flag).
    """

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        base = self.env.unwrapped
        if truncated and not terminated and base.step_index >= base.n_steps:
            terminated, truncated = True, False
        return obs, reward, terminated, truncated, info
