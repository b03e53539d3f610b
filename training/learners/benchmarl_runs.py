"""BenchMARL's MAPPO and IPPO trained on a benchmark task: one run per training seed.

    from agent_envs.training.learners.benchmarl_runs import MarlRun, train_run, load_policy

    run = MarlRun("agent_envs/StiffSwarm-v0", "mappo", seed=0, frames=60_000)
    folder = train_run(run, "out/runs")      # config.json, validation.csv, best.pt, result.json
    policy = load_policy(folder)              # a GroupPolicy (actions scaled by s)
    agent_envs.tasks.score(lambda env: policy, run.task, per_agent=True,
                           interface=run.interface)

The run trains BenchMARL 1.5.2's `MappoConfig` or `IppoConfig` (its YAML defaults, MLP actor and
critic) through the shipped task class (`benchmarl_task.SwarmTask.SWARM`) on the task's own env
kwargs (N, m, eps, noise, integrator...) with the interface `INTERFACE` (the swarm observation,
the team reward: parameter-shared PPO's, so that returns are O(J) and the critic sees the centre
and spread) and one change, the action scale: the train env's bound is s x the task's
(max_control = 25 s), and the scored policy's actions are multiplied by s
(`GroupPolicy(scale=s)`), so the controls it applies on the task's env, u = 25 (s a) = (25 s) a,
are those it trained with (bit for bit for s a power of two, `DEFAULT_ACTION_SCALE` = 1/4).

Seeds: BenchMARL seeds torch, numpy and random from the training seed (`seed_everything`) and
the collector's envs from it; validation is deterministic (tanh(loc)) on the task's validation
seeds 1000.., never the test seeds. Every `evaluate_every` batches (and before the first) the
policy's mean swarm cost J on `validation_episodes` seeds is measured; the parameters with the
lowest J are kept and saved as ``best.pt`` (`torch.save` of the policy's state_dict; read back with
``torch.load(..., weights_only=True)``, nothing else is unpickled). CPU, one torch thread.

Needs the `marl` extra (BenchMARL, TorchRL): benchmarl and torch are imported inside the
functions, so this module imports without them.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import shutil
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from agent_envs.tasks import get_task
from agent_envs.training.storage import write_json_atomic, write_text_atomic

#: The algorithms, by their leaderboard names: BenchMARL's config class of each.
ALGORITHMS = {"mappo": "MappoConfig", "ippo": "IppoConfig"}
#: The interface of the runs: parameter-shared PPO's (`presets.SWARM_TEAM`).
INTERFACE = {"observation": "swarm", "agent_reward": "team"}
#: s: the train env's max_control is s x the task's (25 x 1/4 = 6.25, near the BenchMARL task's
#: default 5 that puts a fresh policy below the zero control); a power of two, so scaling the
#: actions back is exact (docs/learners/marl-libraries.md, "Leaderboard units").
DEFAULT_ACTION_SCALE = 0.25
#: The frame budget of a leaderboard unit by algorithm (env steps; one frame = one step of the
#: N agents), from the design runs on training seed 0 (docs/learners/marl-libraries.md):
#: MAPPO's best validation J came at 12,000 frames and rose after, so its design budget
#: (about 15 minutes of one core at N = 100); IPPO was still falling at its design budget's
#: end (30,000), so 9 batches, about 23 minutes of one core, under the issue's 30.
DEFAULT_FRAMES = {"mappo": 48_000, "ippo": 54_000}
#: Frames per collected batch, minibatch passes per batch, frames per minibatch.
DEFAULT_BATCH_FRAMES = 6_000
DEFAULT_MINIBATCH_ITERS = 10
DEFAULT_MINIBATCH_SIZE = 400
#: Files of a run folder.
CONFIG_FILE, CURVE_FILE, WEIGHTS_FILE, RESULT_FILE = (
    "config.json",
    "validation.csv",
    "best.pt",
    "result.json",
)
CURVE_COLUMNS = ("batch", "frames", "seconds", "validation_cost")


@dataclass(frozen=True)
class MarlRun:
    """One BenchMARL run: `algorithm` ("mappo", "ippo") on `task` with training seed `seed`.

    frames: the budget (env frames, > 0; None: `DEFAULT_FRAMES` of the algorithm);
    batch_frames (> 0, at most frames), minibatch_iters, minibatch_size (at most batch_frames):
    BenchMARL's on-policy batch, passes over it and minibatch; action_scale s in (0, 1];
    evaluate_every: batches between validations; validation_episodes: how many of the seeds
    1000.. are used.
    """

    task: str
    algorithm: str
    seed: int
    frames: int | None = None
    action_scale: float = DEFAULT_ACTION_SCALE
    batch_frames: int = DEFAULT_BATCH_FRAMES
    minibatch_iters: int = DEFAULT_MINIBATCH_ITERS
    minibatch_size: int = DEFAULT_MINIBATCH_SIZE
    evaluate_every: int = 1
    validation_episodes: int = 5
    interface: dict[str, Any] = field(default_factory=lambda: dict(INTERFACE))

    def __post_init__(self) -> None:
        from agent_envs.validation import Range, check_int, check_real

        if self.algorithm not in ALGORITHMS:
            names = ", ".join(ALGORITHMS)
            raise ValueError(f"algorithm must be one of {names}, got {self.algorithm!r}")
        object.__setattr__(self, "task", get_task(self.task).id)
        check_int("seed", self.seed, 0)
        if self.frames is None:
            object.__setattr__(self, "frames", default_frames(self.algorithm))
        check_int("frames", self.frames, 1)
        check_int("batch_frames", self.batch_frames, 1)
        object.__setattr__(self, "batch_frames", min(self.batch_frames, self.frames))
        check_int("minibatch_iters", self.minibatch_iters, 1)
        check_int("minibatch_size", self.minibatch_size, 1)
        object.__setattr__(self, "minibatch_size", min(self.minibatch_size, self.batch_frames))
        check_int("evaluate_every", self.evaluate_every, 1)
        check_int("validation_episodes", self.validation_episodes, 1)
        check_real("action_scale", self.action_scale, Range(0.0, 1.0, low_open=True))

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def train_env_kwargs(self) -> dict[str, Any]:
        """swarm_v0 kwargs of the train env: the task's, the interface, max_control x s."""
        kwargs = get_task(self.task).make_kwargs(self.interface)
        kwargs.pop("action_basis", None)
        kwargs["max_control"] = float(kwargs["max_control"]) * self.action_scale
        return kwargs

    def task_env_kwargs(self) -> dict[str, Any]:
        """swarm_v0 kwargs of the task's own env with the interface (its max_control)."""
        kwargs = get_task(self.task).make_kwargs(self.interface)
        kwargs.pop("action_basis", None)
        return kwargs

    def validation_seeds(self) -> list[int]:
        return list(get_task(self.task).validation_seeds[: self.validation_episodes])


def default_frames(algorithm: str) -> int:
    """The leaderboard's frame budget of `algorithm` (`DEFAULT_FRAMES`)."""
    if algorithm not in DEFAULT_FRAMES:
        names = ", ".join(DEFAULT_FRAMES)
        raise ValueError(f"algorithm must be one of {names}, got {algorithm!r}")
    return DEFAULT_FRAMES[algorithm]


def _experiment_config(run: MarlRun, folder: Path) -> Any:
    from benchmarl.experiment import ExperimentConfig

    config = ExperimentConfig.get_from_yaml()
    config.max_n_frames = run.frames
    config.on_policy_collected_frames_per_batch = run.batch_frames
    config.on_policy_n_minibatch_iters = run.minibatch_iters
    config.on_policy_minibatch_size = run.minibatch_size
    # 10 envs stepped in turn (BenchMARL's default), or fewer where they do not divide a batch
    config.on_policy_n_envs_per_worker = math.gcd(10, run.batch_frames)
    config.loggers = []
    config.evaluation = False
    config.render = False
    config.create_json = False
    config.checkpoint_interval = 0
    config.checkpoint_at_end = False
    config.save_folder = str(folder)
    return config


def build_experiment(run: MarlRun, folder: Path, callbacks: list | None = None) -> Any:
    """The BenchMARL `Experiment` of `run` (its files under `folder`; nothing trained yet)."""
    import benchmarl.algorithms as algorithms
    from benchmarl.experiment import Experiment
    from benchmarl.models.mlp import MlpConfig

    from agent_envs.training.learners.benchmarl_task import SwarmTask

    task = SwarmTask.SWARM.get_task()
    task.config = run.train_env_kwargs()
    folder.mkdir(parents=True, exist_ok=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return Experiment(
            task=task,
            algorithm_config=getattr(algorithms, ALGORITHMS[run.algorithm]).get_from_yaml(),
            model_config=MlpConfig.get_from_yaml(),
            critic_model_config=MlpConfig.get_from_yaml(),
            seed=run.seed,
            config=_experiment_config(run, folder),
            callbacks=callbacks,
        )


def validation_cost(module: Any, run: MarlRun) -> float:
    """Mean swarm cost J of the deterministic policy, actions x s, on the task's env at the
    run's validation seeds (`multiagent.evaluate_per_agent`, costs (seeds, N): minus each
    agent's summed reward; J is their sum with the "own" reward, any one of them with "team",
    where every agent is given the swarm's reward)."""
    from agent_envs.training.learners.benchmarl_policy import GroupPolicy
    from agent_envs.training.learners.multiagent import evaluate_per_agent

    policy = GroupPolicy(module, scale=run.action_scale)
    costs = evaluate_per_agent(policy, run.task_env_kwargs(), run.validation_seeds())
    team = run.interface.get("agent_reward", "own") == "team"
    return float((costs[:, 0] if team else costs.sum(axis=1)).mean())


class ValidationCallback:
    """A BenchMARL callback (its `Callback` interface, duck-typed so that this module imports
    without BenchMARL and the class pickles, as BenchMARL pickles an experiment's callbacks):
    after every `evaluate_every`-th batch's training (and the last), J on the validation seeds
    (`validation_cost`); the lowest J's state_dict is kept in `best`."""

    def __init__(self, run: MarlRun) -> None:
        self.run = run
        self.experiment: Any = None
        self.curve: list[dict[str, float]] = []
        self.best: dict[str, Any] | None = None
        self.best_cost = float("inf")
        self.start = time.perf_counter()

    def measure(self, batch: int) -> None:
        """Validate the experiment's policy after `batch` batches; keep it if the best."""
        policy = self.experiment.policy
        cost = validation_cost(policy, self.run)
        frames = int(self.experiment.total_frames)
        seconds = time.perf_counter() - self.start
        self.curve.append(
            {"batch": batch, "frames": frames, "seconds": seconds, "validation_cost": cost}
        )
        if cost < self.best_cost:
            self.best_cost = cost
            self.best = copy.deepcopy(policy.state_dict())
        print(f"{self.run.algorithm} seed {self.run.seed}: {frames} frames, J = {cost:.5f}")

    def on_train_end(self, training_td: Any, group: str) -> None:
        batch = self.experiment.n_iters_performed + 1
        last = self.experiment.total_frames >= self.run.frames
        if batch % self.run.evaluate_every == 0 or last:
            self.measure(batch)

    def on_setup(self) -> None: ...

    def on_load_state_dict(self, state_dict: dict[str, Any]) -> None: ...

    def on_batch_collected(self, batch: Any) -> None: ...

    def on_train_step(self, batch: Any, group: str) -> None: ...

    def on_evaluation_end(self, rollouts: list[Any]) -> None: ...

    def on_state_dict(self, state_dict: dict[str, Any]) -> None: ...


def _write_curve(path: Path, curve: list[dict[str, float]]) -> None:
    from agent_envs.training.results.episode_csv import rows_text

    write_text_atomic(path, rows_text(curve))


def train_run(run: MarlRun, runs_dir: str | Path) -> Path:
    """Train `run` (or reuse its finished folder); the run folder.

    Folder ``runs_dir/TASK/ALGORITHM_seedS``: config.json (the run), validation.csv (batch,
    frames, wall seconds, validation J), best.pt (the best state_dict), result.json (best J,
    its frames, training wall time) written last; a folder with result.json and the same
    config is reused, anything else there is replaced.
    """
    import torch

    folder = Path(runs_dir) / get_task(run.task).file_stem / f"{run.algorithm}_seed{run.seed}"
    config = run.to_dict()
    if (folder / RESULT_FILE).is_file() and _read_json(folder / CONFIG_FILE) == config:
        return folder
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    write_json_atomic(folder / CONFIG_FILE, config)
    torch.set_num_threads(1)
    callback = ValidationCallback(run)
    experiment = build_experiment(run, folder / "benchmarl", [callback])
    callback.start = time.perf_counter()
    callback.measure(0)  # the fresh policy
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        experiment.run()
    seconds = time.perf_counter() - callback.start
    shutil.rmtree(folder / "benchmarl", ignore_errors=True)
    torch.save(callback.best, folder / WEIGHTS_FILE)
    _write_curve(folder / CURVE_FILE, callback.curve)
    best = min(callback.curve, key=lambda row: row["validation_cost"])
    result = {
        "best_validation_cost": best["validation_cost"],
        "best_frames": best["frames"],
        "frames": run.frames,
        "train_seconds": seconds,
        "torch_threads": torch.get_num_threads(),
    }
    write_json_atomic(folder / RESULT_FILE, result)
    return folder


def _read_json(path: Path) -> Any:
    return json.loads(path.read_text()) if path.is_file() else None


def load_run(folder: str | Path) -> MarlRun:
    """The `MarlRun` of a run folder (its config.json)."""
    return MarlRun(**json.loads((Path(folder) / CONFIG_FILE).read_text()))


def load_policy(folder: str | Path) -> Any:
    """The run's best policy as a `GroupPolicy` with its action scale: the experiment rebuilt
    from config.json (untrained), best.pt loaded with ``torch.load(weights_only=True)``."""
    import tempfile

    import torch

    from agent_envs.training.learners.benchmarl_policy import GroupPolicy

    run = load_run(folder)
    state = torch.load(Path(folder) / WEIGHTS_FILE, weights_only=True)
    with tempfile.TemporaryDirectory() as scratch:
        experiment = build_experiment(run, Path(scratch))
        experiment.policy.load_state_dict(state)
    return GroupPolicy(experiment.policy, scale=run.action_scale)


def policy_factory(folder: str | Path) -> Callable[[Any], Any]:
    """A factory ``env -> policy`` for `agent_envs.tasks.score` (per_agent=True)."""
    policy = load_policy(folder)

    def make(env: Any) -> Any:
        return policy

    return make


__all__ = [
    "ALGORITHMS",
    "DEFAULT_ACTION_SCALE",
    "DEFAULT_FRAMES",
    "INTERFACE",
    "MarlRun",
    "ValidationCallback",
    "build_experiment",
    "default_frames",
    "load_policy",
    "load_run",
    "policy_factory",
    "train_run",
    "validation_cost",
]
