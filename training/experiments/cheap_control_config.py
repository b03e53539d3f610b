"""The options of `agent-envs reproduce cheap-control-bound`: `CheapControlBoundConfig`.

Sizes (N, K paths, evaluation paths), the time step tau (which must divide every horizon into
m >= 2 steps), the horizons of the V(T) rows, sigma, eps, beta, the N and eps of the scaling
rows and the seed, each checked on construction against the core's ranges
(`agent_envs.validation`), plus the solver's options (`experiments.SolverOptions`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from agent_envs.baselines import DEFAULT_BETA
from agent_envs.training.config import option_field
from agent_envs.training.experiments import SolverOptions, check_sizes
from agent_envs.validation import (
    EPSILON_RANGE,
    HORIZON_RANGE,
    MAX_BATCH_SIZE,
    MAX_SEED,
    SIGMA_RANGE,
    check_int,
    check_positive,
    check_real,
)

HORIZONS = (0.5, 1.0, 2.0, 4.0, 8.0)
SCALING_AGENTS = (5, 10, 20, 40)
SCALING_EPSILONS = (0.05, 0.1, 0.2, 0.5, 1.0)


# ------------------------------------------------------------------------------ the config


@dataclass(frozen=True, kw_only=True)
class CheapControlBoundConfig(SolverOptions):
    """Sizes and settings of the run (module docstring): the options of `agent-envs reproduce
    cheap-control-bound`; validated on construction."""

    out: Path = option_field(Path("reproduction_cheap_control_bound"), "output folder")
    n_agents: int = option_field(10, "N of the V(T), x0=xbar, random-x0 and eps rows (paper: 100)")
    n_paths: int = option_field(10, "K: Brownian paths of the sample-average solves (paper: 20)")
    eval_paths: int = option_field(200, "fresh paths (and x^0 draws) each control is evaluated on")
    tau: float = option_field(0.05, "time step (paper: 0.02); it must divide every horizon")
    horizons: tuple[float, ...] = option_field(HORIZONS, "horizons T of the V(T) rows")
    sigma: float = option_field(0.1, "noise level of the sigma > 0 rows (paper: 0.01)")
    epsilon: float = option_field(0.05, "stiffness eps of the symmetric kernel (paper: 0.05)")
    beta: float = option_field(DEFAULT_BETA, "beta of the cheap control and of C_0 (paper: 12)")
    scaling_agents: tuple[int, ...] = option_field(
        SCALING_AGENTS, "N of the noise-floor scaling rows"
    )
    scaling_horizon: float = option_field(
        2.0, "T of the N-scaling rows and of the contraction check"
    )
    scaling_epsilons: tuple[float, ...] = option_field(
        SCALING_EPSILONS, "eps of the C_0 scaling rows"
    )
    seed: int = option_field(0, "x^0, the solver's paths and the evaluation paths")

    def __post_init__(self) -> None:
        from agent_envs.validation import Range

        object.__setattr__(self, "out", Path(self.out))
        for name in ("horizons", "scaling_agents", "scaling_epsilons"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
        check_sizes(self.n_agents, self.n_paths, min_agents=2)
        check_int("--eval-paths", self.eval_paths, 2, 100_000)
        if self.n_agents * self.eval_paths > MAX_BATCH_SIZE:
            raise ValueError(
                f"--n-agents times --eval-paths must be <= {MAX_BATCH_SIZE}, got "
                f"{self.n_agents} x {self.eval_paths}"
            )
        check_positive("--tau", self.tau, HORIZON_RANGE)
        for horizon in self.horizons:
            check_positive("--horizons", horizon, HORIZON_RANGE)
        check_real("--sigma", self.sigma, Range(0.0, SIGMA_RANGE.high, low_open=True))
        check_positive("--epsilon", self.epsilon, EPSILON_RANGE)
        check_positive("--beta", self.beta, Range(0.0, 1e6, low_open=True))
        for n_agents in self.scaling_agents:
            check_int("--scaling-agents", n_agents, 2, 1000)
        check_positive("--scaling-horizon", self.scaling_horizon, HORIZON_RANGE)
        for epsilon in self.scaling_epsilons:
            check_positive("--scaling-epsilons", epsilon, EPSILON_RANGE)
        check_int("--seed", self.seed, 0, MAX_SEED)
        self.check_solver_options()
        if not all((self.horizons, self.scaling_agents, self.scaling_epsilons)):
            raise ValueError(
                "--horizons, --scaling-agents and --scaling-epsilons need a value each"
            )
        for option, horizon in [("--horizons", h) for h in self.horizons] + [
            ("--scaling-horizon", self.scaling_horizon)
        ]:
            steps = horizon / self.tau
            if abs(steps - round(steps)) > 1e-9 or round(steps) < 2:
                raise ValueError(
                    f"--tau must divide {option} into m >= 2 steps; {horizon} / {self.tau} = "
                    f"{steps:g}"
                )
