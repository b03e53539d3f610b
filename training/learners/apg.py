"""`apg`: a feedback law trained by analytic policy gradients through the core's integrator.

The learner (after Brax's `brax/training/agents/apg/train.py`: unroll, loss = the cost, Adam
with gradient clipping, periodic evaluation) for the swarm env `agent_envs/Swarm-v0`:

1. an episode is the env's episode computed on torch by the core's own integrator
   (`apg_rollout.ClosedLoop`: `simulate(..., control=law)`, float64), from a start drawn from
   the env's initial distribution and Brownian increments drawn by a numpy generator the
   trainer owns (seeded by `APGConfig.seed`; never global state);
2. the loss is the discrete cost functional `eq:discrete_cost_functional` (mean over the
   episode's K paths and over `episodes_per_iteration` episodes), back-propagated over the whole
   horizon (m steps; no truncated windows: with SERB the gradient through m = 50 steps stays
   finite and exact, and the target is met without truncation, which was therefore not
   measured; with EM at eps = 0.05 the gradient is 1e15-1e16 and no window length fixes the
   instability of the step itself, docs/learners/apg.md);
3. Adam with the gradient's norm clipped to `max_grad_norm` and a cosine learning-rate decay
   to `final_learning_rate_fraction` of the rates (a constant rate leaves the law rattling
   around the optimum; the per-iteration gradient is a one-start sample);
4. every `eval_freq` iterations the law is evaluated on the validation episodes (env seeds
   `eval_seed`, `eval_seed + 1`, ..., computed in process on exactly the env's noise, see
   `apg_rollout.EpisodeNoise.for_env_seed`), a row is added to ``learning_curve.csv`` (the
   columns of the SB3 runs' `SwarmEvalCallback`, with the reference controllers' costs on the
   same seeds) and to TensorBoard, and the best law so far is kept (``best_apg_law.pt``).

A run folder (`train_apg`) holds ``config.json``, ``env.json``, ``apg_law.json`` (the law's
description), ``checkpoints/apg_{iteration}.pt`` (law, optimizer, scheduler; the generator's
state in ``checkpoints/apg_{iteration}.json``), ``best_apg_law.pt``, ``final_apg_law.pt``,
``learning_curve.csv``, ``summary.json``, ``tb/`` and ``manifest.json`` (the SHA-256 of every
weights file, `agent_envs.training.storage.RunManifest`). Everything is written atomically; the
folder is created exclusively and locked while a process trains in it; weights are torch
``state_dict``s read back with ``torch.load(weights_only=True)``. ``resume=True`` continues
from the newest checkpoint whose files match the manifest (a damaged newer one is skipped with
a line on stderr), bit for bit as if the run had not stopped.

Public API: `train_apg(config, run_dir, resume=False) -> summary dict` (the run's settings,
`APGConfig`, `from_train_options` and `default_run_dir`, are in `apg_config`),
`load_apg_policy(run_dir_or_weights) -> SwarmFeedbackPolicy`, `is_apg_run(path)` (the last two
defined in `apg_policy`, which `policies.resolve_policy` may import).
"""

from __future__ import annotations

import json
import math
import os
import re
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from agent_envs.training.defaults import (
    GYM_ENV_ID,
)
from agent_envs.training.learners.apg_config import APGConfig
from agent_envs.training.learners.apg_policy import (
    BEST_LAW,
    FINAL_LAW,
    LAW_DESCRIPTION,
    SwarmFeedbackLaw,
    describe_law,
    is_apg_run,
    load_apg_policy,
    save_law,
)
from agent_envs.training.learners.apg_rollout import ClosedLoop, EpisodeNoise
from agent_envs.training.learners.callbacks import (
    mean_ci95,
    read_learning_curve,
    write_learning_curve,
)
from agent_envs.training.learners.environments import env_description
from agent_envs.training.storage import (
    RunLock,
    RunManifest,
    create_run_directory,
    remove_stale_temporaries,
    save_recorded,
    write_json_atomic,
)

CHECKPOINT_DIR = "checkpoints"
_CHECKPOINT = re.compile(r"apg_(\d+)\.pt")


# ------------------------------------------------------------------------------ checkpoints


def _checkpoint_path(run_dir: Path, iteration: int) -> Path:
    return run_dir / CHECKPOINT_DIR / f"apg_{iteration}.pt"


def _checkpoint_iterations(run_dir: Path) -> list[int]:
    found = []
    for path in (run_dir / CHECKPOINT_DIR).glob("apg_*.pt"):
        match = _CHECKPOINT.fullmatch(path.name)
        if match:
            found.append(int(match.group(1)))
    return sorted(found, reverse=True)


def _resume_point(run_dir: Path) -> tuple[int, Path, Path]:
    """(iteration, weights, generator state) of the newest checkpoint matching the manifest."""
    manifest = RunManifest(run_dir)
    skipped = []
    for iteration in _checkpoint_iterations(run_dir):
        weights = _checkpoint_path(run_dir, iteration)
        state = weights.with_suffix(".json")
        problem = manifest.problem(weights) or manifest.problem(state)
        if problem is None:
            for line in skipped:
                print(f"apg --resume: skipped {line}", file=sys.stderr)
            return iteration, weights, state
        skipped.append(f"checkpoint {iteration}: {problem}")
    detail = f" ({' | '.join(skipped)})" if skipped else ""
    raise ValueError(f"resume {run_dir}: no valid apg checkpoint{detail}; start a new run")


def _save_checkpoint(run_dir: Path, iteration: int, trainer: _Trainer) -> None:
    weights = _checkpoint_path(run_dir, iteration)
    weights.parent.mkdir(exist_ok=True)
    state = {
        "law": trainer.law.state_dict(),
        "optimizer": trainer.optimizer.state_dict(),
        "scheduler": trainer.scheduler.state_dict(),
        "iteration": iteration,
    }
    books = {
        "iteration": iteration,
        "generator": trainer.rng.bit_generator.state,
        "best_cost": trainer.best_cost,
        "wall_time_s": trainer.wall_time(),
        "cpu_time_s": trainer.cpu_time(),
    }
    save_recorded(run_dir, weights.with_suffix(".json"), lambda p: p.write_text(json.dumps(books)))
    save_recorded(run_dir, weights, lambda p: torch.save(state, p))


# ------------------------------------------------------------------------------ training


class _Trainer:
    """The state of one run: law, optimizer, schedule, generator, validation, books."""

    def __init__(self, config: APGConfig, run_dir: Path) -> None:
        self.config = config
        self.run_dir = run_dir
        env_config = config.episode_config()
        self.env_config = env_config
        train_config = env_config
        if config.train_paths is not None:
            train_config = env_config.replace(n_paths=config.train_paths)
        self.train_loop = ClosedLoop(train_config, config.phi_method)
        self.train_config = train_config
        self.eval_loop = ClosedLoop(env_config, config.phi_method)
        self.spec = config.law_spec()
        self.law = SwarmFeedbackLaw(self.spec, seed=config.seed)
        gains = [self.law.centre_gain, self.law.offset_gain, self.law.drift_gain]
        groups = [{"params": gains, "lr": config.learning_rate}]
        if self.law.mlp is not None:
            groups.append(
                {"params": list(self.law.mlp.parameters()), "lr": config.mlp_learning_rate}
            )
        self.optimizer = torch.optim.Adam(groups)
        fraction = config.final_learning_rate_fraction
        iterations = config.iterations

        def cosine(step: int) -> float:
            progress = min(step, iterations) / iterations
            return fraction + (1.0 - fraction) * 0.5 * (1.0 + math.cos(math.pi * progress))

        self.scheduler = torch.optim.lr_scheduler.LambdaLR(self.optimizer, cosine)
        self.rng = np.random.default_rng(np.random.SeedSequence(config.seed))
        self.eval_seeds = [config.eval_seed + i for i in range(config.n_eval_episodes)]
        self._eval_noise = [EpisodeNoise.for_env_seed(s, env_config) for s in self.eval_seeds]
        self.best_cost = math.inf
        self.history: list[dict[str, Any]] = []
        self.reference_costs: dict[str, float] = {}
        self._started = time.perf_counter()
        self._cpu_started = time.process_time()
        self._wall_offset = 0.0
        self._cpu_offset = 0.0

    def wall_time(self) -> float:
        return self._wall_offset + time.perf_counter() - self._started

    def cpu_time(self) -> float:
        """CPU seconds of this process spent on the run (resumed parts included); on a shared
        machine the wall time also counts the waits for a core."""
        return self._cpu_offset + time.process_time() - self._cpu_started

    def step(self) -> tuple[float, float]:
        """One Adam step on fresh episodes; returns the mean training cost and the gradient's
        norm before clipping."""
        self.optimizer.zero_grad(set_to_none=True)
        k = self.config.episodes_per_iteration
        total = 0.0
        for _ in range(k):
            noise = EpisodeNoise.draw(self.rng, self.train_config)
            cost, diverged = self.train_loop.cost(self.law, noise)
            if diverged or not bool(torch.isfinite(cost)):
                raise FloatingPointError(
                    "a training episode diverged under the law; lower learning_rate or "
                    "max_grad_norm, or use a stabler integrator (docs/learners/apg.md)"
                )
            (cost / k).backward()
            total += float(cost.detach()) / k
        grads = [p.grad for p in self.law.parameters() if p.grad is not None]
        if not all(bool(torch.all(torch.isfinite(g))) for g in grads):
            raise FloatingPointError(
                "the gradient of the cost is not finite (an unstable integrator: EM at small "
                "epsilon; docs/learners/apg.md)"
            )
        norm = torch.nn.utils.clip_grad_norm_(self.law.parameters(), self.config.max_grad_norm)
        self.optimizer.step()
        self.scheduler.step()
        return total, float(norm)

    def validation_costs(self) -> tuple[np.ndarray, np.ndarray]:
        """The law's cost on each validation episode and which diverged."""
        costs, diverged = [], []
        with torch.no_grad():
            for noise in self._eval_noise:
                cost, bad = self.eval_loop.cost(self.law, noise)
                costs.append(float(cost))
                diverged.append(bad)
        return np.array(costs), np.array(diverged)

    def evaluate_references(self) -> dict[str, float]:
        """Mean cost of every reference controller on the validation seeds (env rollouts)."""
        if self.reference_costs or not self.config.references:
            return self.reference_costs
        from agent_envs.baselines import make_baseline
        from agent_envs.training.results.rollout import make_swarm_env, rollout

        env = make_swarm_env(GYM_ENV_ID, self.config.env_kwargs)
        try:
            for name in self.config.references:
                policy = make_baseline(name, env)
                costs = []
                for seed in self.eval_seeds:
                    if hasattr(policy, "reset"):
                        policy.reset()
                    costs.append(float(-rollout(policy, env, seed).rewards.sum()))
                self.reference_costs[name] = float(np.mean(costs))
        finally:
            env.close()
        return self.reference_costs


def _write_law(run_dir: Path, name: str, law: SwarmFeedbackLaw) -> None:
    save_recorded(run_dir, run_dir / name, lambda p: save_law(law, p))


def train_apg(
    config: APGConfig, run_dir: str | os.PathLike, *, resume: bool = False
) -> dict[str, Any]:
    """Train (or continue) an `apg` run in `run_dir`; return its summary (also summary.json).

    A new run creates `run_dir` exclusively (`storage.create_run_directory`: an existing folder
    is an error naming --resume); ``resume=True`` needs the folder, its config.json equal to
    `config` except for `iterations` (which may grow), `progress`, `eval_freq`, `checkpoint_freq`
    and `threads` (none changes the training's arithmetic), and a valid checkpoint.
    The folder is locked (`storage.RunLock`) for the whole run. Resuming with more iterations
    stretches the cosine schedule over the new total from where the run stopped. Ctrl-C
    (KeyboardInterrupt) saves a checkpoint of the last whole iteration, then propagates.
    """
    if not isinstance(config, APGConfig):
        raise TypeError(f"config must be an APGConfig, got {type(config).__name__}")
    run_dir = Path(run_dir)
    if resume:
        if not (run_dir / "config.json").is_file():
            raise ValueError(f"resume {run_dir}: not an apg run folder (no config.json)")
        saved = APGConfig.from_dict(json.loads((run_dir / "config.json").read_text()))
        ignore = {"iterations", "progress", "eval_freq", "checkpoint_freq", "threads"}
        # compared as JSON (a tuple target of d > 1 comes back from config.json as a list)
        now, then = (
            json.loads(json.dumps(config.to_dict())),
            json.loads(json.dumps(saved.to_dict())),
        )
        diff = sorted(k for k, v in now.items() if k not in ignore and then[k] != v)
        if diff:
            raise ValueError(f"resume {run_dir}: config differs from the run's in {diff}")
        if config.iterations < saved.iterations:
            raise ValueError(
                f"iterations must be >= the run's {saved.iterations} to resume, "
                f"got {config.iterations}"
            )
    else:
        create_run_directory(run_dir)
    import torch as _torch

    previous_threads = _torch.get_num_threads()
    with RunLock(run_dir):
        _torch.set_num_threads(config.threads)
        try:
            return _train_locked(config, run_dir, resume)
        finally:
            _torch.set_num_threads(previous_threads)


def _restore(trainer: _Trainer, run_dir: Path) -> int:
    """Load the newest valid checkpoint into `trainer` (law, Adam, schedule, generator, books,
    the learning curve up to it); return its iteration."""
    remove_stale_temporaries(run_dir)
    remove_stale_temporaries(run_dir / CHECKPOINT_DIR)
    iteration, weights, books_path = _resume_point(run_dir)
    state = torch.load(weights, map_location="cpu", weights_only=True)
    books = json.loads(books_path.read_text())
    trainer.law.load_state_dict(state["law"])
    trainer.optimizer.load_state_dict(state["optimizer"])
    trainer.scheduler.load_state_dict(state["scheduler"])
    trainer.rng.bit_generator.state = books["generator"]
    trainer.best_cost = float(books["best_cost"])
    trainer._wall_offset = float(books["wall_time_s"])
    trainer._cpu_offset = float(books.get("cpu_time_s", 0.0))
    trainer.history = [
        r
        for r in read_learning_curve(run_dir / "learning_curve.csv")
        if r.get("iteration", 0) <= iteration
    ]
    return iteration


def _validate(
    trainer: _Trainer, run_dir: Path, writer: Any, row_head: dict[str, Any]
) -> dict[str, Any]:
    """Validate the law on the validation seeds: a learning-curve row (the SB3 runs' columns
    and `row_head`'s iteration, train_cost, grad_norm), TensorBoard, and the best law kept."""
    costs, diverged = trainer.validation_costs()
    mean, ci = mean_ci95(costs) if len(costs) > 1 else (float(costs[0]), 0.0)
    row: dict[str, Any] = {
        "timesteps": row_head["timesteps"],
        "wall_time_s": round(trainer.wall_time(), 3),
        "cost_mean": mean,
        "cost_ci95": ci,
        "diverged_rate": float(np.mean(diverged)),
    }
    for name, value in trainer.evaluate_references().items():
        row[f"{name}_cost"] = value
    if row.get("turnpike_cost"):
        row["cost_ratio_to_turnpike"] = mean / row["turnpike_cost"]
    row.update({k: v for k, v in row_head.items() if k != "timesteps"})
    trainer.history.append(row)
    write_learning_curve(run_dir / "learning_curve.csv", trainer.history)
    for key, value in row.items():
        if key.endswith("_cost") or key in ("cost_ci95", "diverged_rate"):
            writer.add_scalar(f"eval/{key}", value, row["timesteps"])
    writer.add_scalar("eval/cost", mean, row["timesteps"])
    writer.flush()
    if np.isfinite(mean) and mean < trainer.best_cost:
        trainer.best_cost = mean
        _write_law(run_dir, BEST_LAW, trainer.law)
    return row


def _iterate(trainer: _Trainer, run_dir: Path, start: int, writer: Any, bar: Any) -> None:
    """Adam steps `start + 1 .. iterations`, validating every `eval_freq` and checkpointing
    every `checkpoint_freq` (and at the end). Ctrl-C keeps the last whole iteration (not one
    stopped inside its Adam step, whose weights may be half-updated), so a resume loses
    nothing."""
    config = trainer.config
    per_iteration = config.episodes_per_iteration * trainer.env_config.n_steps

    def head(iteration: int, train_cost: float, grad_norm: float) -> dict[str, Any]:
        return {
            "timesteps": iteration * per_iteration,
            "iteration": iteration,
            "train_cost": train_cost,
            "grad_norm": grad_norm,
        }

    done, saved, in_step = start, start, False
    try:
        if start == 0:
            _validate(trainer, run_dir, writer, head(0, math.nan, math.nan))
        for iteration in range(start + 1, config.iterations + 1):
            in_step = True
            train_cost, grad_norm = trainer.step()
            in_step, done = False, iteration
            writer.add_scalar("train/cost", train_cost, iteration * per_iteration)
            writer.add_scalar("train/grad_norm", grad_norm, iteration * per_iteration)
            writer.add_scalar(
                "train/learning_rate", trainer.scheduler.get_last_lr()[0], iteration * per_iteration
            )
            bar.update(1)
            if iteration % config.eval_freq == 0 or iteration == config.iterations:
                row = _validate(trainer, run_dir, writer, head(iteration, train_cost, grad_norm))
                bar.set_postfix_str(f"val {row['cost_mean']:.5g}")
            if iteration % config.checkpoint_freq == 0 or iteration == config.iterations:
                _save_checkpoint(run_dir, iteration, trainer)
                saved = iteration
    except KeyboardInterrupt:
        if not in_step and done > saved:
            _save_checkpoint(run_dir, done, trainer)
        raise


def _summary(trainer: _Trainer, run_dir: Path) -> dict[str, Any]:
    """summary.json of a finished run (with the SB3 runs' keys compare and sweep read)."""
    config = trainer.config
    steps = config.iterations * config.episodes_per_iteration * trainer.env_config.n_steps
    return {
        "algo": "apg",
        "env_id": GYM_ENV_ID,
        "seed": config.seed,
        "iterations": config.iterations,
        "timesteps": steps,
        # the SB3 runs' keys (compare's and sweep's training tables): env transitions simulated
        # in training, and the training wall time over every part of a resumed run
        "swarm_steps": steps,
        "train_wall_time_s": round(trainer.wall_time(), 2),
        "best_validation_cost": trainer.best_cost,
        "final_validation_cost": trainer.history[-1]["cost_mean"] if trainer.history else None,
        "validation_seeds": trainer.eval_seeds,
        "reference_costs": trainer.reference_costs,
        "wall_time_s": round(trainer.wall_time(), 3),
        "cpu_time_s": round(trainer.cpu_time(), 3),
        "best_law": BEST_LAW,
        "final_law": FINAL_LAW,
        "run_dir": str(run_dir),
    }


def _train_locked(config: APGConfig, run_dir: Path, resume: bool) -> dict[str, Any]:
    from torch.utils.tensorboard import SummaryWriter
    from tqdm.auto import tqdm

    trainer = _Trainer(config, run_dir)
    start = _restore(trainer, run_dir) if resume else 0
    write_json_atomic(run_dir / "config.json", config.to_dict())
    # the SB3 runs' env.json (N, d, m, integrator, ...): compare and sweep read it alike
    write_json_atomic(run_dir / "env.json", env_description(GYM_ENV_ID, config.env_kwargs))
    write_json_atomic(run_dir / LAW_DESCRIPTION, describe_law(trainer.spec))
    writer = SummaryWriter(str(run_dir / "tb"))
    bar = tqdm(
        total=config.iterations, initial=start, desc="apg", unit="it", disable=not config.progress
    )
    try:
        _iterate(trainer, run_dir, start, writer, bar)
    finally:
        bar.close()
        writer.close()
    _write_law(run_dir, FINAL_LAW, trainer.law)
    summary = _summary(trainer, run_dir)
    write_json_atomic(run_dir / "summary.json", summary)
    return summary


__all__ = [
    "is_apg_run",
    "load_apg_policy",
    "train_apg",
]
