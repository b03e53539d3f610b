"""The options of `agent-envs evaluate` (`EvaluateConfig`) and its policy specs.

Kept apart from the rollouts (`agent_envs.training.commands.evaluate`, which needs pandas) so that
`agent-envs evaluate --task ID -p module:attribute` runs on the core install: numpy, no torch,
no pandas (`agent_envs.training.commands.task_evaluation`).

Policy specs (``-p [NAME=]SPEC``, `parse_policy_specs`):

- a baseline name: turnpike, proportional, zero, optimal, mpc;
- a saved SB3 model ``[ALGO:]PATH.zip[:STATS.pkl]``, or an apg run folder;
- ``module:attribute`` (`is_object_spec`): a Python object the user names, imported from the
  working directory or PYTHONPATH (`agent_envs.training.commands.task_evaluation.import_policy`): a
  callable ``obs -> action``, an object with SB3's ``predict``, or a factory ``env -> policy``
  (`agent_envs.tasks.scoring`); ``per-agent:module:attribute`` marks a parameter-shared
  per-agent law, scored on the task's PettingZoo twin (``--task`` only).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import MISSING, dataclass, field
from pathlib import Path
from typing import Any

from agent_envs.training.config import option_field
from agent_envs.training.defaults import (
    ALGORITHMS,
    BASELINE_POLICIES,
    DEFAULT_BETA,
    DEFAULT_DELTA,
    FEEDBACK_BASELINES,
    GYM_ENV_ID,
    check_env_id,
    parse_env_kwargs,
    parse_seeds,
)
from agent_envs.training.learners.policies import ModelSpec, check_model
from agent_envs.validation import TARGET_RANGE, check_positive, check_real

#: ``module:attribute`` (dotted names), optionally after ``per-agent:``.
OBJECT_SPEC = re.compile(
    r"^(?P<per_agent>per-agent:)?(?P<module>[A-Za-z_][\w]*(?:\.[A-Za-z_][\w]*)*)"
    r":(?P<attribute>[A-Za-z_][\w]*(?:\.[A-Za-z_][\w]*)*)$"
)


def is_object_spec(spec: str) -> bool:
    """Whether a policy spec names a Python object (``[per-agent:]module:attribute``).

    ``ALGO:PATH`` of a saved model (ALGO one of ppo, sac, td3, a2c) and anything ending in
    ``.zip``, ``.pkl`` or ``.pt`` is a file, not an object.
    """
    match = OBJECT_SPEC.match(spec)
    if match is None or spec.endswith((".zip", ".pkl", ".pt")):
        return False
    return match.group("module") not in ALGORITHMS or bool(match.group("per_agent"))


def object_spec_parts(spec: str) -> tuple[str, str, bool]:
    """(module, attribute, per_agent) of an object spec; ValueError otherwise."""
    match = OBJECT_SPEC.match(spec)
    if match is None or not is_object_spec(spec):
        raise ValueError(f"--policy {spec!r} is not of the form [per-agent:]module:attribute")
    return match.group("module"), match.group("attribute"), bool(match.group("per_agent"))


def parse_policy_specs(items: Sequence[str] | None) -> dict[str, str]:
    """``NAME=SPEC`` or ``SPEC`` items -> {name: spec} (a bare path is named by its file stem).

    A SPEC is a baseline name, ``[ALGO:]MODEL.zip[:STATS.pkl]``, an apg run folder, or
    ``[per-agent:]module:attribute`` (named by its attribute). None or no items: the three
    reference controllers.
    """
    if not items:
        return {name: name for name in FEEDBACK_BASELINES}
    out: dict[str, str] = {}
    for item in items:
        if "=" in item:
            name, spec = item.split("=", 1)
        else:
            spec = item
            if item in BASELINE_POLICIES:
                name = item
            elif is_object_spec(item):
                name = object_spec_parts(item)[1].rsplit(".", 1)[-1]
            else:
                name = ModelSpec.parse(item).path.stem
        if not name or not spec:
            raise ValueError(f"--policy {item!r}: write NAME=SPEC or SPEC")
        if name in out:
            raise ValueError(f"--policy name {name!r} given twice; use NAME=SPEC to rename")
        out[name] = spec
    return out


@dataclass(frozen=True, kw_only=True)
class EvaluateConfig:
    """The options of `agent-envs evaluate`; validated on construction (the saved models named
    by --policy are checked by `check_models`, the output folder by the command).

    `seeds` may be given as ints or as seed-list strings (`defaults.parse_seeds`) and is stored
    as a tuple of ints; `env_kwargs` as a JSON object or a dict.
    """

    policies: tuple[str, ...] | None = option_field(
        None,
        "a baseline (turnpike | proportional | zero | optimal | mpc), a saved SB3 model "
        "PATH.zip (ALGO:PATH to name the algorithm, PATH.zip:STATS.pkl to name its VecNormalize "
        "statistics; statistics are found by themselves only in a run folder of agent-envs "
        "train, checked against its manifest.json, or of rl-zoo3), an apg run folder, or "
        "module:attribute, a Python object you name (a callable obs -> action, an object with "
        "predict, or a factory env -> policy; per-agent:module:attribute for a parameter-shared "
        "per-agent law, scored on the task's PettingZoo twin); repeat for several. Default: "
        "turnpike, proportional, zero.",
        flags=("--policy", "-p"),
        action="append",
        metavar="[NAME=]SPEC",
    )
    task: str | None = option_field(
        None,
        "a benchmark task id (agent-envs tasks lists them): score the policies on its test "
        "seeds against its shipped references and write OUT/scores.csv (--env-kwargs may then "
        "set the interface only: observation, action_basis, agent_reward)",
    )
    env_id: str = option_field(GYM_ENV_ID, "Gymnasium env id")
    env_kwargs: dict = field(
        default_factory=dict,
        metadata={
            "help": 'env keyword arguments as a JSON object, e.g. \'{"n_agents": 20, '
            '"integrator": "em"}\' (default: the env\'s defaults)'
        },
    )
    seeds: tuple[int, ...] | None = option_field(
        None,
        "reset seeds: '0 1 2', '0-19', '0:20' or '0,1,2' (default 10000-10019; with --task "
        "the task's 20 test seeds, and only they may be named)",
        nargs="*",
        type=str,
    )
    target: float | None = option_field(None, "reset option: the target (default: the env's)")
    beta: float = option_field(DEFAULT_BETA, "baselines' beta")
    delta: float = option_field(DEFAULT_DELTA, "baselines' delta")
    out: Path = option_field(MISSING, "output folder")
    report: bool = option_field(False, "also write a report in OUT/report", action="store_true")
    progress: bool = option_field(
        True, "no progress bar", flags=("--no-progress",), action="store_false"
    )

    def __post_init__(self) -> None:
        if self.policies is not None:
            object.__setattr__(self, "policies", tuple(self.policies))
        self.policy_specs()  # ValueError naming --policy
        object.__setattr__(self, "env_kwargs", parse_env_kwargs(self.env_kwargs))
        object.__setattr__(self, "out", Path(self.out))
        check_env_id(self.env_id)
        if self.target is not None:
            check_real("--target", self.target, TARGET_RANGE)
        if self.task is not None:
            self._check_task()
        else:
            object.__setattr__(self, "seeds", tuple(parse_seeds(self.seeds)))
            for name, spec in self.policy_specs().items():
                if spec.startswith("per-agent:"):
                    raise ValueError(
                        f"--policy {name}: per-agent:module:attribute policies are scored on a "
                        "task's PettingZoo twin: give --task"
                    )
        check_positive("--beta", self.beta)
        check_positive("--delta", self.delta)

    def _check_task(self) -> None:
        """--task: a known task, its test seeds, interface kwargs only, no --env-id/--target."""
        from agent_envs.tasks import get_task

        task = get_task(self.task)
        object.__setattr__(self, "task", task.id)
        if self.env_id != GYM_ENV_ID:
            raise ValueError("--task fixes the env: leave out --env-id")
        if self.target is not None:
            raise ValueError(f"--task {task.id} fixes the target: leave out --target")
        task.make_kwargs(self.env_kwargs)  # ValueError naming a kwarg the task fixes
        seeds = tuple(task.test_seeds)
        if self.seeds is not None:
            seeds = tuple(parse_seeds(self.seeds))
            unknown = [s for s in seeds if s not in task.test_seeds]
            if unknown:
                raise ValueError(
                    f"--seeds: {unknown} are not test seeds of {task.id} "
                    f"({task.test_seeds[0]}..{task.test_seeds[-1]}); only they have references"
                )
        object.__setattr__(self, "seeds", seeds)

    def policy_specs(self) -> dict[str, str]:
        """{name: spec} of the --policy items (`parse_policy_specs`)."""
        return parse_policy_specs(self.policies)

    def check_models(self) -> None:
        """Check every saved model named: its file, algorithm and statistics (nothing is
        unpickled); an apg run folder is checked against its manifest when it is loaded."""
        files = [
            spec
            for spec in self.policy_specs().values()
            if spec not in BASELINE_POLICIES and not is_object_spec(spec)
        ]
        if not files:
            return  # nothing to check: no torch needed
        from agent_envs.training.learners.apg_policy import is_apg_run

        for spec in files:
            if not is_apg_run(spec):
                check_model(spec)

    def reset_options(self) -> dict[str, Any] | None:
        """The options of every reset: the target when given."""
        return {"target": self.target} if self.target is not None else None
