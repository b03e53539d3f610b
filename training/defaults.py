"""Defaults and registries of the training layer: each value has its one home here.

- the env ids: the Gymnasium single-controller env and the PettingZoo env (by module path);
- the reference controllers' beta and delta (the paper's values, owned by
  `agent_envs.baselines`, re-exported here for the training layer);
- the Stable-Baselines3 algorithms, by name, for training and for loading saved models;
- the seeds: validation seeds during training, held-out test seeds for the comparisons;
- the one parser of ``--env-kwargs`` (and every other JSON-object option): a JSON object, for
  every subcommand;
- the one parser of seed lists (``--seeds`` of every subcommand): `parse_seeds`.

Nothing here imports torch or Stable-Baselines3 at import time.
"""

from __future__ import annotations

import difflib
import json
import re
from collections import Counter
from collections.abc import Sequence
from typing import Any

from agent_envs.baselines import BASELINES, DEFAULT_BETA, DEFAULT_DELTA
from agent_envs.envs import ENV_ID as GYM_ENV_ID
from agent_envs.validation import MAX_SEED, check_int

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
#: The most seeds one seed list may hold (a typo like 0:10**12 is an error, not an OOM).
MAX_SEEDS = 100_000

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
    "INTERFACE_OPTIONS",
    "MAX_SEEDS",
    "OFF_POLICY",
    "PETTINGZOO_ENV_ID",
    "algorithm_class",
    "check_algo",
    "check_env_id",
    "default_interface",
    "interface_of",
    "is_multiagent",
    "parse_env_kwargs",
    "parse_json_object",
    "parse_seeds",
    "seed_text",
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


#: One item of a seed list: N, A-B (inclusive) or A:B (half-open).
_SEED_ITEM = re.compile(r"(\d+)(?:([-:])(\d+))?")
_SEED_SYNTAX = "a seed N, a range A-B (inclusive) or A:B (half-open), separated by commas or spaces"


def _seed_span(part: str, option: str) -> range:
    """The seeds of one item ``N``, ``A-B`` or ``A:B``; ValueError naming `option` otherwise."""
    match = _SEED_ITEM.fullmatch(part)
    if match is None:
        raise ValueError(f"{option}: {part!r} is not {_SEED_SYNTAX}, each in [0, {MAX_SEED}]")
    if max(len(match.group(1)), len(match.group(3) or "")) > len(str(MAX_SEED)) + 1:
        raise ValueError(f"{option}: {part[:40]!r}... goes past the largest seed {MAX_SEED}")
    low = int(match.group(1))
    if match.group(2) is None:
        span = range(low, low + 1)
    else:
        span = range(low, int(match.group(3)) + (1 if match.group(2) == "-" else 0))
        if not span:
            raise ValueError(f"{option}: the range {part!r} is empty")
    if span[-1] > MAX_SEED:
        raise ValueError(f"{option}: {part!r} goes past the largest seed {MAX_SEED}")
    return span


def seed_text(seeds: Sequence[int], through: str = "-", separator: str = ",") -> str:
    """Seeds as a user writes them: ``A-B`` for a run of three or more, else ``A,B,...``."""
    seeds = [int(s) for s in seeds]
    if len(seeds) > 2 and seeds == list(range(seeds[0], seeds[0] + len(seeds))):
        return f"{seeds[0]}{through}{seeds[-1]}"
    return separator.join(map(str, seeds))


def parse_seeds(
    items: str | int | Sequence[str | int] | None,
    option: str = "--seeds",
    default: Sequence[int] | None = DEFAULT_TEST_SEEDS,
) -> list[int] | None:
    """The seed list of every ``--seeds`` option: items ``N``, ``A-B`` or ``A:B``.

    `items` is one string or a sequence of them (argparse's ``nargs``), each holding one or
    more comma-separated items: ``N`` (a seed), ``A-B`` (A to B inclusive) or ``A:B`` (A to B-1),
    so ``"0-2,7"``, ``["0-2", "7"]`` and ``["0", "1", "2", "7"]`` are the same list. Library
    callers may pass ints. Every seed lies in [0, `MAX_SEED`], no seed twice, at most
    `MAX_SEEDS` of them.

    None (the option left out) gives `default` as a list, or None when `default` is None (the
    caller then uses its own default, e.g. a preset's). Raises ValueError (TypeError for a
    value of another type) naming `option` for anything else: a malformed item, a negative or
    too large seed, an empty range, a seed listed twice, no seed at all.
    """
    if items is None:
        return None if default is None else list(default)
    if isinstance(items, (str, int)):
        items = [items]
    seeds: list[int] = []
    for item in items:
        if isinstance(item, str):
            spans = [_seed_span(p.strip(), option) for p in item.split(",") if p.strip()]
        else:  # an int from a library caller (bools and other types rejected)
            seed = check_int(option, item, 0, MAX_SEED)
            spans = [range(seed, seed + 1)]
        for span in spans:
            if len(seeds) + len(span) > MAX_SEEDS:
                raise ValueError(f"{option}: more than {MAX_SEEDS} seeds")
            seeds.extend(span)
    if not seeds:
        hint = f" (leave the option out for {seed_text(default)})" if default else ""
        raise ValueError(f"{option}: no seed given{hint}")
    if len(set(seeds)) != len(seeds):
        twice = sorted(seed for seed, count in Counter(seeds).items() if count > 1)
        raise ValueError(f"{option} lists a seed twice: {', '.join(map(str, twice[:5]))}")
    return seeds


#: The env kwargs that set the learner's interface (`agent_envs.envs.interface`), not the
#: dynamics: a policy trained with them is evaluated on the default interface through
#: `agent_envs.training.learners.policies.InterfacePolicy` / `PerAgentPolicy`. ``neighbours``
#: (K of the "local" observation) goes with the observation.
INTERFACE_OPTIONS = ("observation", "action_basis", "agent_reward", "neighbours")


def default_interface(env_kwargs: dict[str, Any] | None) -> dict[str, Any]:
    """`env_kwargs` without the interface options: the same dynamics, cost and draws with the
    default observation ("absolute", no neighbours), action basis ("agents") and agent reward
    ("own")."""
    return {k: v for k, v in (env_kwargs or {}).items() if k not in INTERFACE_OPTIONS}


def interface_of(env_kwargs: dict[str, Any] | None) -> dict[str, str]:
    """The interface options a run's env kwargs set, with the defaults filled in."""
    kwargs = env_kwargs or {}
    return {
        "observation": str(kwargs.get("observation", "absolute")),
        "action_basis": str(kwargs.get("action_basis", "agents")),
        "agent_reward": str(kwargs.get("agent_reward", "own")),
    }
