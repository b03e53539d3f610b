"""Evaluate policies on a swarm env over a fixed list of seeds, and store the results.

    from agent_envs.training.evaluate import evaluate_policies
    results = evaluate_policies(
        {"turnpike": "turnpike", "zero": "zero", "ppo": "runs/x/best_model.zip"},
        env_id="agent_envs/Swarm-v0", env_kwargs={"n_agents": 20}, seeds=range(10),
    )
    results.save("eval_out")            # episodes.csv/.json, meta.json, trajectories/*.npz

A policy is any SB3 `PolicyPredictor` (an object with
``predict(obs, state, episode_start, deterministic) -> (action, state)``), a baseline name
("turnpike", "proportional", "zero", built for the env), a callable ``env -> PolicyPredictor``,
or the path of a saved SB3 model (``.zip``; ``ALGO:PATH`` to name the algorithm, otherwise it is
read from the file). A `VecNormalize` statistics file next to the model is found and applied to
the observations, frozen (see `find_vecnormalize`). A model trained on the PettingZoo env's
per-agent observations (shape (3d+1,)) is run on the Gymnasium env with one action per agent from
that agent's own observation (`PerAgentPolicy`), so every policy is scored in the same cost units.

Every policy runs on the same seeds (and the same `reset_options`), one fresh env per policy.
Per episode it records: total cost (minus the sum of rewards, i.e. the discrete cost functional
`eq:discrete_cost_functional` on the env's paths), final distance to the target (RMS over agents
of E x_k(T) - xbar), the Lyapunov value ||E x^m - xbar||^2, divergence, control energy
tau sum_n (1/N) sum_k |u_k^n|^2, and the fraction of saturated controls; per step: the path-mean
positions, controls, running cost and turnpike distance ||E x^n - xbar||^2 + ||u^n||^2.
A diverged episode ends early (env `terminated`): its cost covers only the steps it ran, so read
costs together with the divergence rate.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import re
import time
import zipfile
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

DEFAULT_ENV_ID = "agent_envs/Swarm-v0"
#: held-out evaluation seeds used when none are given (training seeds are usually small ints)
DEFAULT_SEEDS = tuple(range(10_000, 10_020))
DEFAULT_POLICIES = ("turnpike", "proportional", "zero")
#: saturation tolerance: |u| >= (1 - SATURATION_TOL) max_control counts as saturated
SATURATION_TOL = 1e-6

EPISODE_COLUMNS = (
    "policy",
    "seed",
    "total_cost",
    "final_distance",
    "final_sq_distance",
    "diverged",
    "divergence_step",
    "control_energy",
    "saturated_fraction",
    "turnpike_time",
    "n_steps_run",
    "wall_time_s",
)


# --------------------------------------------------------------------------------------------
# Loading policies
# --------------------------------------------------------------------------------------------

#: SB3 algorithms a saved model can be loaded with, by name
SB3_ALGOS = ("ppo", "a2c", "sac", "td3", "ddpg", "dqn")


def _sb3_class(algo: str):
    import stable_baselines3 as sb3

    algo = algo.lower()
    if algo not in SB3_ALGOS:
        raise ValueError(f"unknown SB3 algorithm {algo!r}; choose one of {SB3_ALGOS}")
    return getattr(sb3, algo.upper())


def detect_algo(path: str | os.PathLike) -> str:
    """The SB3 algorithm of a saved model, read from its zip's ``data`` (policy class, fields).

    SAC/TD3/DQN have their own policy modules; ActorCriticPolicy is PPO when the file has
    PPO's ``clip_range``, else A2C. Raises ValueError when it cannot tell (use ``ALGO:PATH``).
    """
    with zipfile.ZipFile(path) as zf:
        data = json.loads(zf.read("data"))
    module = str(data.get("policy_class", {}).get("__module__", ""))
    for algo in ("sac", "td3", "dqn"):
        if f"stable_baselines3.{algo}." in module:
            return algo
    if module.startswith("stable_baselines3.common.policies"):
        return "ppo" if "clip_range" in data else "a2c"
    raise ValueError(
        f"cannot tell the SB3 algorithm of {path} (policy module {module!r}); "
        "give it as ALGO:PATH, e.g. ppo:model.zip"
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
    docs/CONTRACT.md); the inner policy acts on all B*N rows at once and the actions are
    concatenated agent-major into (B, N d). Parameter-shared multi-agent policies are thus scored
    on the single-controller env, same seeds, same cost units.
    """

    def __init__(self, policy: Any, n_agents: int, dim: int) -> None:
        self.policy = policy
        self.n_agents = n_agents
        self.dim = dim

    def agent_rows(self, observation: np.ndarray) -> np.ndarray:
        from agent_envs.envs.observation import split_observation

        obs = np.asarray(observation, dtype=np.float32)
        batch = obs[None] if obs.ndim == 1 else obs
        parts = split_observation(batch, self.n_agents, self.dim)
        b, n, d = batch.shape[0], self.n_agents, self.dim
        rows = np.concatenate(
            [
                parts["positions"],
                parts["interaction_drift"],
                np.broadcast_to(parts["target"][:, None, :], (b, n, d)),
                np.broadcast_to(np.asarray(parts["time_fraction"])[:, None, None], (b, n, 1)),
            ],
            axis=-1,
        )
        return rows.reshape(b * n, 3 * d + 1).astype(np.float32)

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
    if match and match.group(1).lower() in SB3_ALGOS:
        algo, text = match.group(1).lower(), match.group(2)
    path = Path(text)
    if not path.is_file() and Path(text + ".zip").is_file():
        path = Path(text + ".zip")
    if not path.is_file():
        raise FileNotFoundError(f"no saved model at {text!r} (and no baseline of that name)")
    algo = algo or detect_algo(path)
    model = _sb3_class(algo).load(path, device=device)
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
        return load_sb3_policy(name, env)
    if hasattr(spec, "predict"):
        return spec, {"kind": "object", "type": type(spec).__name__}
    if callable(spec):
        policy = spec(env)
        if not hasattr(policy, "predict"):
            raise TypeError("a policy factory must return an object with predict(...)")
        return policy, {"kind": "factory", "type": type(policy).__name__}
    raise TypeError(f"cannot make a policy from {spec!r}")


# --------------------------------------------------------------------------------------------
# Rollouts
# --------------------------------------------------------------------------------------------


@dataclass
class Episode:
    """One episode's per-step record (path means) and its summary scalars.

    Arrays: times (m+1,), mean_positions (m+1, N, d) (NaN after a divergence), controls (m, N, d),
    running_cost (m,), rewards (m,) (zeros after the episode ended), target (d,).
    """

    seed: int | None
    times: np.ndarray
    mean_positions: np.ndarray
    controls: np.ndarray
    running_cost: np.ndarray
    rewards: np.ndarray
    target: np.ndarray
    dt: float
    max_control: float
    diverged: bool
    divergence_step: int | None
    n_steps_run: int
    turnpike_time: float
    wall_time: float

    @property
    def total_cost(self) -> float:
        """Minus the sum of rewards = tau sum_n c(x^n, u^n) on the env's paths."""
        return float(-np.sum(self.rewards))

    @property
    def last_positions(self) -> np.ndarray:
        return self.mean_positions[self.n_steps_run]

    @property
    def final_sq_distance(self) -> float:
        """||E x^m - xbar||^2 (sum over agents and coordinates); NaN when diverged."""
        if self.diverged:
            return float("nan")
        return float(np.sum((self.last_positions - self.target) ** 2))

    @property
    def final_distance(self) -> float:
        """RMS over agents of |E x_k(T) - xbar|; NaN when diverged."""
        if self.diverged:
            return float("nan")
        return float(np.sqrt(np.mean(np.sum((self.last_positions - self.target) ** 2, -1))))

    @property
    def control_energy(self) -> float:
        """tau sum_n (1/N) sum_k |u_k^n|^2 (the control term of the cost without gamma)."""
        return float(self.dt * np.sum(np.mean(np.sum(self.controls**2, -1), -1)))

    @property
    def saturated_fraction(self) -> float:
        """Fraction of control entries at the bound max_control (clipped actions)."""
        run = self.controls[: self.n_steps_run]
        if run.size == 0:
            return 0.0
        return float(np.mean(np.abs(run) >= (1 - SATURATION_TOL) * self.max_control))

    def turnpike_distance(self) -> np.ndarray:
        """||E x^n - xbar||^2 + ||u^n||^2 for n = 0..m (u^m := 0); shape (m+1,)."""
        from agent_envs.costs import turnpike_distance

        u = np.concatenate([self.controls, np.zeros_like(self.controls[:1])], axis=0)
        return turnpike_distance(self.mean_positions, u, self.target)

    def summary(self) -> dict[str, Any]:
        return {
            "seed": self.seed,
            "total_cost": self.total_cost,
            "final_distance": self.final_distance,
            "final_sq_distance": self.final_sq_distance,
            "diverged": bool(self.diverged),
            "divergence_step": self.divergence_step,
            "control_energy": self.control_energy,
            "saturated_fraction": self.saturated_fraction,
            "turnpike_time": self.turnpike_time,
            "n_steps_run": self.n_steps_run,
            "wall_time_s": self.wall_time,
        }


def rollout(
    policy: Any,
    env: Any,
    seed: int | None = None,
    reset_options: Mapping[str, Any] | None = None,
    deterministic: bool = True,
) -> Episode:
    """Run one episode of `policy` on a Gymnasium swarm env and record it (see `Episode`).

    The policy is called the way SB3's `evaluate_policy` calls it on a one-env VecEnv: with a
    batch of one observation, the previous `state` and `episode_start`.
    """
    inner = env.unwrapped
    m = int(inner.n_steps)
    start = time.perf_counter()
    obs, _ = env.reset(seed=seed, options=dict(reset_options) if reset_options else None)
    params = inner.params
    n, d = params.n_agents, params.dim
    target = np.asarray(params.target_vector, dtype=float)
    mean_positions = np.full((m + 1, n, d), np.nan)
    mean_positions[0] = np.asarray(inner.positions, dtype=float).mean(axis=0)
    controls = np.zeros((m, n, d))
    running = np.zeros(m)
    rewards = np.zeros(m)
    state = None
    episode_start = np.ones(1, dtype=bool)
    diverged, divergence_step, steps = False, None, 0
    tbar = float("nan")
    for step in range(m):
        action, state = policy.predict(
            np.asarray(obs)[None],
            state=state,
            episode_start=episode_start,
            deterministic=deterministic,
        )
        episode_start[:] = False
        if step == 0:
            tb = getattr(policy, "turnpike_times", None)
            if tb is not None and len(tb):
                tbar = float(tb[0])
        obs, reward, terminated, truncated, info = env.step(np.asarray(action)[0])
        steps = step + 1
        rewards[step] = float(reward)
        controls[step] = np.asarray(info["control"], dtype=float).reshape(n, d)
        running[step] = float(info["running_cost"])
        if info.get("diverged", False):
            diverged, divergence_step = True, step + 1
            break
        mean_positions[step + 1] = np.asarray(info["positions"], dtype=float).mean(axis=0)
        if terminated or truncated:
            break
    return Episode(
        seed=seed,
        times=np.linspace(0.0, params.horizon, m + 1),
        mean_positions=mean_positions,
        controls=controls,
        running_cost=running,
        rewards=rewards,
        target=target,
        dt=float(inner.dt),
        max_control=float(inner.max_control),
        diverged=diverged,
        divergence_step=divergence_step,
        n_steps_run=steps,
        turnpike_time=tbar,
        wall_time=time.perf_counter() - start,
    )


# --------------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------------


def _safe_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_") or "policy"


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating, float)):
        v = float(value)
        return v if np.isfinite(v) else None
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (str, int, bool)) or value is None:
        return value
    return repr(value)


@dataclass
class EvaluationResults:
    """Per-episode table, per-policy trajectories and metadata of one evaluation.

    `trajectories[policy]` holds arrays over the seeds: ``seeds`` (S,), ``times`` (m+1,),
    ``mean_positions`` (S, m+1, N, d), ``controls`` (S, m, N, d), ``running_cost`` (S, m),
    ``turnpike_distance`` (S, m+1), ``target`` (S, d), ``turnpike_time`` (S,).
    """

    episodes: pd.DataFrame
    trajectories: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)
    source: Path | None = None

    @property
    def policies(self) -> list[str]:
        return list(dict.fromkeys(self.episodes["policy"]))

    def save(self, out_dir: str | os.PathLike) -> Path:
        """Write episodes.csv, episodes.json, meta.json and trajectories/{policy}.npz."""
        out = Path(out_dir)
        (out / "trajectories").mkdir(parents=True, exist_ok=True)
        self.episodes.to_csv(out / "episodes.csv", index=False)
        records = [_jsonable(r) for r in self.episodes.to_dict(orient="records")]
        (out / "episodes.json").write_text(json.dumps(records, indent=1))
        files = {}
        for policy, arrays in self.trajectories.items():
            fname = f"{_safe_name(policy)}.npz"
            files[policy] = f"trajectories/{fname}"
            np.savez_compressed(out / "trajectories" / fname, **arrays)
        meta = {**self.meta, "trajectory_files": files}
        (out / "meta.json").write_text(json.dumps(_jsonable(meta), indent=1))
        self.source = out
        return out

    @classmethod
    def load(cls, path: str | os.PathLike) -> EvaluationResults:
        """Load what `save` wrote (a folder, or its episodes.csv / meta.json)."""
        p = Path(path)
        folder = p if p.is_dir() else p.parent
        if not (folder / "episodes.csv").is_file():
            raise FileNotFoundError(f"no episodes.csv in {folder} (not an evaluation folder)")
        episodes = pd.read_csv(folder / "episodes.csv")
        meta = {}
        if (folder / "meta.json").is_file():
            meta = json.loads((folder / "meta.json").read_text())
        trajectories: dict[str, dict[str, np.ndarray]] = {}
        for policy, rel in meta.get("trajectory_files", {}).items():
            f = folder / rel
            if f.is_file():
                with np.load(f) as data:
                    trajectories[policy] = {k: data[k] for k in data.files}
        return cls(episodes=episodes, trajectories=trajectories, meta=meta, source=folder)


def _stack_episodes(episodes: Sequence[Episode]) -> dict[str, np.ndarray]:
    return {
        "seeds": np.array([-1 if e.seed is None else e.seed for e in episodes]),
        "times": episodes[0].times,
        "mean_positions": np.stack([e.mean_positions for e in episodes]),
        "controls": np.stack([e.controls for e in episodes]),
        "running_cost": np.stack(
            [
                np.where(np.arange(len(e.running_cost)) < e.n_steps_run, e.running_cost, np.nan)
                for e in episodes
            ]
        ),
        "turnpike_distance": np.stack([e.turnpike_distance() for e in episodes]),
        "target": np.stack([e.target for e in episodes]),
        "turnpike_time": np.array([e.turnpike_time for e in episodes]),
    }


def evaluate_policies(
    policies: Mapping[str, PolicySpec] | Sequence[str],
    env_id: str = DEFAULT_ENV_ID,
    env_kwargs: Mapping[str, Any] | None = None,
    seeds: Iterable[int] = DEFAULT_SEEDS,
    *,
    reset_options: Mapping[str, Any] | None = None,
    deterministic: bool = True,
    baseline_kwargs: Mapping[str, Any] | None = None,
    progress: bool = True,
    out_dir: str | os.PathLike | None = None,
) -> EvaluationResults:
    """Run every policy on `env_id` (+ `env_kwargs`) for each seed; the same seeds for all.

    Args:
        policies: {name: spec} (or a list of baseline names / model paths, named by themselves);
            a spec is a PolicyPredictor, a baseline name, a saved SB3 model path (``ALGO:PATH``
            allowed) or a callable ``env -> PolicyPredictor``.
        env_id: a Gymnasium id of a swarm env (default ``agent_envs/Swarm-v0``).
        env_kwargs: keyword arguments of `gym.make`.
        seeds: the reset seeds; episode i of every policy uses seeds[i].
        reset_options: options passed to every reset (e.g. {"target": 2.3}).
        deterministic: passed to `predict`.
        baseline_kwargs: extra arguments of the baselines (e.g. {"beta": 8.0}).
        progress: show a tqdm bar over the episodes.
        out_dir: when given, `save` the results there.
    """
    import gymnasium as gym
    from tqdm.auto import tqdm

    import agent_envs  # noqa: F401  (registers the env ids)
    from agent_envs.baselines import FeedbackController

    if not isinstance(policies, Mapping):
        policies = {
            os.fspath(p) if isinstance(p, (str, os.PathLike)) else repr(p): p for p in policies
        }
    if not policies:
        raise ValueError("no policies to evaluate")
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise ValueError("no seeds to evaluate on")
    env_kwargs = dict(env_kwargs or {})
    rows: list[dict[str, Any]] = []
    trajectories: dict[str, dict[str, np.ndarray]] = {}
    descriptions: dict[str, dict] = {}
    total = len(policies) * len(seeds)
    bar = tqdm(total=total, desc="evaluate", unit="ep", disable=not progress)
    env_info: dict[str, Any] = {}
    try:
        for name, spec in policies.items():
            env = gym.make(env_id, **env_kwargs)
            try:
                policy, desc = resolve_policy(spec, env, baseline_kwargs)
                descriptions[name] = desc
                episodes = []
                for seed in seeds:
                    bar.set_postfix_str(f"{name} seed={seed}")
                    if isinstance(policy, FeedbackController):
                        policy.reset()
                    ep = rollout(policy, env, seed, reset_options, deterministic)
                    episodes.append(ep)
                    rows.append({"policy": name, **ep.summary()})
                    bar.update(1)
                trajectories[name] = _stack_episodes(episodes)
                inner = env.unwrapped
                env_info = {
                    "dt": float(inner.dt),
                    "n_steps": int(inner.n_steps),
                    "n_paths": int(inner.n_paths),
                    "max_control": float(inner.max_control),
                    "integrator": str(inner.integrator_name),
                    "jacobian": str(getattr(inner, "jacobian", "")),
                    "params": {k: getattr(inner.params, k) for k in inner.params.field_names()},
                }
            finally:
                env.close()
    finally:
        bar.close()
    meta = {
        "env_id": env_id,
        "env_kwargs": env_kwargs,
        "reset_options": dict(reset_options or {}),
        "seeds": seeds,
        "deterministic": deterministic,
        "policies": descriptions,
        "env": env_info,
        "created": time.strftime("%Y-%m-%d %H:%M:%S"),
    }
    episodes_df = pd.DataFrame(rows, columns=list(EPISODE_COLUMNS))
    for col in ("divergence_step", "turnpike_time"):  # None -> NaN, as after a CSV round trip
        episodes_df[col] = pd.to_numeric(episodes_df[col], errors="coerce").astype(float)
    results = EvaluationResults(episodes=episodes_df, trajectories=trajectories, meta=meta)
    if out_dir is not None:
        results.save(out_dir)
    return results


# --------------------------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------------------------


def parse_env_kwargs(items: Sequence[str] | str | None) -> dict[str, Any]:
    """Env kwargs from a JSON object (``'{"n_agents": 20}'``) or ``key=value`` items.

    In ``key=value`` form each value is parsed as JSON when it can be (numbers, true/false,
    lists), else kept as a string: ``n_agents=20 integrator=em target=2.3``.
    """
    if items is None:
        return {}
    if isinstance(items, str):
        items = [items]
    items = [i for i in items if i.strip()]
    if len(items) == 1 and items[0].lstrip().startswith("{"):
        try:
            value = json.loads(items[0])
        except json.JSONDecodeError as exc:
            raise ValueError(f"--env-kwargs is not valid JSON: {exc}") from None
        if not isinstance(value, dict):
            raise ValueError("--env-kwargs JSON must be an object")
        return value
    out: dict[str, Any] = {}
    for item in items:
        if "=" not in item:
            raise ValueError(f"--env-kwargs item {item!r} is not key=value (or give a JSON object)")
        key, raw = item.split("=", 1)
        try:
            out[key.strip()] = json.loads(raw)
        except json.JSONDecodeError:
            out[key.strip()] = raw
    return out


def parse_seeds(items: Sequence[str] | None) -> list[int]:
    """Seeds from items like ``0 1 2``, ``0-19`` (inclusive) or ``0:20`` (half-open)."""
    if not items:
        return list(DEFAULT_SEEDS)
    seeds: list[int] = []
    for item in items:
        for part in str(item).split(","):
            part = part.strip()
            if not part:
                continue
            if ":" in part:
                a, b = part.split(":", 1)
                seeds.extend(range(int(a), int(b)))
            elif re.fullmatch(r"\d+-\d+", part):
                a, b = part.split("-", 1)
                seeds.extend(range(int(a), int(b) + 1))
            else:
                seeds.append(int(part))
    return seeds


def parse_policy_specs(items: Sequence[str] | None) -> dict[str, str]:
    """``NAME=SPEC`` or ``SPEC`` items -> {name: spec} (a bare path is named by its file stem)."""
    if not items:
        return {name: name for name in DEFAULT_POLICIES}
    out: dict[str, str] = {}
    for item in items:
        if "=" in item:
            name, spec = item.split("=", 1)
        else:
            spec = item
            name = Path(item.split(":", 1)[-1]).stem if item not in DEFAULT_POLICIES else item
        if name in out:
            raise ValueError(f"policy name {name!r} given twice; use NAME=SPEC to rename")
        out[name] = spec
    return out


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--policy",
        "-p",
        action="append",
        dest="policies",
        metavar="[NAME=]SPEC",
        help="a baseline (turnpike | proportional | zero | optimal | mpc) or a saved SB3 model "
        "PATH.zip (ALGO:PATH to name the algorithm); repeat for several. Default: turnpike, "
        "proportional, zero.",
    )
    parser.add_argument("--env-id", default=DEFAULT_ENV_ID, help="Gymnasium env id")
    parser.add_argument(
        "--env-kwargs",
        nargs="*",
        default=None,
        metavar="KEY=VALUE",
        help="env keyword arguments as key=value items or one JSON object",
    )
    parser.add_argument(
        "--seeds",
        nargs="*",
        default=None,
        help="reset seeds: '0 1 2', '0-19' or '0:20' (default 10000-10019)",
    )
    parser.add_argument("--target", type=float, default=None, help="reset option: the target")
    parser.add_argument("--beta", type=float, default=12.0, help="baselines' beta (paper: 12)")
    parser.add_argument("--delta", type=float, default=2e-4, help="baselines' delta (paper 2e-4)")
    parser.add_argument("--out", required=True, type=Path, help="output folder")
    parser.add_argument("--report", action="store_true", help="also write a report in OUT/report")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    try:
        policies = parse_policy_specs(args.policies)
        env_kwargs = parse_env_kwargs(args.env_kwargs)
        seeds = parse_seeds(args.seeds)
    except ValueError as exc:
        print(f"error: {exc}")
        return 2
    options = {"target": args.target} if args.target is not None else None
    results = evaluate_policies(
        policies,
        args.env_id,
        env_kwargs,
        seeds,
        reset_options=options,
        baseline_kwargs={"beta": args.beta, "delta": args.delta},
        progress=not args.no_progress,
        out_dir=args.out,
    )
    from agent_envs.training.report import display_table, summarize

    reference = "turnpike" if "turnpike" in policies else None
    table = display_table(summarize(results.episodes, reference), reference)
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        print(table.to_string(index=False))
    print(f"results written to {args.out}")
    if args.report:
        from agent_envs.training.report import build_report

        paths = build_report([results], args.out / "report")
        print(f"report: {paths['markdown']} and {paths['html']}")
    return 0


__all__ = [
    "DEFAULT_ENV_ID",
    "DEFAULT_SEEDS",
    "Episode",
    "EvaluationResults",
    "NormalizedObservationPolicy",
    "PerAgentPolicy",
    "detect_algo",
    "evaluate_policies",
    "find_vecnormalize",
    "load_sb3_policy",
    "parse_env_kwargs",
    "parse_policy_specs",
    "parse_seeds",
    "resolve_policy",
    "rollout",
    "vecnormalize_candidates",
]
