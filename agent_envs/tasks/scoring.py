"""Score any policy on a task's test seeds against its shipped references (numpy only).

    from agent_envs.tasks import score
    result = score(lambda obs: np.zeros(100, np.float32), "agent_envs/StiffSwarm-v0")
    result.summary()["score"].mean          # 0.0: the zero control
    result.rows()                           # per seed: cost, V, J_zero, gap, score

What a policy may be (`as_policy`):

- an object with Stable-Baselines3's ``predict(obs, state=None, episode_start=None,
  deterministic=True) -> (action, state)`` (a `PolicyPredictor`: SB3 models, our controllers);
- a factory ``env -> policy``: a class, or a function whose first parameter is named ``env``;
  it is called once with the task env and must return one of these;
- any other callable ``obs -> action``.

With ``per_agent=True`` the policy is one agent's law, parameter-shared: it is scored on the
task's PettingZoo twin (`agent_envs.tasks.envs.parallel_env`) and is given all agents'
observations at once, as a batch of rows (N, obs_size) in agent order, and must return the
(N, d) actions (or (N d,)). Its cost is minus the swarm's reward summed over the steps
(the agents' "own" rewards added up, or one agent's "team" reward), equal to the Gymnasium
env's cost up to round-off.

Every action is checked before it is applied: a real numeric dtype, the action space's size, no
NaN or inf; a policy that raises, or returns anything else, ends its scoring with `PolicyError`
(a ValueError) naming the policy, the seed and the step. The env runs with `interface` kwargs
(observation layout, action basis, agent reward) over the task's defaults: the interface a
learner was trained with. Seeds: the task's test seeds (a subset may be named; only they have
references).
"""

from __future__ import annotations

import inspect
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from agent_envs.tasks.catalog import TaskSpec, get_task
from agent_envs.tasks.envs import parallel_env
from agent_envs.tasks.references import TaskReferences, load_references
from agent_envs.tasks.scores import Summary, gap, normalized_score, summarize


class PolicyError(ValueError):
    """A policy failed on a task: it raised, or returned an action the env cannot apply."""


def is_factory(obj: Any) -> bool:
    """Whether `obj` is a policy factory ``env -> policy`` (see the module docstring)."""
    if isinstance(obj, type):
        return True
    if hasattr(obj, "predict") or not callable(obj):
        return False
    try:
        parameters = list(inspect.signature(obj).parameters)
    except (TypeError, ValueError):
        return False
    return bool(parameters) and parameters[0] == "env"


class CallablePolicy:
    """A callable ``obs -> action`` as a `PolicyPredictor`."""

    def __init__(self, function: Callable[[Any], Any]) -> None:
        self.function = function

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        return self.function(observation), state


def as_policy(obj: Any, env: Any) -> Any:
    """An object with ``predict`` from a policy, a factory (called with `env`) or a callable."""
    factory = is_factory(obj)
    made = obj(env) if factory else obj
    if hasattr(made, "predict"):
        return made
    if callable(made):
        return CallablePolicy(made)
    if factory:
        raise TypeError(
            f"a policy factory must return an object with predict(...) or a callable, got "
            f"{type(made).__name__}"
        )
    raise TypeError(
        f"a policy must have predict(obs, ...), be a callable obs -> action or a factory "
        f"env -> policy; got {type(obj).__name__}"
    )


def check_action(action: Any, size: int, where: str) -> np.ndarray:
    """The action as a float array of `size` entries; PolicyError naming `where` otherwise."""
    try:
        arr = np.asarray(action)
    except Exception as exc:  # a ragged list, an object numpy cannot convert
        raise PolicyError(f"{where}: the action is not an array ({exc})") from None
    if arr.dtype.kind not in "iuf":
        raise PolicyError(f"{where}: the action has dtype {arr.dtype}; it must be real numbers")
    if arr.size != size:
        raise PolicyError(
            f"{where}: the action has shape {arr.shape} ({arr.size} entries); the env takes {size}"
        )
    if not np.all(np.isfinite(arr)):
        raise PolicyError(f"{where}: the action holds NaN or inf")
    return arr


@dataclass
class TaskScore:
    """A policy's episodes on a task's test seeds and their scores.

    Attributes:
        task: the task.
        policy: the policy's name.
        seeds, costs, diverged: one entry per episode.
        references: the task's shipped references.
        seconds: wall time of the episodes (the policy's and the env's time).
        interface: the env kwargs the policy was scored with, over the task's defaults.
    """

    task: TaskSpec
    policy: str
    seeds: list[int]
    costs: list[float]
    diverged: list[bool]
    references: TaskReferences
    seconds: float = 0.0
    interface: dict[str, Any] = field(default_factory=dict)

    def _aligned(self, name: str) -> np.ndarray:
        return np.array([self.references.cost(name, s) for s in self.seeds])

    @property
    def values(self) -> np.ndarray:
        """V per episode (the yardstick's cost on the episode's seed)."""
        return self._aligned(self.task.yardstick)

    @property
    def gaps(self) -> np.ndarray:
        """(J - V) / V per episode; +inf where the episode diverged."""
        out = gap(np.array(self.costs), self.values)
        return np.where(self.diverged, np.inf, out)

    @property
    def scores(self) -> np.ndarray:
        """100 (J0 - J) / (J0 - V) per episode; -inf where the episode diverged."""
        out = normalized_score(np.array(self.costs), self.values, self._aligned("zero"))
        return np.where(self.diverged, -np.inf, out)

    def rows(self) -> list[dict[str, Any]]:
        """One dict per episode: policy, seed, cost, V, zero cost, gap, score, diverged."""
        values, zero = self.values, self._aligned("zero")
        return [
            {
                "task": self.task.id,
                "policy": self.policy,
                "seed": seed,
                "cost": cost,
                "value": float(v),
                "zero_cost": float(z),
                "gap": float(g),
                "score": float(s),
                "diverged": bool(d),
            }
            for seed, cost, v, z, g, s, d in zip(
                self.seeds,
                self.costs,
                values,
                zero,
                self.gaps,
                self.scores,
                self.diverged,
                strict=True,
            )
        ]

    def summary(self) -> dict[str, Summary]:
        """{"score": ..., "gap": ..., "cost": ...}: mean, IQM and their intervals over seeds."""
        return {
            "score": summarize(self.scores),
            "gap": summarize(self.gaps),
            "cost": summarize(np.array(self.costs)),
        }

    def __repr__(self) -> str:
        summary = self.summary()
        s, g = summary["score"], summary["gap"]
        return (
            f"TaskScore({self.policy} on {self.task.id}: score {s.mean:.2f} "
            f"[{s.mean_low:.2f}, {s.mean_high:.2f}], IQM {s.iqm:.2f}, gap {100 * g.mean:+.2f}% "
            f"over {s.n_seeds} seeds)"
        )


def _select_seeds(task: TaskSpec, seeds: Sequence[int] | None) -> list[int]:
    if seeds is None:
        return list(task.test_seeds)
    chosen = [int(s) for s in seeds]
    unknown = [s for s in chosen if s not in task.test_seeds]
    if unknown or not chosen:
        raise ValueError(
            f"seeds must be among {task.id}'s test seeds {task.test_seeds[0]}.."
            f"{task.test_seeds[-1]} (only they have references); got {unknown or chosen}"
        )
    return chosen


def _call(policy: Any, obs: Any, state: Any, start: bool, where: str) -> tuple[Any, Any]:
    try:
        out = policy.predict(obs, state, np.array([start]), deterministic=True)
    except Exception as exc:
        raise PolicyError(f"{where}: the policy raised {type(exc).__name__}: {exc}") from exc
    if not (isinstance(out, tuple) and len(out) == 2):
        raise PolicyError(f"{where}: predict must return (action, state), got {type(out).__name__}")
    return out


def _episode_gym(env: Any, policy: Any, seed: int, name: str) -> tuple[float, bool]:
    size = int(np.prod(env.action_space.shape))
    obs, _ = env.reset(seed=seed)
    cost, state, step, start = 0.0, None, 0, True
    while True:
        where = f"policy {name!r}, seed {seed}, step {step}"
        action, state = _call(policy, obs, state, start, where)
        action = check_action(action, size, where).reshape(env.action_space.shape)
        obs, reward, terminated, truncated, info = env.step(action)
        cost -= float(reward)
        step, start = step + 1, False
        if terminated or truncated:
            return cost, bool(info.get("diverged", False))


def _episode_agents(env: Any, policy: Any, seed: int, name: str) -> tuple[float, bool]:
    observations, _ = env.reset(seed=seed)
    agents = list(env.possible_agents)
    d = env.action_space(agents[0]).shape[0]
    team = env.config.agent_reward == "team"
    cost, state, step, start = 0.0, None, 0, True
    while True:
        where = f"policy {name!r}, seed {seed}, step {step}"
        rows = np.stack([observations[a] for a in agents])
        action, state = _call(policy, rows, state, start, where)
        action = check_action(action, len(agents) * d, where).reshape(len(agents), d)
        observations, rewards, terms, truncs, infos = env.step(
            {a: action[k] for k, a in enumerate(agents)}
        )
        cost -= float(rewards[agents[0]]) if team else float(sum(rewards.values()))
        step, start = step + 1, False
        if any(terms.values()) or any(truncs.values()):
            return cost, any(bool(i.get("diverged", False)) for i in infos.values())


def score(
    policy: Any,
    task_id: str | TaskSpec,
    *,
    name: str = "policy",
    per_agent: bool = False,
    interface: Mapping[str, Any] | None = None,
    seeds: Sequence[int] | None = None,
    references: TaskReferences | None = None,
) -> TaskScore:
    """Run `policy` on the task's test seeds and score it against the shipped references.

    Args:
        policy: see the module docstring.
        task_id: the task.
        name: the policy's name in errors and tables.
        per_agent: score a parameter-shared per-agent law on the PettingZoo twin.
        interface: env kwargs of the interface the policy acts through (observation,
            action_basis, agent_reward); the task's defaults otherwise.
        seeds: a subset of the test seeds (default: all 20).
        references: the task's references (default: the shipped ones, hash-checked).

    Raises:
        PolicyError: the policy raised or returned an unusable action (seed and step named).
        ValueError: an unknown task, a kwarg the task fixes, a seed that is not a test seed.
    """
    import gymnasium as gym

    task = get_task(task_id)
    refs = references or load_references(task)
    chosen = _select_seeds(task, seeds)
    interface = dict(interface or {})
    if per_agent:
        env = parallel_env(task.id, **interface)
        run = _episode_agents
    else:
        env = gym.make(task.id, **interface)
        run = _episode_gym
    try:
        acting = as_policy(policy, env)
        costs, diverged = [], []
        start = time.perf_counter()
        for seed in chosen:
            cost, div = run(env, acting, seed, name)
            costs.append(cost)
            diverged.append(div)
        seconds = time.perf_counter() - start
    finally:
        env.close()
    return TaskScore(task, name, chosen, costs, diverged, refs, seconds, interface)


__all__ = ["CallablePolicy", "PolicyError", "TaskScore", "as_policy", "check_action", "score"]
