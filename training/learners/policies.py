"""Policies to evaluate: saved Stable-Baselines3 models, their statistics, and adapters.

A policy is any SB3 `PolicyPredictor` (an object with
``predict(obs, state, episode_start, deterministic) -> (action, state)``), a baseline name
("turnpike", "proportional", "zero", built for the env), a callable ``env -> PolicyPredictor``,
or the path of a saved SB3 model (``.zip``; ``ALGO:PATH`` to name the algorithm, otherwise it is
read from the file; ``PATH:STATS.pkl`` to name its `VecNormalize` statistics). The statistics
are applied to the observations, frozen; they are unpickled only when the user named them, when
the manifest of the run that saved them records their SHA-256, or from the rl-zoo3 run the
named model belongs to (`find_statistics`, the trust boundary). A model trained on the PettingZoo
env's per-agent observations (shape (3d+1,)) is run on the Gymnasium env with one action per
agent from that agent's own observation (`PerAgentPolicy`), so every policy is scored in the same
cost units.
"""

from __future__ import annotations

import json
import os
import pickle
import re
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from agent_envs.envs.interface import DEFAULT_NEIGHBOURS, action_rows, controls_from_actions
from agent_envs.envs.observation import (
    agent_observation_size,
    agent_observations_from_global,
    global_observation,
    observation_size,
    split_observation,
)
from agent_envs.training.defaults import (
    ALGORITHMS,
    PETTINGZOO_ENV_ID,
    algorithm_class,
    interface_of,
)
from agent_envs.training.storage import find_manifest


def read_model_data(path: str | os.PathLike) -> dict[str, Any]:
    """The JSON ``data`` member of an SB3 model zip; ValueError when it is not one."""
    try:
        with zipfile.ZipFile(path) as zf:
            data = json.loads(zf.read("data"))
    except (OSError, zipfile.BadZipFile, KeyError, ValueError, EOFError) as exc:
        raise ValueError(
            f"{path} is not a readable Stable-Baselines3 model zip ({type(exc).__name__}: {exc})"
        ) from None
    if not isinstance(data, dict):
        raise ValueError(f"{path} is not a Stable-Baselines3 model zip (its data is no object)")
    return data


def detect_algo(path: str | os.PathLike) -> str:
    """The SB3 algorithm of a saved model, read from its zip's ``data`` (policy class, fields).

    SAC and TD3 have their own policy modules (a DDPG file has TD3's and is detected as TD3);
    ActorCriticPolicy is PPO when the file has PPO's ``clip_range``, else A2C. Raises ValueError
    when it cannot tell (use ``ALGO:PATH``) or the algorithm is not in `ALGORITHMS`.
    """
    data = read_model_data(path)
    policy_class = data.get("policy_class")
    module = str(policy_class.get("__module__", "")) if isinstance(policy_class, dict) else ""
    for algo in ("sac", "td3"):
        if f"stable_baselines3.{algo}." in module:
            return algo
    if module.startswith("stable_baselines3.common.policies"):
        return "ppo" if "clip_range" in data else "a2c"
    raise ValueError(
        f"cannot tell the SB3 algorithm of {path} (policy module {module!r}); "
        f"give it as ALGO:PATH with ALGO one of {', '.join(ALGORITHMS)}, e.g. ppo:model.zip"
    )


@dataclass(frozen=True)
class ModelSpec:
    """A saved SB3 model named on the command line: ``[ALGO:]MODEL.zip[:STATS.pkl]``.

    `algo` is None when it is to be read from the file; `statistics` is the VecNormalize file
    the user named (None: looked up by `find_statistics`).
    """

    path: Path
    algo: str | None = None
    statistics: Path | None = None

    @classmethod
    def parse(cls, spec: str | os.PathLike) -> ModelSpec:
        """Split ``[ALGO:]MODEL[.zip][:STATS.pkl]`` (a '.zip' is added when only it exists)."""
        text = os.fspath(spec)
        algo = None
        match = re.match(r"^([A-Za-z0-9_]+):(.+)$", text)
        if match and match.group(1).lower() in ALGORITHMS:
            algo, text = match.group(1).lower(), match.group(2)
        statistics = None
        head, sep, tail = text.rpartition(":")
        if sep and head and tail.endswith(".pkl"):
            text, statistics = head, Path(tail)
        path = Path(text)
        if not path.is_file() and Path(text + ".zip").is_file():
            path = Path(text + ".zip")
        return cls(path, algo, statistics)


#: Why a statistics file may be unpickled (`Statistics.source` -> the words `evaluate` prints).
STATISTICS_SOURCES = {
    "named": "named on the command line",
    "manifest": "SHA-256 verified against the run's manifest.json",
    "rl-zoo3": "the rl-zoo3 run's statistics",
}


@dataclass(frozen=True)
class Statistics:
    """The VecNormalize statistics chosen for a model and why they may be unpickled."""

    path: Path
    #: a key of `STATISTICS_SOURCES`: "named" (by the user), "manifest" (hash recorded by the
    #: run that wrote them) or "rl-zoo3" (the statistics of the rl-zoo3 run of the named model)
    source: str


def own_run_candidates(model_path: str | os.PathLike) -> list[Path]:
    """Where a run of `agent-envs train` keeps the statistics of a model, in order.

    ``DIR/STEM.zip`` -> ``STEM_vecnormalize.pkl`` (best_model, final_model); a checkpoint
    ``P_T_steps.zip`` -> ``P_vecnormalize_T_steps.pkl`` (SB3 `CheckpointCallback` names).
    """
    path = Path(model_path)
    stem = path.name[:-4] if path.name.endswith(".zip") else path.name
    names = [f"{stem}_vecnormalize.pkl"]
    checkpoint = re.fullmatch(r"(.+)_(\d+)_steps", stem)
    if checkpoint:
        names.append(f"{checkpoint.group(1)}_vecnormalize_{checkpoint.group(2)}_steps.pkl")
    return [path.parent / name for name in names]


def rl_zoo3_statistics(model_path: str | os.PathLike) -> Path | None:
    """The statistics of an rl-zoo3 run the model belongs to, or None if it is not one.

    rl-zoo3 writes ``<log>/<algo>/<env>_<id>/`` with the models (``<env>.zip``,
    ``best_model.zip``, checkpoints ``rl_model_<T>_steps.zip`` + ``rl_model_vecnormalize_<T>_
    steps.pkl``) and a folder ``<env>/`` holding ``args.yml``, ``config.yml`` and
    ``vecnormalize.pkl`` (the final statistics, which rl-zoo3's own ``enjoy`` loads for every
    model of the run). A checkpoint gets its own statistics; every other model the run's.
    """
    path = Path(model_path)
    folder = path.parent
    runs = (
        [
            sub
            for sub in sorted(folder.iterdir())
            if sub.is_dir() and (sub / "args.yml").is_file() and (sub / "config.yml").is_file()
        ]
        if folder.is_dir()
        else []
    )
    if len(runs) != 1:
        return None
    stem = path.name[:-4] if path.name.endswith(".zip") else path.name
    checkpoint = re.fullmatch(r"rl_model_(\d+)_steps", stem)
    if checkpoint:
        candidate = folder / f"rl_model_vecnormalize_{checkpoint.group(1)}_steps.pkl"
        if candidate.is_file():
            return candidate
    candidate = runs[0] / "vecnormalize.pkl"
    return candidate if candidate.is_file() else None


#: Pickles next to a model that are never loaded unless named (other tools' names).
UNVERIFIED_NAMES = ("vecnormalize.pkl", "vec_normalize.pkl")


def find_statistics(spec: ModelSpec) -> Statistics | None:
    """The VecNormalize statistics to use with a saved model, or None when it has none.

    The trust boundary (a pickle runs code when loaded, so only these are unpickled):

    1. the file the user named (``MODEL.zip:STATS.pkl``);
    2. the statistics a run of `agent-envs train` saved with the model, when that run's
       ``manifest.json`` records their SHA-256 and the file still matches it;
    3. the statistics of the rl-zoo3 run whose model the user named (`rl_zoo3_statistics`).

    A statistics file next to the model that none of these vouches for is refused with a
    ValueError saying how to name it.
    """
    if spec.statistics is not None:
        if not spec.statistics.is_file():
            raise FileNotFoundError(
                f"no VecNormalize statistics file at {spec.statistics} (named after {spec.path})"
            )
        return Statistics(spec.statistics, "named")
    zoo = rl_zoo3_statistics(spec.path)
    if zoo is not None:
        return Statistics(zoo, "rl-zoo3")
    found = [c for c in own_run_candidates(spec.path) if c.is_file()]
    found += [spec.path.parent / n for n in UNVERIFIED_NAMES if (spec.path.parent / n).is_file()]
    if not found:
        return None
    candidate = found[0]
    manifest = find_manifest(candidate)
    problem = manifest.problem(candidate) if manifest is not None else "no manifest.json"
    if problem is None:
        return Statistics(candidate, "manifest")
    raise ValueError(
        f"refusing to load the statistics {candidate} found next to {spec.path.name}: they are "
        f"not vouched for by a run this project wrote ({problem}); a pickle runs code when "
        f"loaded, so if you trust the file name it explicitly: {spec.path}:{candidate}"
    )


def load_vecnormalize(path: str | os.PathLike):
    """A frozen VecNormalize (training=False, norm_reward=False) from its pickle, without a venv.

    Only its `normalize_obs` is used, so the env itself stays unwrapped (raw rewards and infos).
    Call it only on a file `find_statistics` chose. ValueError when the file is not a whole
    VecNormalize pickle.
    """
    try:
        with open(path, "rb") as fh:
            vec_normalize = pickle.load(fh)
    except (pickle.UnpicklingError, EOFError, AttributeError, ImportError, IndexError) as exc:
        raise ValueError(f"{path} is not a readable VecNormalize statistics file ({exc})") from None
    if not hasattr(vec_normalize, "normalize_obs"):
        raise ValueError(
            f"{path} holds a {type(vec_normalize).__name__}, not VecNormalize statistics"
        )
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
    """Runs a per-agent policy (PettingZoo observation, action (d,)) on the Gym env.

    Each Gym observation (B, 2Nd+d+1) (default layout) is split into the N per-agent rows of
    `layout` (``[x_k | interaction drift on k | target | t/T]`` for "absolute"; see
    `agent_envs.envs.interface`); the inner policy acts on all B*N rows at once and the
    actions are concatenated agent-major into (B, N d). Parameter-shared multi-agent policies
    are thus scored on the single-controller env, same seeds, same cost units.
    """

    def __init__(
        self,
        policy: Any,
        n_agents: int,
        dim: int,
        layout: str = "absolute",
        neighbours: int | None = None,
    ) -> None:
        self.policy = policy
        self.n_agents = n_agents
        self.dim = dim
        self.layout = layout
        #: K of the "local" layout (None: the env's default, `DEFAULT_NEIGHBOURS`)
        self.neighbours = DEFAULT_NEIGHBOURS if neighbours is None else int(neighbours)

    def agent_rows(self, observation: np.ndarray) -> np.ndarray:
        """The (B N, size) per-agent rows of one (2Nd+d+1,) or a batch of Gym observations."""
        obs = np.asarray(observation, dtype=np.float32)
        batch = obs[None] if obs.ndim == 1 else obs
        rows = agent_observations_from_global(
            batch, self.n_agents, self.dim, self.layout, self.neighbours
        )
        return rows.reshape(-1, rows.shape[-1])

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        obs = np.asarray(observation)
        rows = self.agent_rows(obs)
        actions, _ = self.policy.predict(rows, None, None, deterministic)
        actions = np.asarray(actions, dtype=np.float32).reshape(-1, self.n_agents * self.dim)
        return (actions[0] if obs.ndim == 1 else actions), None


class InterfacePolicy:
    """Runs a policy trained with other interface options on the default-interface Gym env.

    The policy was trained on `agent_envs/Swarm-v0` with ``observation=layout`` and
    ``action_basis=basis`` (`agent_envs.envs.interface`); the env it acts on has the defaults.
    Each observation is mapped to the training layout (positions and drift read back from the
    default layout, then laid out again, float32 round-off), and each action to the control u
    it applies in the training env and back to ``u / max_control``, so the policy applies the
    controls it would apply in its own env.
    """

    def __init__(
        self,
        policy: Any,
        n_agents: int,
        dim: int,
        layout: str,
        basis: str,
        max_control: float,
        observation_space: Any,
    ) -> None:
        self.policy = policy
        self.n_agents, self.dim = n_agents, dim
        self.layout, self.basis = layout, basis
        self.max_control = float(max_control)
        self.observation_space = observation_space

    def observation(self, observation: np.ndarray) -> np.ndarray:
        """(..., 2Nd+d+1) default-layout observations -> the training layout."""
        parts = split_observation(observation, self.n_agents, self.dim)
        return global_observation(
            parts["positions"],
            parts["interaction_drift"],
            parts["target"],
            parts["time_fraction"],
            self.observation_space,
            self.layout,
        )

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        obs = self.observation(np.asarray(observation, dtype=np.float64))
        actions, state = self.policy.predict(obs, state, episode_start, deterministic)
        a = np.asarray(actions, dtype=np.float64)
        rows = action_rows(self.basis, self.n_agents)
        u = controls_from_actions(
            a.reshape(*a.shape[:-1], rows, self.dim), self.basis, self.max_control, self.n_agents
        )
        lead = a.shape[:-1]
        return (u / self.max_control).reshape(*lead, -1).astype(np.float32), state


def trained_interface(model_path: Path) -> dict[str, Any]:
    """The env id (None when unknown) and interface options of the run a model belongs to (its
    ``env.json``, JSON, next to the model or one folder up); the defaults when there is none."""
    for folder in (model_path.parent, model_path.parent.parent):
        env_json = folder / "env.json"
        if env_json.is_file():
            kwargs, env_id = _read_json_keys(env_json, "env_kwargs", "env_id")
            # the trained env id from the run's config (runs of earlier versions wrote the
            # Gymnasium twin's id into env.json for the parameter-shared learner)
            trained_id = _read_json_keys(folder / "config.json", "env_id")[0]
            kwargs = kwargs if isinstance(kwargs, dict) else {}
            neighbours = kwargs.get("neighbours")
            return {
                "env_id": trained_id or env_id,
                **interface_of(kwargs),
                "neighbours": neighbours,
            }
    return {"env_id": None, **interface_of({}), "neighbours": None}


def _read_json_keys(path: Path, *keys: str) -> list[Any]:
    """The values of `keys` in the JSON object at `path` (None where missing or unreadable)."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return [None] * len(keys)
    return [data.get(k) if isinstance(data, dict) else None for k in keys]


def _adapt_to_env(policy: Any, model: Any, env: Any, path: Path, info: dict[str, Any]) -> Any:
    """Wrap `policy` for `env`: per-agent models through `PerAgentPolicy`, a model trained with
    other interface options through `InterfacePolicy`; ValueError when the shapes cannot
    match."""
    inner = env.unwrapped
    n, d = inner.params.n_agents, inner.params.dim
    trained = trained_interface(path)
    config = getattr(inner, "config", None)
    here = (getattr(config, "observation", "absolute"), getattr(config, "action_basis", "agents"))
    obs_shape = tuple(model.observation_space.shape or ())
    env_shape = tuple(env.observation_space.shape or ())
    if trained["env_id"] is None:  # no run folder: the default per-agent row, by its shape
        per_agent = (agent_observation_size(d),)
        multiagent = obs_shape == per_agent and env_shape != per_agent
    else:
        multiagent = trained["env_id"] == PETTINGZOO_ENV_ID
    if multiagent:
        if here != ("absolute", "agents"):
            raise ValueError(
                f"model {path} is a per-agent policy; evaluate it on the Gymnasium env's default "
                "observation and action basis"
            )
        info["per_agent"] = True
        return PerAgentPolicy(policy, n, d, trained["observation"], trained["neighbours"])
    wanted = (trained["observation"], trained["action_basis"])
    if wanted != here:
        if here != ("absolute", "agents"):
            raise ValueError(
                f"model {path} was trained with observation={wanted[0]!r}, "
                f"action_basis={wanted[1]!r}; evaluate it on those or on the defaults"
            )
        expected = (observation_size(n, d, wanted[0]),), (action_rows(wanted[1], n) * d,)
        found = obs_shape, tuple(model.action_space.shape or ())
        if found != expected:
            raise ValueError(
                f"model {path} has observation and action shapes {found}; its interface "
                f"(observation={wanted[0]!r}, action_basis={wanted[1]!r}) on this env needs "
                f"{expected} (was it trained with other env kwargs, e.g. n_agents?)"
            )
        policy = InterfacePolicy(policy, n, d, *wanted, inner.max_control, model.observation_space)
        info["interface"] = {"observation": wanted[0], "action_basis": wanted[1]}
        env_shape = obs_shape
    if obs_shape != env_shape:
        raise ValueError(
            f"model {path} expects observations of shape {obs_shape}, the env gives {env_shape} "
            "(was it trained with other env kwargs, e.g. n_agents?)"
        )
    return policy


def check_model(spec: str | os.PathLike | ModelSpec) -> tuple[ModelSpec, str, Statistics | None]:
    """Check a saved-model spec without unpickling anything: (spec, algorithm, statistics).

    The file must exist and be an SB3 model zip; an algorithm given as ``ALGO:`` must match the
    file's (when the file tells); the statistics are chosen by `find_statistics`. Raises
    FileNotFoundError / ValueError naming the file.
    """
    model = spec if isinstance(spec, ModelSpec) else ModelSpec.parse(spec)
    if not model.path.is_file():
        raise FileNotFoundError(
            f"{os.fspath(model.path)!r} is neither a baseline ({', '.join(_baseline_names())}) "
            "nor a saved model file"
        )
    read_model_data(model.path)
    algo = model.algo
    try:
        detected = detect_algo(model.path)
    except ValueError:
        if algo is None:
            raise
        detected = algo
    if algo is not None and detected != algo:
        raise ValueError(
            f"{model.path} holds a {detected.upper()} model, not {algo.upper()}; write "
            f"{detected}:{model.path} (or leave the algorithm out: it is read from the file)"
        )
    return model, detected, find_statistics(model)


def _baseline_names() -> tuple[str, ...]:
    from agent_envs.baselines import BASELINES

    return tuple(BASELINES)


def load_sb3_policy(spec: str | os.PathLike, env: Any, device: str = "cpu") -> tuple[Any, dict]:
    """Load a saved SB3 model (``[ALGO:]PATH[:STATS.pkl]``) as a policy for `env`.

    Applies the VecNormalize statistics `find_statistics` allows (frozen, observations only)
    and wraps a per-agent model in `PerAgentPolicy`. Returns the policy and a description dict
    (path, algo, vecnormalize, vecnormalize_source).
    """
    model_spec, algo, stats = check_model(spec)
    path = model_spec.path
    try:
        model = algorithm_class(algo).load(path, device=device)
    except (ValueError, TypeError, KeyError, RuntimeError, EOFError, zipfile.BadZipFile) as exc:
        raise ValueError(f"cannot load {path} as an SB3 {algo.upper()} model: {exc}") from None
    policy: Any = model
    info: dict[str, Any] = {
        "kind": "sb3",
        "path": str(path),
        "algo": algo,
        "vecnormalize": None,
        "vecnormalize_source": None,
    }
    if stats is not None:
        policy = NormalizedObservationPolicy(policy, load_vecnormalize(stats.path))
        info["vecnormalize"] = str(stats.path)
        info["vecnormalize_source"] = stats.source
    policy = _adapt_to_env(policy, model, env, path, info)
    return policy, info


PolicySpec = Any  # PolicyPredictor | str | os.PathLike | Callable[[gym.Env], PolicyPredictor]


def resolve_policy(
    spec: PolicySpec, env: Any, baseline_kwargs: Mapping[str, Any] | None = None
) -> tuple[Any, dict]:
    """A PolicyPredictor for `env` from a spec (see the module docstring) and its description."""
    from agent_envs.baselines import BASELINES, FeedbackController, make_baseline

    if isinstance(spec, (str, os.PathLike)):
        name = os.fspath(spec)
        if name in BASELINES:
            kw = dict(baseline_kwargs or {})
            # beta/delta are the turnpike-type controllers' options; zero, optimal and mpc
            # take none of them
            if name == "zero" or not issubclass(BASELINES[name], FeedbackController):
                kw = {}
            return make_baseline(name, env, **kw), {"kind": "baseline", "name": name, **kw}
        from agent_envs.training.learners.apg_policy import is_apg_run, load_apg_policy

        if is_apg_run(name):  # an apg run folder or its weights (.pt beside apg_law.json)
            return load_apg_policy(name), {"kind": "apg", "path": name}
        return load_sb3_policy(name, env)
    if hasattr(spec, "predict"):
        return spec, {"kind": "object", "type": type(spec).__name__}
    if callable(spec):
        policy = spec(env)
        if not hasattr(policy, "predict"):
            raise TypeError("a policy factory must return an object with predict(...)")
        return policy, {"kind": "factory", "type": type(policy).__name__}
    raise TypeError(f"cannot make a policy from {spec!r}")


def live_policy(
    model: Any,
    agent_shape: tuple[int, int] | None = None,
    layout: str = "absolute",
    neighbours: int | None = None,
) -> Any:
    """`model` as a PolicyPredictor on the raw Gymnasium env, following its live VecNormalize.

    `agent_shape` = (N, d) for a parameter-shared per-agent model (PettingZoo training), which
    then acts on the default-interface Gymnasium env through `PerAgentPolicy` with its
    per-agent `layout` (and K = `neighbours` for the "local" layout).
    """
    stats = model.get_vec_normalize_env()
    policy = model if stats is None else NormalizedObservationPolicy(model, stats)
    if agent_shape is not None:
        policy = PerAgentPolicy(policy, *agent_shape, layout, neighbours)
    return policy
