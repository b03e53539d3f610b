"""Evaluate policies on a swarm env over a fixed list of seeds (episodes by `results.rollout`).

    from agent_envs.training.commands.evaluate import evaluate_policies
    results = evaluate_policies(
        {"turnpike": "turnpike", "zero": "zero", "ppo": "runs/x/best_model.zip"},
        env_id="agent_envs/Swarm-v0", env_kwargs={"n_agents": 20}, seeds=range(10),
    )
    results.save("eval_out")            # episodes.csv/.json, meta.json, trajectories/*.npz

Policies are resolved by `agent_envs.training.learners.policies.resolve_policy` (a PolicyPredictor,
a baseline name, a saved SB3 model, or a factory); results are
`agent_envs.training.results.tables.EvaluationResults`.

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

import os
import time
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from agent_envs.training.commands.evaluate_options import EvaluateConfig, parse_policy_specs
from agent_envs.training.defaults import (
    DEFAULT_TEST_SEEDS,
    GYM_ENV_ID,
)
from agent_envs.training.learners.policies import PolicySpec, resolve_policy
from agent_envs.training.results.rollout import make_swarm_env, rollout
from agent_envs.training.results.tables import (
    EPISODE_COLUMNS,
    Episode,
    EvaluationResults,
    stack_episodes,
)
from agent_envs.training.storage import check_output_dir


def _env_info(env: Any) -> dict[str, Any]:
    """What the results' meta.json records of the env a policy ran on."""
    inner = env.unwrapped
    return {
        "dt": float(inner.dt),
        "n_steps": int(inner.n_steps),
        "n_paths": int(inner.n_paths),
        "max_control": float(inner.max_control),
        "integrator": str(inner.integrator_name),
        "jacobian": str(getattr(inner, "jacobian", "")),
        "params": {k: getattr(inner.params, k) for k in inner.params.field_names()},
    }


def _open_policies(
    policies: Mapping[str, PolicySpec],
    env_id: str,
    env_kwargs: dict[str, Any],
    baseline_kwargs: Mapping[str, Any] | None,
    envs: dict[str, Any],
) -> tuple[dict[str, Any], dict[str, dict]]:
    """One env per policy (into `envs`, which the caller closes) and the policy built or loaded
    for it: (policies by name, their descriptions). Raises on the first bad env or policy."""
    resolved: dict[str, Any] = {}
    descriptions: dict[str, dict] = {}
    for name, spec in policies.items():
        env = envs[name] = make_swarm_env(env_id, env_kwargs)
        resolved[name], descriptions[name] = resolve_policy(spec, env, baseline_kwargs)
    return resolved, descriptions


def _run_policy(
    name: str,
    policy: Any,
    env: Any,
    seeds: list[int],
    reset_options: Mapping[str, Any] | None,
    deterministic: bool,
    bar: Any,
) -> list[Episode]:
    """One episode of `policy` per seed on `env`, advancing the progress `bar`."""
    from agent_envs.baselines import FeedbackController

    episodes = []
    for seed in seeds:
        bar.set_postfix_str(f"{name} seed={seed}")
        if isinstance(policy, FeedbackController):
            policy.reset()
        episodes.append(rollout(policy, env, seed, reset_options, deterministic))
        bar.update(1)
    return episodes


def _run_all(
    resolved: dict[str, Any],
    envs: dict[str, Any],
    seeds: list[int],
    reset_options: Mapping[str, Any] | None,
    deterministic: bool,
    progress: bool,
) -> tuple[list[dict[str, Any]], dict[str, dict[str, np.ndarray]], dict[str, Any]]:
    """Every policy on every seed, under one progress bar: (episode rows, trajectories per
    policy, the env's description)."""
    from tqdm.auto import tqdm

    rows: list[dict[str, Any]] = []
    trajectories: dict[str, dict[str, np.ndarray]] = {}
    env_info: dict[str, Any] = {}
    bar = tqdm(total=len(resolved) * len(seeds), desc="evaluate", unit="ep", disable=not progress)
    try:
        for name, policy in resolved.items():
            episodes = _run_policy(
                name, policy, envs[name], seeds, reset_options, deterministic, bar
            )
            rows += [{"policy": name, **ep.summary()} for ep in episodes]
            trajectories[name] = stack_episodes(episodes)
            env_info = _env_info(envs[name])
    finally:
        bar.close()
    return rows, trajectories, env_info


def _named(policies: Mapping[str, PolicySpec] | Sequence[str]) -> dict[str, PolicySpec]:
    """{name: spec}: a list of baseline names / model paths is named by itself."""
    if not isinstance(policies, Mapping):
        policies = {
            os.fspath(p) if isinstance(p, (str, os.PathLike)) else repr(p): p for p in policies
        }
    if not policies:
        raise ValueError("no policies to evaluate")
    return dict(policies)


def _episodes_table(rows: list[dict[str, Any]]) -> pd.DataFrame:
    """The per-episode rows as the results' table (None -> NaN, as after a CSV round trip)."""
    episodes_df = pd.DataFrame(rows, columns=list(EPISODE_COLUMNS))
    for col in ("divergence_step", "turnpike_time"):
        episodes_df[col] = pd.to_numeric(episodes_df[col], errors="coerce").astype(float)
    return episodes_df


def evaluate_policies(
    policies: Mapping[str, PolicySpec] | Sequence[str],
    env_id: str = GYM_ENV_ID,
    env_kwargs: Mapping[str, Any] | None = None,
    seeds: Iterable[int] = DEFAULT_TEST_SEEDS,
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
    from agent_envs.validation import check_seed

    policies = _named(policies)
    seeds = [check_seed(s) for s in seeds]
    if not seeds:
        raise ValueError("no seeds to evaluate on")
    env_kwargs = dict(env_kwargs or {})
    if out_dir is not None:
        check_output_dir(out_dir, "out_dir")
    # Every input is checked before the first episode: the env (id, kwargs, reset options),
    # every policy (built or loaded for its own env) and the seeds.
    envs: dict[str, Any] = {}
    try:
        resolved, descriptions = _open_policies(policies, env_id, env_kwargs, baseline_kwargs, envs)
        first = next(iter(envs.values()))
        first.reset(seed=seeds[0], options=dict(reset_options) if reset_options else None)
        rows, trajectories, env_info = _run_all(
            resolved, envs, seeds, reset_options, deterministic, progress
        )
    finally:
        for env in envs.values():
            env.close()
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
    results = EvaluationResults(_episodes_table(rows), trajectories, meta)
    if out_dir is not None:
        results.save(out_dir)
    return results


__all__ = [
    "EvaluateConfig",
    "evaluate_policies",
    "parse_policy_specs",
]
