"""The paper's experiments, reproduced (Cassini & Segala, arXiv 2503.09549, Section 5).

- `uncontrolled`: Section 5.1 (Figs. 1-4): the uncontrolled swarm under EM, EE, Heun, ERB and
  SERB, with a Jacobian study.
- `turnpike_controlled`: Section 5.2 (Figs. 5-6): the turnpike-controlled swarm, through the
  Gymnasium env and as the paper's closed loop.
- `turnpike_property`: the turnpike theorem measured on optimal solutions.
- `cheap_control_bound`: Lemma `lem:cheap` measured: its counterexamples, the noise floor, a
  corrected bound (docs/cheap-control-bound.md) and the proof's contraction under SERB.

Each module has a frozen config dataclass (one field per option of `agent-envs reproduce NAME`,
validated on construction) and ``reproduce(out_dir, ...)`` (writes tables and figures); the
command line is `agent-envs reproduce uncontrolled|turnpike|turnpike-property|cheap-control-bound`
(`agent_envs.training.commands.cli`).
"""

from __future__ import annotations

from dataclasses import dataclass

from agent_envs.simulator import DEFAULT_MAX_CONTROL
from agent_envs.training.config import option_field
from agent_envs.validation import (
    MAX_AGENTS,
    MAX_BATCH_SIZE,
    MAX_CONTROL_RANGE,
    MAX_PATHS,
    MAX_STEPS,
    check_int,
    check_positive,
)


@dataclass(frozen=True, kw_only=True)
class SolverOptions:
    """The optimal-control solver's options of the experiments that solve the problem
    (`turnpike_property`, `cheap_control_bound`), and their progress lines."""

    max_control: float = option_field(DEFAULT_MAX_CONTROL, "bound |u| <= max_control of the solver")
    gtol: float = option_field(1e-6, "relative gradient tolerance of the solver")
    max_iterations: int = option_field(500, "the solver's iterations per solve, at most")
    progress: bool = option_field(
        True, "no progress lines", flags=("--no-progress",), action="store_false"
    )

    def check_solver_options(self) -> None:
        """ValueError/TypeError naming the option for a bad solver option."""
        check_positive("--max-control", self.max_control, MAX_CONTROL_RANGE)
        check_positive("--gtol", self.gtol)
        check_int("--max-iterations", self.max_iterations, 1, 1_000_000)


def check_sizes(
    n_agents: int, n_paths: int, n_steps: int | None = None, min_agents: int = 1
) -> None:
    """--n-agents, --n-paths (and --n-steps) within the core's accepted sizes.

    Raises TypeError/ValueError naming the option and its range, and naming --n-paths when
    --n-agents times --n-paths exceeds the core's batch size (`validation.MAX_BATCH_SIZE`).
    """
    check_int("--n-agents", n_agents, min_agents, MAX_AGENTS)
    check_int("--n-paths", n_paths, 1, MAX_PATHS)
    if n_steps is not None:
        check_int("--n-steps", n_steps, 1, MAX_STEPS)
    if n_agents * n_paths > MAX_BATCH_SIZE:
        raise ValueError(
            f"--n-agents times --n-paths must be <= {MAX_BATCH_SIZE}, got {n_agents} x {n_paths}"
        )
