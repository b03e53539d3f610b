"""Stable-Baselines3 `VecEnv` over the native vector env `SwarmVectorEnv`.

    venv = NativeVecEnv(n_envs=8, env_kwargs={"n_agents": 100})
    model = PPO("MlpPolicy", venv, seed=0)

SB3's `DummyVecEnv` steps one Python env per copy; this adapter steps all copies as one batch
(`agent_envs.envs.vector_env.SwarmVectorEnv`) and speaks SB3's VecEnv protocol the way
`DummyVecEnv` over `Monitor(gym.make("agent_envs/Swarm-v0", ...))` does, so that a learner
sees the same data for the same seeds (tested against DummyVecEnv in tests/test_vector_env.py):

- `seed(s)` then `reset()` seeds env i with s + i (once; later resets continue the generators);
  `set_options` options are used at the next reset (the same for every env).
- `step_wait` resets an ended env at once (SB3's same-step autoreset): its last observation is
  in ``infos[i]["terminal_observation"]``, ``infos[i]["TimeLimit.truncated"]`` is
  ``truncated and not terminated``, and ``infos[i]["episode"]`` holds Monitor's
  ``{"r", "l", "t"}`` (return, length, seconds since the adapter was built).
- observations float32, rewards float32, dones bool, as DummyVecEnv returns them.
- `horizon_as_termination=True` applies `agent_envs.training.learners.wrappers.HorizonAsTermination`
  (the end of the horizon is terminal for the learner), as the training env does.
- `get_attr` returns per-env values of `positions`, `step_index`, `time`, `target` and
  `np_random`, and otherwise the native env's attribute (then its `config`'s, then its
  `params`'), the same for every env; `env_method` calls a method of the native env once per
  index; `env_is_wrapped(Monitor)` is True (the adapter adds Monitor's episode info).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env.base_vec_env import (
    VecEnv,
    VecEnvIndices,
    VecEnvObs,
    VecEnvStepReturn,
)

from agent_envs.envs.vector_env import SwarmVectorEnv

#: Attributes `get_attr` answers with one value per env.
PER_ENV_ATTRIBUTES = ("positions", "step_index", "time", "target", "np_random")


class NativeVecEnv(VecEnv):
    """SB3 VecEnv of `n_envs` swarm envs stepped as one batch (see the module docstring).

    Args:
        n_envs: number of envs B >= 1.
        env_kwargs: keyword arguments of `agent_envs/Swarm-v0` (validated as the single env's).
        horizon_as_termination: report the end of the horizon as a termination (training).
        num_threads: threads of the compiled passes over the batch
            (`SwarmVectorEnv`'s `num_threads`; the same results on any number).
    """

    def __init__(
        self,
        n_envs: int,
        env_kwargs: dict[str, Any] | None = None,
        *,
        horizon_as_termination: bool = False,
        num_threads: int = 1,
    ) -> None:
        self.venv = SwarmVectorEnv(
            n_envs,
            autoreset_mode=AutoresetMode.SAME_STEP,
            num_threads=num_threads,
            **dict(env_kwargs or {}),
        )
        self.horizon_as_termination = bool(horizon_as_termination)
        super().__init__(
            self.venv.num_envs, self.venv.single_observation_space, self.venv.single_action_space
        )
        self.actions: np.ndarray | None = None
        self._episode_returns = np.zeros(self.num_envs)
        self._episode_lengths = np.zeros(self.num_envs, dtype=np.int64)
        self._start_time = time.time()

    # ------------------------------------------------------------------ VecEnv API
    def reset(self) -> VecEnvObs:
        options = self._options[0]
        if any(opts != options for opts in self._options):
            raise ValueError(
                "NativeVecEnv resets every env with the same options; set_options got "
                "different options per env (use DummyVecEnv for that)"
            )
        obs, info = self.venv.reset(seed=list(self._seeds), options=options or None)
        self.reset_infos = self._per_env(info, np.ones(self.num_envs, dtype=bool))
        self._reset_seeds()
        self._reset_options()
        self._episode_returns[:] = 0.0
        self._episode_lengths[:] = 0
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self.actions = actions

    def step_wait(self) -> VecEnvStepReturn:
        if self.actions is None:
            raise RuntimeError("call step_async(actions) before step_wait()")
        obs, rewards, terminated, truncated, info = self.venv.step(self.actions)
        self.actions = None
        if self.horizon_as_termination:
            # The native env truncates only at the horizon (step_index = n_steps).
            terminated, truncated = terminated | truncated, np.zeros_like(truncated)
        dones = terminated | truncated
        self._episode_returns += rewards
        self._episode_lengths += 1
        infos = self._per_env(info, ~dones)
        if np.any(dones):  # an ended env's step info is its final_info; info holds its reset
            for i, final in enumerate(self._per_env(info["final_info"], dones)):
                if dones[i]:
                    infos[i] = final
            for i, reset_info in enumerate(self._per_env(info, dones)):
                if dones[i]:
                    self.reset_infos[i] = reset_info
        now = time.time()
        for i in range(self.num_envs):
            infos[i]["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
            if dones[i]:
                infos[i]["terminal_observation"] = info["final_obs"][i]
                infos[i]["episode"] = {
                    "r": round(float(self._episode_returns[i]), 6),
                    "l": int(self._episode_lengths[i]),
                    "t": round(now - self._start_time, 6),
                }
                self._episode_returns[i] = 0.0
                self._episode_lengths[i] = 0
        return obs, rewards.astype(np.float32), dones, infos

    def _per_env(self, info: dict[str, Any], rows: np.ndarray) -> list[dict[str, Any]]:
        """Gymnasium's vector info (arrays + "_key" masks) as SB3's list of per-env dicts.

        Env i (for i in `rows`) gets the keys whose mask holds i.
        """
        out: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        for key, value in info.items():
            if key.startswith("_") or key in ("final_obs", "final_info"):
                continue
            mask = info.get(f"_{key}", np.ones(self.num_envs, dtype=bool)) & rows
            for i in np.flatnonzero(mask):
                item = value[i]
                out[i][key] = item.item() if isinstance(item, np.generic) else item
        return out

    def close(self) -> None:
        self.venv.close()

    # ------------------------------------------------------------------ attributes
    def _attribute(self, attr_name: str, i: int) -> Any:
        venv = self.venv
        per_env = {
            "positions": lambda: venv.positions[i].copy(),
            "step_index": lambda: int(venv.step_index[i]),
            "time": lambda: float(venv.times[i]),
            "target": lambda: venv.targets[i].copy(),
            "np_random": lambda: venv._rng(i),
        }
        if attr_name in per_env:
            return per_env[attr_name]()
        for owner in (venv, venv.config, venv.config.params):
            if hasattr(owner, attr_name):
                return getattr(owner, attr_name)
        raise AttributeError(f"the native swarm vector env has no attribute {attr_name!r}")

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [self._attribute(attr_name, i) for i in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        raise AttributeError(
            f"NativeVecEnv cannot set {attr_name!r} per env: its envs share one batched state"
        )

    def env_method(
        self,
        method_name: str,
        *method_args: Any,
        indices: VecEnvIndices = None,
        **method_kwargs: Any,
    ) -> list[Any]:
        method = getattr(self.venv, method_name)
        return [method(*method_args, **method_kwargs) for _ in self._get_indices(indices)]

    def env_is_wrapped(
        self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None
    ) -> list[bool]:
        wrapped = issubclass(wrapper_class, Monitor)
        return [wrapped for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [None for _ in range(self.num_envs)]
