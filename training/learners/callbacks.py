"""Evaluation during training, read against the turnpike controller on the same seeds.

`SwarmEvalCallback` is SB3's `EvalCallback` with three changes that the comparison needs:

1. every evaluation runs the *same* validation episodes: one env per episode, env i reset with
   seed ``eval_seed + i`` (SB3's `VecEnv.seed` convention), so two evaluations differ only by
   the policy;
2. the reference controllers (turnpike, proportional and zero in `agent-envs train`) are run
   once on those seeds, and their costs are logged next to the learner's at every evaluation
   (`eval/turnpike_cost`, `eval/cost_ratio_to_turnpike`, ...), so the learning curve is read
   against the reference lines in TensorBoard and in ``learning_curve.csv``;
3. the learner is evaluated as a `PolicyPredictor` on the raw env
   (`agent_envs.training.learners.policies.NormalizedObservationPolicy` applies the live
   `VecNormalize` statistics; `agent_envs.training.learners.policies.PerAgentPolicy` runs a
   parameter-shared PettingZoo policy on the Gymnasium env), and the `VecNormalize` statistics are
   saved with the best model (SB3's own `EvalCallback` saves only the model).

Costs are minus the episode's summed reward, which the env defines as the paper's discrete
cost functional.
"""

from __future__ import annotations

import csv
import math
import os
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import EvalCallback
from stable_baselines3.common.vec_env import VecEnv

from agent_envs.training.learners.checkpoints import BEST_MODEL, save_model_with_statistics
from agent_envs.training.results.tables import mean_confidence_interval
from agent_envs.training.storage import atomic_path


def mean_ci95(values: np.ndarray) -> tuple[float, float]:
    """Mean and half-width of the t 95% interval (`results.mean_confidence_interval`)."""
    mean, low, high = mean_confidence_interval(values, 0.95)
    return mean, (high - low) / 2


def run_seeded_episodes(
    policy: Any, venv: VecEnv, seed: int, deterministic: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """One episode per sub-env, sub-env i reset with ``seed + i``; returns (costs, diverged).

    `policy` is any `PolicyPredictor`; it gets the batch of raw observations. The cost of an
    episode is minus the sum of its rewards; `diverged` is the env's `info["diverged"]` at the
    episode's end. Sub-envs that finish first keep stepping (auto-reset) but are not counted.
    """
    n = venv.num_envs
    venv.seed(int(seed))
    observation = venv.reset()
    costs = np.zeros(n)
    finished = np.zeros(n, dtype=bool)
    diverged = np.zeros(n, dtype=bool)
    state = None
    episode_start = np.ones(n, dtype=bool)
    while not finished.all():
        actions, state = policy.predict(
            observation, state=state, episode_start=episode_start, deterministic=deterministic
        )
        observation, rewards, dones, infos = venv.step(actions)
        active = ~finished
        costs[active] -= rewards[active]
        for i in np.flatnonzero(active & dones):
            finished[i] = True
            diverged[i] = bool(infos[i].get("diverged", False))
        episode_start = dones
    return costs, diverged


class SwarmEvalCallback(EvalCallback):
    """`EvalCallback` on fixed validation seeds with reference controllers' costs logged.

    Args:
        eval_env: a raw (unnormalized) VecEnv of the Gymnasium swarm env with one sub-env per
            validation episode.
        policy_factory: builds the `PolicyPredictor` to evaluate from the model being trained
            (e.g. ``lambda m: NormalizedObservationPolicy(m, m.get_vec_normalize_env())``).
        references: name -> `PolicyPredictor` run on the same seeds once (the turnpike
            controller first; its cost is the denominator of the logged ratio).
        eval_seed: seed of the first validation episode.
        eval_freq: evaluate every `eval_freq` callback calls (SB3 counts calls, i.e. steps of
            the vectorized training env).
        run_dir: where ``learning_curve.csv``, ``evaluations.npz`` and the best model go.
        history: rows of an earlier ``learning_curve.csv`` to continue (resume).
        on_evaluation: called with each evaluation's row after it is logged (e.g. to report
            the validation cost to a tuner).
        reference_env: where the references run (default `eval_env`): the same env with the
            default interface when the learner's has other env options (observation layout,
            action basis), which the references may not read.
    """

    def __init__(
        self,
        eval_env: VecEnv,
        policy_factory: Callable[[Any], Any],
        references: Mapping[str, Any],
        *,
        eval_seed: int,
        eval_freq: int,
        run_dir: str | os.PathLike,
        history: list[dict[str, Any]] | None = None,
        on_evaluation: Callable[[dict[str, Any]], None] | None = None,
        reference_env: VecEnv | None = None,
        verbose: int = 0,
    ) -> None:
        run_dir = Path(run_dir)
        super().__init__(
            eval_env,
            n_eval_episodes=eval_env.num_envs,
            eval_freq=eval_freq,
            log_path=str(run_dir),
            best_model_save_path=str(run_dir),
            deterministic=True,
            verbose=verbose,
            warn=False,
        )
        self.policy_factory = policy_factory
        self.references = dict(references)
        self.reference_env = eval_env if reference_env is None else reference_env
        self.eval_seed = int(eval_seed)
        self.run_dir = run_dir
        self.curve_path = run_dir / "learning_curve.csv"
        self.reference_costs: dict[str, np.ndarray] = {}
        self.history: list[dict[str, Any]] = list(history or [])
        self.on_evaluation = on_evaluation
        self._start_time = time.perf_counter()
        self._wall_offset = float(self.history[-1]["wall_time_s"]) if self.history else 0.0
        for row in self.history:
            self.evaluations_timesteps.append(int(row["timesteps"]))
            self.evaluations_results.append([-float(row["cost_mean"])])
            self.evaluations_length.append([0])
        if self.history:
            self.best_mean_reward = max(-float(r["cost_mean"]) for r in self.history)

    def _init_callback(self) -> None:
        # SB3 warns when the eval env is not wrapped like the training env; ours is raw on
        # purpose (normalization happens in the policy), so only the folders are made here.
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.evaluate_references()

    def evaluate_references(self) -> dict[str, np.ndarray]:
        """Run every reference controller on the validation seeds (once; deterministic)."""
        if not self.reference_costs:
            for name, policy in self.references.items():
                costs, _ = run_seeded_episodes(policy, self.reference_env, self.eval_seed)
                self.reference_costs[name] = costs
        return self.reference_costs

    def _on_step(self) -> bool:
        if self.eval_freq > 0 and self.n_calls % self.eval_freq == 0:
            self.evaluate_now()
        return True

    def evaluate_now(self) -> dict[str, Any]:
        """Evaluate the current policy on the validation seeds, log, save the best model."""
        policy = self.policy_factory(self.model)
        costs, diverged = run_seeded_episodes(policy, self.eval_env, self.eval_seed)
        mean, ci = mean_ci95(costs)
        row: dict[str, Any] = {
            "timesteps": int(self.num_timesteps),
            "wall_time_s": round(self._wall_offset + time.perf_counter() - self._start_time, 3),
            "cost_mean": mean,
            "cost_ci95": ci,
            "diverged_rate": float(np.mean(diverged)),
        }
        for name, ref in self.evaluate_references().items():
            row[f"{name}_cost"] = float(np.mean(ref))
        turnpike = row.get("turnpike_cost")
        if turnpike:
            row["cost_ratio_to_turnpike"] = mean / turnpike
        self.history.append(row)
        self._write_curve()

        self.evaluations_timesteps.append(self.num_timesteps)
        self.evaluations_results.append(list(-costs))
        self.evaluations_length.append([0] * len(costs))
        # SB3's EvalCallback layout (rl-zoo3's plot scripts read it): results and ep_lengths of
        # shape (n_evaluations, 1); one column, the mean over the validation episodes, since a
        # resumed curve keeps only means. ep_lengths holds the nominal episode length m.
        means = np.array([[np.mean(r)] for r in self.evaluations_results])
        n_steps = int(self.eval_env.get_attr("n_steps")[0])
        with atomic_path(f"{self.log_path}.npz") as tmp:
            np.savez(
                tmp,
                timesteps=np.array(self.evaluations_timesteps),
                results=means,
                ep_lengths=np.full(means.shape, n_steps),
            )
        self.last_mean_reward = -mean
        self.logger.record("eval/mean_reward", -mean)
        self.logger.record("eval/cost", mean)
        self.logger.record("eval/cost_ci95", ci)
        self.logger.record("eval/diverged_rate", row["diverged_rate"])
        for key, value in row.items():
            if key.endswith("_cost") or key == "cost_ratio_to_turnpike":
                self.logger.record(f"eval/{key}", value)
        self.logger.record("time/total_timesteps", self.num_timesteps, exclude="tensorboard")
        self.logger.dump(self.num_timesteps)
        if self.verbose >= 1:
            ratio = row.get("cost_ratio_to_turnpike", math.nan)
            print(
                f"eval @ {self.num_timesteps} steps: cost {mean:.4g} ± {ci:.2g} "
                f"(turnpike {turnpike if turnpike is not None else math.nan:.4g}, "
                f"ratio {ratio:.3g})"
            )
        if -mean > self.best_mean_reward:
            self.best_mean_reward = -mean
            save_model_with_statistics(self.model, self.run_dir, BEST_MODEL)
        if self.on_evaluation is not None:
            self.on_evaluation(row)
        return row

    def _write_curve(self) -> None:
        write_learning_curve(self.curve_path, self.history)


def write_learning_curve(path: str | os.PathLike, rows: list[dict[str, Any]]) -> None:
    """Write the evaluation rows as CSV (union of the rows' keys, in first-seen order)."""
    keys: list[str] = []
    for row in rows:
        keys.extend(k for k in row if k not in keys)
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=keys)
        writer.writeheader()
        writer.writerows(rows)


def read_learning_curve(path: str | os.PathLike, max_timesteps: int | None = None):
    """Rows of a ``learning_curve.csv`` (numbers parsed), optionally up to `max_timesteps`."""
    path = Path(path)
    if not path.exists():
        return []
    rows = []
    with open(path, newline="") as handle:
        for raw in csv.DictReader(handle):
            row: dict[str, Any] = {}
            for key, value in raw.items():
                try:
                    row[key] = float(value) if value not in ("", None) else math.nan
                except ValueError:
                    row[key] = value
            row["timesteps"] = int(row["timesteps"])
            if max_timesteps is None or row["timesteps"] <= max_timesteps:
                rows.append(row)
    return rows
