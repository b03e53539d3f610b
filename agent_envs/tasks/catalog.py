"""The benchmark's tasks: versioned ids that fix a swarm problem, its seeds and its yardstick.

A task is a Gymnasium id in Farama's convention, ``agent_envs/Name-vN``. Within one version
nothing about it changes: the dynamics (`SwarmParams`), the cost (`eq:discrete_cost_functional`
with the task's gamma), the horizon and time step, the integrator and its numerics, the action
bound, the test seeds and the reference data shipped for them. A change to any of these is a new
version; the old one stays loadable. `agent_envs/Swarm-v0` stays the free-kwargs env for
exploration.

What a user may still choose is the *interface* (`INTERFACE_KWARGS`: observation layout, action
basis, PettingZoo agent reward and neighbours, render mode, compiled threads): it changes what
a policy sees and moves, never the dynamics, the cost or the random draws
(`agent_envs.envs.interface`), so a score stays comparable whatever interface a learner used.

    import gymnasium as gym, agent_envs
    env = gym.make("agent_envs/StiffSwarm-v0")                           # the task's defaults
    env = gym.make("agent_envs/StiffSwarm-v0", observation="summary", action_basis="common")
    envs = gym.make_vec("agent_envs/StiffSwarm-v0", num_envs=8,
                        vectorization_mode="vector_entry_point")          # the native vector env
    from agent_envs.tasks import parallel_env
    par = parallel_env("agent_envs/StiffSwarm-v0", observation="swarm")  # the PettingZoo twin

Seeds. Each task names 20 test seeds (the final table's only episodes; nothing is designed on
them) and 20 validation seeds (for every design choice: bounds, budgets, interfaces,
hyperparameters). Training seeds are the learner's own (small ints seeding its generator and
its envs' resets). The three sets are disjoint (`check_disjoint_seeds`, tested).

The yardstick V of a task (`TaskSpec.yardstick`) is what its score calls 100:
- ``"optimal"``: the open-loop optimum, solved per test seed by `solve_optimal_control` on 20
  sampled Brownian paths of its own (a sample-average plan), replayed in the env;
- ``"mpc"``: receding-horizon re-solves of that problem, where the noise is large enough that
  feedback beats any open-loop plan (`NoisySwarm`);
- ``"lower_bound"``: where no optimum can be solved (`LargeSwarm`, N = 10^4), a certified lower
  bound on the cost of *any* policy on that seed (`agent_envs.tasks.bounds`): no policy reaches
  100 there, and the gap to it is an upper bound on the gap to the optimum.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

#: Env kwargs a task leaves to the user: the interface, never the dynamics, cost or draws.
INTERFACE_KWARGS = (
    "observation",
    "action_basis",
    "agent_reward",
    "neighbours",
    "render_mode",
    "num_threads",
)
#: The task id's shape: ``agent_envs/Name-vN`` (Farama's namespace/name-version convention).
TASK_ID_PATTERN = re.compile(r"^(?:agent_envs/)?(?P<name>[A-Za-z][A-Za-z0-9]*)-v(?P<version>\d+)$")
#: What a yardstick may be (module docstring).
YARDSTICKS = ("optimal", "mpc", "lower_bound")
#: Validation seeds of every task (also the training layer's evaluation seeds,
#: `agent_envs.training.defaults.DEFAULT_EVAL_SEED`).
VALIDATION_SEEDS = tuple(range(1000, 1020))


@dataclass(frozen=True)
class TaskSpec:
    """One versioned task.

    Attributes:
        name: the name without namespace and version (``"StiffSwarm"``).
        version: N of ``-vN``.
        tests: one line: what makes this task hard, what it tells apart.
        env_kwargs: every kwarg of `agent_envs/Swarm-v0` the task fixes (dynamics, cost,
            horizon, numerics, action bound) and its default interface.
        test_seeds: the 20 reset seeds of the final table.
        validation_seeds: the seeds for design choices (disjoint from `test_seeds`).
        yardstick: which reference is V (module docstring).
        references: the reference controllers shipped per test seed, V's among them.
        card: a paragraph for the docs' task card (what V certifies, what was measured).
    """

    name: str
    version: int
    tests: str
    env_kwargs: Mapping[str, Any]
    test_seeds: tuple[int, ...]
    yardstick: str
    references: tuple[str, ...]
    card: str = ""
    validation_seeds: tuple[int, ...] = VALIDATION_SEEDS

    def __post_init__(self) -> None:
        object.__setattr__(self, "env_kwargs", MappingProxyType(dict(self.env_kwargs)))
        if self.yardstick not in YARDSTICKS:
            raise ValueError(f"yardstick must be one of {YARDSTICKS}, got {self.yardstick!r}")
        if self.yardstick not in self.references:
            raise ValueError(f"the yardstick {self.yardstick!r} must be among the references")
        if set(self.test_seeds) & set(self.validation_seeds):
            raise ValueError(f"{self.id}: test and validation seeds overlap")

    @property
    def id(self) -> str:
        """The Gymnasium id, ``agent_envs/Name-vN``."""
        return f"agent_envs/{self.name}-v{self.version}"

    @property
    def file_stem(self) -> str:
        """``Name-vN``: the stem of the task's reference data file."""
        return f"{self.name}-v{self.version}"

    def make_kwargs(self, interface: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """The task's env kwargs with `interface` over its default interface.

        Raises ValueError naming a kwarg the task fixes (only `INTERFACE_KWARGS` may change).
        """
        interface = dict(interface or {})
        fixed = sorted(k for k in interface if k not in INTERFACE_KWARGS)
        if fixed:
            raise ValueError(
                f"{self.id} fixes {', '.join(fixed)} (a task's dynamics, cost, horizon and "
                f"numerics never change within a version); only the interface may be given: "
                f"{', '.join(INTERFACE_KWARGS)}. Use agent_envs/Swarm-v0 to change anything else"
            )
        return {**self.env_kwargs, **interface}

    @property
    def n_agents(self) -> int:
        return int(self.env_kwargs.get("n_agents", 100))

    @property
    def dim(self) -> int:
        return int(self.env_kwargs.get("dim", 1))

    @property
    def n_steps(self) -> int:
        return int(self.env_kwargs.get("n_steps", 50))


#: The paper's stiff setting (Section 5.2, Figs. 5-6; `eq:serb` with the frozen L(x)).
_PAPER = {
    "n_agents": 100,
    "dim": 1,
    "kernel": "symmetric",
    "alpha": 0.1,
    "epsilon": 0.05,
    "sigma": 0.01,
    "horizon": 1.0,
    "target": 0.7,
    "gamma": 0.01,
    "integrator": "serb",
    "jacobian": "frozen",
    "phi_method": "auto",
    "linear_operator": "auto",
    "n_steps": 50,
    "n_paths": 20,
    "max_control": 25.0,
    "divergence_threshold": 1e4,
}

_REFERENCES = ("optimal", "proportional", "turnpike", "zero")


def _seeds(first: int) -> tuple[int, ...]:
    return tuple(range(first, first + 20))


TASK_LIST: tuple[TaskSpec, ...] = (
    TaskSpec(
        "StiffSwarm",
        0,
        "the paper's stiff setting: the interaction collapses the swarm in a few steps, "
        "explicit schemes blow up, and a common push does most of the work",
        _PAPER,
        _seeds(20_000),
        "optimal",
        _REFERENCES,
        card="N = 100, m = 50, eps = 0.05, alpha = 0.1, sigma = 0.01, T = 1, target 0.7, "
        "gamma = 0.01, SERB with the frozen kernel L(x) (the paper's Fig. 5-6 scheme; its J_n "
        "is the exact Jacobian `eq:jac`, which we do not use here), 20 Brownian paths, "
        "|u| <= 25. At sigma = 0.01 feedback buys nothing measurable: MPC was within 0.01% of "
        "the open-loop plan at this setting (docs/optimum.md), so V is the open-loop optimum.",
    ),
    TaskSpec(
        "WeakCouplingSwarm",
        0,
        "weak coupling (eps = 1): the spread decays slowly, so every agent needs its own "
        "control; one common control stays far above the optimum",
        {**_PAPER, "epsilon": 1.0},
        _seeds(21_000),
        "optimal",
        _REFERENCES,
        card="The stiff task with eps = 1: the interaction is 20x weaker, the swarm does not "
        "collapse within the horizon, and a control shared by all agents cannot shrink its "
        "spread.",
    ),
    TaskSpec(
        "PlaneSwarm",
        0,
        "the plane (d = 2): a target point in R^2, controls and interactions in two coordinates",
        {**_PAPER, "dim": 2, "target": (0.7, -0.4)},
        _seeds(22_000),
        "optimal",
        _REFERENCES,
        card="The stiff task in d = 2: agents start uniform on [-1, 1]^2, the target is "
        "(0.7, -0.4), p(x, y) = 1/(eps (alpha^2 + |x - y|^2)) with the Euclidean distance.",
    ),
    TaskSpec(
        "NonSymmetricSwarm",
        0,
        "the non-symmetric kernel (eq:nonsymmker): agents weigh their neighbours unequally, "
        "the centre is no longer conserved by the interaction, and the target (2.3) lies "
        "outside the initial interval",
        {
            **_PAPER,
            "kernel": "nonsymmetric",
            "epsilon_min": 0.01,
            "epsilon_max": 0.1,
            "target": 2.3,
        },
        _seeds(23_000),
        "optimal",
        _REFERENCES,
        card="The paper's non-symmetric experiment (fig:test2_cheap_stiff_nonsymm): "
        "p(x_k, x_l) = 1/(eps_l (alpha^2 + |x_k - x_l|^2)) with eps_l from 0.01 to 0.1 linear "
        "in l, target 2.3, otherwise the stiff task.",
    ),
    TaskSpec(
        "LargeSwarm",
        0,
        "a large swarm (N = 10^4, matrix-free kernel sums): a policy must run at any N; no "
        "optimum can be solved, so V is a certified lower bound",
        {**_PAPER, "n_agents": 10_000, "n_paths": 1},
        _seeds(24_000),
        "lower_bound",
        ("lower_bound", "proportional", "turnpike", "zero"),
        card="The stiff task at N = 10^4 with one Brownian path: the env takes the matrix-free "
        "path (grid sums, docs/large-swarms.md). The optimum is not solved at N >= 1000 on a "
        "2-core machine (one cost + gradient of the noise-free problem took 124 s at "
        "N = 1000). V is a lower bound that holds for every policy on that seed "
        "(`agent_envs.tasks.bounds.centre_lower_bound`): the swarm's centre moves only with "
        "the mean control and the noise's mean, the spread costs at least nothing after the "
        "first step, so the clairvoyant linear-quadratic problem of the centre bounds the "
        "cost from below. No policy scores 100; on the stiff task the same bound is "
        "measured against the optimum (task card there).",
    ),
    TaskSpec(
        "NoisySwarm",
        0,
        "strong noise (sigma = 0.5, N = 10): feedback beats any open-loop plan, so the "
        "yardstick is MPC, not the open-loop optimum",
        {**_PAPER, "n_agents": 10, "n_steps": 20, "sigma": 0.5, "n_paths": 1},
        _seeds(25_000),
        "mpc",
        ("mpc", "optimal", "proportional", "turnpike", "zero"),
        card="N = 10, m = 20, sigma = 0.5, one Brownian path: the centre's random walk "
        "(sigma sqrt(T / N) = 0.16) is as large as the distance to cover. V is the cost of "
        "MPC (re-solving the 20-path sample-average problem from the observed state at every "
        "step, warm-started, 15 L-BFGS-B iterations per re-solve); the open-loop optimum is "
        "shipped too and scores below 100 on this task. A policy may beat MPC (score > 100): "
        "MPC is not the optimal feedback law.",
    ),
)

#: id -> task, every version of every task.
TASKS: dict[str, TaskSpec] = {t.id: t for t in TASK_LIST}


def check_disjoint_seeds(training_seeds: tuple[int, ...] = (0, 1, 2)) -> None:
    """Raise ValueError if a task's test, validation and the given training seeds overlap."""
    for task in TASK_LIST:
        sets = {
            "test": set(task.test_seeds),
            "validation": set(task.validation_seeds),
            "training": set(training_seeds),
        }
        names = list(sets)
        for i, a in enumerate(names):
            for b in names[i + 1 :]:
                if sets[a] & sets[b]:
                    raise ValueError(f"{task.id}: {a} and {b} seeds overlap")


def get_task(task_id: str) -> TaskSpec:
    """The task called `task_id` (``agent_envs/Name-vN``; the namespace may be left out).

    An unknown name lists the known tasks; a version that does not exist says which do. A
    `TaskSpec` is returned as it is.
    """
    if isinstance(task_id, TaskSpec):
        return task_id
    if not isinstance(task_id, str):
        raise TypeError(f"task must be a task id string, got {type(task_id).__name__}")
    match = TASK_ID_PATTERN.match(task_id.strip())
    if match is None:
        raise ValueError(
            f"task {task_id!r} is not a task id of the form agent_envs/Name-vN; the tasks are "
            f"{', '.join(TASKS)}"
        )
    name, version = match.group("name"), int(match.group("version"))
    full = f"agent_envs/{name}-v{version}"
    if full in TASKS:
        return TASKS[full]
    versions = sorted(t.version for t in TASK_LIST if t.name == name)
    if versions:
        raise ValueError(
            f"task {name} has no version v{version}; it has {', '.join(f'v{v}' for v in versions)}"
        )
    raise ValueError(f"unknown task {task_id!r}; the tasks are {', '.join(TASKS)}")


__all__ = [
    "INTERFACE_KWARGS",
    "TASKS",
    "TASK_LIST",
    "VALIDATION_SEEDS",
    "YARDSTICKS",
    "TaskSpec",
    "check_disjoint_seeds",
    "get_task",
]
