"""Policies to evaluate: saved Stable-Baselines3 models, their statistics, and adapters.

A policy is any SB3 `PolicyPredictor` (an object with
``predict(obs, state, episode_start, deterministic) -> (action, state)``), a baseline name
("turnpike", "proportional", "zero", built for the env), a callable ``env -> PolicyPredictor``,
or the path of a saved SB3 model (``.zip``; ``ALGO:PATH`` to name the algorithm, otherwise it is
read from the file). A `VecNormalize` statistics file next to the model is found and applied to
the observations, frozen (see `find_vecnormalize`). A model trained on the PettingZoo env's
per-agent observations (shape (3d+1,)) is run on the Gymnasium env with one action per agent from
that agent's own observation (`PerAgentPolicy`), so every policy is scored in the same cost units.
"""

from __future__ import annotations

import json
import os
import pickle
import re
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from agent_envs.envs.observation import agent_observations_from_global
from agent_envs.training.defaults import ALGORITHMS, algorithm_class


def detect_algo(path: str | os.PathLike) -> str:
    """The SB3 algorithm of a saved model, read from its zip's ``data`` (policy class, fields).

    SAC and TD3 have their own policy modules (a DDPG file has TD3's and is detected as TD3);
    ActorCriticPolicy is PPO when the file has PPO's ``clip_range``, else A2C. Raises ValueError
    when it cannot tell (use ``ALGO:PATH``) or the algorithm is not in `ALGORITHMS`.
    """
    with zipfile.ZipFile(path) as zf:
        data = json.loads(zf.read("data"))
    module = str(data.get("policy_class", {}).get("__module__", ""))
    for algo in ("sac", "td3"):
        if f"stable_baselines3.{algo}." in module:
            return algo
    if module.startswith("stable_baselines3.common.policies"):
        return "ppo" if "clip_range" in data else "a2c"
    raise ValueError(
        f"cannot tell the SB3 algorithm of {path} (policy module {module!r}); "
        f"give it as ALGO:PATH with ALGO one of {', '.join(ALGORITHMS)}, e.g. ppo:model.zip"
    )


def vecnormalize_candidates(model_path: str | os.PathLike) -> list[Path]:
    """Where the VecNormalize statistics of a saved model may be, in the order they are tried.

    For a model ``DIR/STEM.zip``: ``STEM_vecnormalize.pkl``; for ``X_model.zip``:
    ``X_vecnormalize.pkl`` (``best_model.zip`` -> ``best_vecnormalize.pkl``); for a checkpoint
    ``P_T_steps.zip``: ``P_vecnormalize_T_steps.pkl`` (SB3 `CheckpointCallback`); then
    ``vecnormalize.pkl`` and ``vec_normalize.pkl`` (rl-zoo3) in the same folder.
    """
    path = Path(model_path)
    stem = path.name[:-4] if path.name.endswith(".zip") else path.name
    names = [f"{stem}_vecnormalize.pkl"]
    if stem.endswith("_model"):
        names.append(f"{stem[: -len('_model')]}_vecnormalize.pkl")
    checkpoint = re.fullmatch(r"(.+)_(\d+)_steps", stem)
    if checkpoint:
        names.append(f"{checkpoint.group(1)}_vecnormalize_{checkpoint.group(2)}_steps.pkl")
    names += ["vecnormalize.pkl", "vec_normalize.pkl"]
    return [path.parent / name for name in names]


def find_vecnormalize(model_path: str | os.PathLike) -> Path | None:
    """The first existing file of `vecnormalize_candidates`, or None."""
    for candidate in vecnormalize_candidates(model_path):
        if candidate.is_file():
            return candidate
    return None


def load_vecnormalize(path: str | os.PathLike):
    """A frozen VecNormalize (training=False, norm_reward=False) from its pickle, without a venv.

    Only its `normalize_obs` is used, so the env itself stays unwrapped (raw rewards and infos).
    """
    with open(path, "rb") as fh:
        vec_normalize = pickle.load(fh)
    vec_normalize.training = False
    vec_normalize.norm_reward = False
    return vec_normalize


class NormalizedObservationPolicy:
    """A policy that sees observations normalized with frozen VecNormalize statistics."""

    def __init__(self, policy: Any, vec_normalize: Any) -> None:
        self.policy = policy
        self.vec_normalize = vec_normalize
        self.observation_space = getattr(policy, "observation_space", None)

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        obs = self.vec_normalize.normalize_obs(np.asarray(observation, dtype=np.float32))
        return self.policy.predict(obs, state, episode_start, deterministic)


class PerAgentPolicy:
    """Runs a per-agent policy (PettingZoo observation (3d+1,), action (d,)) on the Gym env.

    Each Gym observation (B, 2Nd+d+1) is split into the N per-agent rows
    ``[x_k | interaction drift on k | target | t/T]`` (the PettingZoo layout of
    docs/ARCHITECTURE.md); the inner policy acts on all B*N rows at once and the actions are
    concatenated agent-major into (B, N d). Parameter-shared multi-agent policies are thus scored
    on the single-controller env, same seeds, same cost units.
    """

    def __init__(self, policy: Any, n_agents: int, dim: int) -> None:
        self.policy = policy
        self.n_agents = n_agents
        self.dim = dim

    def agent_rows(self, observation: np.ndarray) -> np.ndarray:
        """The (B N, 3d+1) per-agent rows of one (2Nd+d+1,) or a batch of Gym observations."""
        obs = np.asarray(observation, dtype=np.float32)
        batch = obs[None] if obs.ndim == 1 else obs
        rows = agent_observations_from_global(batch, self.n_agents, self.dim)
        return rows.reshape(-1, 3 * self.dim + 1)

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        obs = np.asarray(observation)
        rows = self.agent_rows(obs)
        actions, _ = self.policy.predict(rows, None, None, deterministic)
        actions = np.asarray(actions, dtype=np.float32).reshape(-1, self.n_agents * self.dim)
        return (actions[0] if obs.ndim == 1 else actions), None


def load_sb3_policy(spec: str | os.PathLike, env: Any, device: str = "cpu") -> tuple[Any, dict]:
    """Load a saved SB3 model (``PATH`` or ``ALGO:PATH``) as a policy for `env`.

    Applies VecNormalize statistics found next to it (`find_vecnormalize`) and wraps a per-agent
    model in `PerAgentPolicy`. Returns the policy and a description dict (path, algo, vecnormalize).
    """
    text = os.fspath(spec)
    match = re.match(r"^([A-Za-z0-9_]+):(.+)$", text)
    algo = None
    if match and match.group(1).lower() in ALGORITHMS:
        algo, text = match.group(1).lower(), match.group(2)
    path = Path(text)
    if not path.is_file() and Path(text + ".zip").is_file():
        path = Path(text + ".zip")
    if not path.is_file():
        raise FileNotFoundError(f"no saved model at {text!r} (and no baseline of that name)")
    algo = algo or detect_algo(path)
    model = algorithm_class(algo).load(path, device=device)
    policy: Any = model
    info: dict[str, Any] = {"kind": "sb3", "path": str(path), "algo": algo, "vecnormalize": None}
    stats = find_vecnormalize(path)
    if stats is not None:
        policy = NormalizedObservationPolicy(policy, load_vecnormalize(stats))
        info["vecnormalize"] = str(stats)
    obs_shape = tuple(model.observation_space.shape or ())
    env_shape = tuple(env.observation_space.shape or ())
    inner = env.unwrapped
    per_agent = (3 * inner.params.dim + 1,)
    if obs_shape == per_agent and env_shape != per_agent:
        policy = PerAgentPolicy(policy, inner.params.n_agents, inner.params.dim)
        info["per_agent"] = True
    elif obs_shape != env_shape:
        raise ValueError(
            f"model {path} expects observations of shape {obs_shape}, the env gives {env_shape} "
            "(was it trained with other env kwargs, e.g. n_agents?)"
        )
    return policy, info


PolicySpec = Any  # PolicyPredictor | str | os.PathLike | Callable[[gym.Env], PolicyPredictor]


def resolve_policy(
    spec: PolicySpec, env: Any, baseline_kwargs: Mapping[str, Any] | None = None
) -> tuple[Any, dict]:
    """A PolicyPredictor for `env` from a spec (see the module docstring) and its description."""
    from agent_envs.baselines import BASELINES, make_baseline

    if isinstance(spec, (str, os.PathLike)):
        name = os.fspath(spec)
        if name in BASELINES:
            kw = dict(baseline_kwargs or {})
            if name == "zero":
                kw = {}
            return make_baseline(name, env, **kw), {"kind": "baseline", "name": name, **kw}
        return load_sb3_policy(name, env)
    if hasattr(spec, "predict"):
        return spec, {"kind": "object", "type": type(spec).__name__}
    if callable(spec):
        policy = spec(env)
        if not hasattr(policy, "predict"):
            raise TypeError("a policy factory must return an object with predict(...)")
        return policy, {"kind": "factory", "type": type(policy).__name__}
    raise TypeError(f"cannot make a policy from {spec!r}")


def live_policy(model: Any, agent_shape: tuple[int, int] | None = None) -> Any:
    """`model` as a PolicyPredictor on the raw Gymnasium env, following its live VecNormalize.

    `agent_shape` = (N, d) for a parameter-shared per-agent model (PettingZoo training), which
    then acts on the Gymnasium env through `PerAgentPolicy`.
    """
    stats = model.get_vec_normalize_env()
    policy = model if stats is None else NormalizedObservationPolicy(model, stats)
    if agent_shape is not None:
        policy = PerAgentPolicy(policy, *agent_shape)
    return policy
