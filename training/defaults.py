"""Defaults and registries of the training layer: each value has its one home here.

- the env ids: the Gymnasium single-controller env and the PettingZoo env (by module path);
- the reference controllers' beta and delta (the paper's values, owned by
  `agent_envs.baselines`, re-exported here for the training layer);
- the Stable-Baselines3 algorithms, by name, for training and for loading saved models;
- the seeds: validation seeds during training, held-out test seeds for the comparisons;
- the one parser of ``--env-kwargs`` (and every other JSON-object option): a JSON object, for
  every subcommand.

Nothing here imports torch or Stable-Baselines3 at import time.
"""

from __future__ import annotations

import difflib
import json
from typing import Any

from agent_envs.baselines import BASELINES, DEFAULT_BETA, DEFAULT_DELTA
from agent_envs.envs import ENV_ID as GYM_ENV_ID

#: The PettingZoo parallel env (one agent per swarm member), named by its module.
PETTINGZOO_ENV_ID = "agent_envs.swarm_v0"
#: name -> Stable-Baselines3 class name: what `agent-envs train --algo` trains and what a saved
#: model (``ALGO:PATH``) is loaded with.
ALGORITHMS: dict[str, str] = {"ppo": "PPO", "sac": "SAC", "td3": "TD3", "a2c": "A2C"}
#: Algorithms that keep a replay buffer (saved with each checkpoint so a resume loses nothing).
OFF_POLICY = ("sac", "td3")
#: The reference controllers, by name (`agent_envs.baselines.BASELINES`).
BASELINE_POLICIES = tuple(BASELINES)
#: The feedback references evaluated by default (`evaluate`, `compare`, the training
#: callback); the optimal-control ones ("optimal", "mpc") solve an optimization per episode or
#: step and are asked for by name (`-p optimal`, `compare --optimum`).
FEEDBACK_BASELINES = ("turnpike", "proportional", "zero")
#: First validation seed (evaluation during training): episodes use seeds 1000, 1001, ...
DEFAULT_EVAL_SEED = 1_000
#: First held-out test seed of `agent-envs evaluate` and `agent-envs compare`.
DEFAULT_TEST_SEED = 10_000
#: The held-out test seeds used when none are given (training seeds are usually small ints).
DEFAULT_TEST_SEEDS = tuple(range(DEFAULT_TEST_SEED, DEFAULT_TEST_SEED + 20))

__all__ = [
    "ALGORITHMS",
    "BASELINE_POLICIES",
    "DEFAULT_BETA",
    "DEFAULT_DELTA",
    "DEFAULT_EVAL_SEED",
    "DEFAULT_TEST_SEED",
    "DEFAULT_TEST_SEEDS",
    "FEEDBACK_BASELINES",
    "GYM_ENV_ID",
    "OFF_POLICY",
    "PETTINGZOO_ENV_ID",
    "algorithm_class",
    "check_algo",
    "check_env_id",
    "is_multiagent",
    "parse_env_kwargs",
    "parse_json_object",
]


def check_algo(algo: str) -> str:
    """Return `algo` lower-cased; raise ValueError naming --algo if it is unknown."""
    name = str(algo).lower()
    if name not in ALGORITHMS:
        raise ValueError(f"--algo must be one of {', '.join(ALGORITHMS)}; got {algo!r}")
    return name


def algorithm_class(algo: str) -> Any:
    """The Stable-Baselines3 class of `algo` (ppo, sac, td3, a2c); imports SB3 lazily."""
    import stable_baselines3 as sb3

    return getattr(sb3, ALGORITHMS[check_algo(algo)])


def is_multiagent(env_id: str) -> bool:
    """True for the PettingZoo env id (a module path), False for a Gymnasium id."""
    return env_id == PETTINGZOO_ENV_ID


def check_env_id(env_id: str) -> str:
    """Return `env_id` if it names a registered Gymnasium env or the PettingZoo swarm env.

    Raises ValueError naming --env-id, with the closest known ids, otherwise.
    """
    import gymnasium as gym

    import agent_envs  # noqa: F401  (registers agent_envs/Swarm-v0)

    if env_id == PETTINGZOO_ENV_ID or env_id in gym.registry:
        return env_id
    known = [PETTINGZOO_ENV_ID, *gym.registry.keys()]
    close = difflib.get_close_matches(env_id, known, n=3)
    hint = f" Did you mean {', '.join(close)}?" if close else ""
    raise ValueError(
        f"--env-id {env_id!r} is neither a registered Gymnasium env nor the PettingZoo env "
        f"{PETTINGZOO_ENV_ID!r}; the swarm envs are {GYM_ENV_ID!r} and {PETTINGZOO_ENV_ID!r}.{hint}"
    )


def parse_json_object(text: str | dict | None, option: str) -> dict[str, Any]:
    """Parse a JSON object given on the command line; ValueError naming `option` if malformed.

    None gives {}; a dict is copied (library callers pass dicts).
    """
    if text is None:
        return {}
    if isinstance(text, dict):
        return dict(text)
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(
            f'{option} must be a JSON object such as \'{{"n_agents": 10, "integrator": '
            f'"em"}}\'; could not parse {text!r}: {exc}'
        ) from None
    if not isinstance(value, dict):
        raise ValueError(f"{option} must be a JSON object ({{...}}), got {type(value).__name__}")
    return value


def parse_env_kwargs(text: str | dict | None, option: str = "--env-kwargs") -> dict[str, Any]:
    """The env keyword arguments of every subcommand: one JSON object (`parse_json_object`)."""
    return parse_json_object(text, option)
