"""The validated keyword arguments of the swarm envs, and the start of an episode from them.

`EpisodeConfig.from_kwargs(**kwargs)` splits an env's flat keyword arguments into the swarm's
`SwarmParams`, the env's `SimulationSpec` (how a step is discretized: integrator, Jacobian, phi
method, m, paths, control bound; the one spec `simulate`, the solver and the controllers share)
and the env's own options (divergence threshold, linear operator, the learner's interface),
each checked where it is defined. `reset_options`, `start_positions` and `episode_params` read a
reset's options into x^0 and the episode's `SwarmParams`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from agent_envs.draws import uniform_positions
from agent_envs.dynamics.operators import check_linear_operator
from agent_envs.envs.interface import (
    DEFAULT_NEIGHBOURS,
    ENV_KIND_VALUES,
    MAX_NEIGHBOURS,
    check_env_options,
    check_option,
)
from agent_envs.params import SwarmParams
from agent_envs.simulator import (
    DEFAULT_DIVERGENCE_THRESHOLD,
    SimulationSpec,
    as_positions,
    diverged_paths,
)
from agent_envs.validation import DIVERGENCE_THRESHOLD_RANGE, check_int, check_positive

#: Keys of `reset(options=...)` the swarm envs understand.
RESET_OPTION_NAMES = ("initial_positions", "target")


def reset_options(options: Any, strict: bool) -> dict[str, Any]:
    """The understood reset options as a dict (missing keys are None).

    With `strict`, an unknown key (a typo such as "initial_position") raises `ValueError`
    naming it; otherwise unknown keys are ignored (PettingZoo's API tests pass
    ``{"options": 1}`` and expect it to be accepted). The values are checked by
    `SwarmEpisode.reset` (errors name ``initial_positions`` or ``target``).
    """
    if options is None:
        options = {}
    if not isinstance(options, dict):
        raise TypeError(f"options must be a dict or None, got {type(options).__name__}")
    unknown = sorted(set(options) - set(RESET_OPTION_NAMES))
    if strict and unknown:
        raise ValueError(
            f"unknown reset option(s) {unknown}; the swarm envs take {list(RESET_OPTION_NAMES)}"
        )
    return {name: options.get(name) for name in RESET_OPTION_NAMES}


#: The env kwargs that make the env's `SimulationSpec` (`EpisodeConfig.simulation`).
SIMULATION_OPTION_NAMES = (
    "integrator",
    "jacobian",
    "phi_method",
    "n_steps",
    "n_paths",
    "max_control",
)

#: Every env kwarg other than the `SwarmParams` fields (and `render_mode`).
ENV_OPTION_NAMES = (
    *SIMULATION_OPTION_NAMES,
    "divergence_threshold",
    "linear_operator",
    "observation",
    "action_basis",
    "agent_reward",
    "neighbours",
)


def _check_target(params: SwarmParams, threshold: float) -> None:
    if np.any(np.abs(params.target_vector) >= threshold):
        raise ValueError(
            f"target must lie inside the divergence threshold (|target| < {threshold:g}), "
            f"got {params.target}"
        )


def unexpected_keyword(owner: str, name: str, accepted: tuple[str, ...]) -> TypeError:
    """Python's own error for an unknown keyword argument, with the accepted names as a note.

    The message is exactly ``"<owner>() got an unexpected keyword argument '<name>'"``, the
    form Python raises for a function call, because clients parse it (TorchRL's `GymEnv`
    retries `gym.make` without ``render_mode`` or ``frameskip`` only on that message).
    """
    error = TypeError(f"{owner}() got an unexpected keyword argument {name!r}")
    if hasattr(error, "add_note"):  # Python >= 3.11
        error.add_note(f"the swarm envs take {', '.join(accepted)}")
    return error


@dataclass(frozen=True)
class EpisodeConfig:
    """Validated keyword arguments of the swarm envs (everything except `render_mode` and the
    native vector env's own arguments).

    Build it with `EpisodeConfig.from_kwargs(**kwargs)`: the `SwarmParams` fields go to
    `params`, the six `SIMULATION_OPTION_NAMES` (integrator, jacobian, phi_method, n_steps,
    n_paths, max_control) to `simulation`, the env's `SimulationSpec` (checked by it, with its
    defaults: one Brownian path per episode, `ENV_N_PATHS`; seed None, the env draws from its
    own generator), the rest are the fields below. A bad value raises `ValueError` (or
    `TypeError`) naming the argument and its range (`agent_envs.validation`); an unknown name
    raises Python's standard `TypeError` ("... got an unexpected keyword argument 'x'").

    Ranges: 1 <= n_steps <= 1e9; 1 <= n_paths <= 1e6 with n_paths N d <= 1e8;
    0 < max_control <= 1e6; 1 <= divergence_threshold <= 1e6 with |target| < it;
    linear_operator in "auto" | "dense" | "matrix_free" (see `SwarmModel`); observation,
    action_basis and agent_reward are the learner's interface (`agent_envs.envs.interface`:
    each env takes its own values of them; none changes the dynamics, the cost or the random
    draws). neighbours: K of ``observation="local"`` (PettingZoo), an int in [1, 1024], default
    6 (None before it is resolved); given with another layout it raises `ValueError`, since it
    would change nothing. The simulation's fields read as the config's own too
    (``config.n_steps`` is ``config.simulation.n_steps``), as the env kwargs name them.
    """

    params: SwarmParams
    simulation: SimulationSpec = field(default_factory=SimulationSpec)
    divergence_threshold: float = DEFAULT_DIVERGENCE_THRESHOLD
    linear_operator: str = "auto"
    observation: str = "absolute"
    action_basis: str = "agents"
    agent_reward: str = "own"
    neighbours: int | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.params, SwarmParams):
            raise TypeError(f"params must be a SwarmParams, got {type(self.params).__name__}")
        if not isinstance(self.simulation, SimulationSpec):
            raise TypeError(
                f"simulation must be a SimulationSpec, got {type(self.simulation).__name__}"
            )
        self.simulation.for_params(self.params)
        threshold = check_positive(
            "divergence_threshold", self.divergence_threshold, DIVERGENCE_THRESHOLD_RANGE
        )
        object.__setattr__(self, "divergence_threshold", threshold)
        _check_target(self.params, threshold)
        check_linear_operator(self.linear_operator)
        for name in ("observation", "action_basis", "agent_reward"):
            check_option(name, getattr(self, name))
        self._check_neighbours()

    def _check_neighbours(self) -> None:
        """``neighbours``: an int in [1, MAX_NEIGHBOURS] with ``observation="local"`` (None
        there becomes `DEFAULT_NEIGHBOURS`), None with any other layout."""
        if self.neighbours is None:
            if self.observation == "local":
                object.__setattr__(self, "neighbours", DEFAULT_NEIGHBOURS)
            return
        value = check_int("neighbours", self.neighbours, 1, MAX_NEIGHBOURS)
        if self.observation != "local":
            raise ValueError(
                "neighbours is an option of the PettingZoo env's observation='local' only; "
                f"got neighbours={value} with observation={self.observation!r}"
            )
        object.__setattr__(self, "neighbours", value)

    @classmethod
    def from_kwargs(
        cls, owner: str = "EpisodeConfig.from_kwargs", /, env_kind: str | None = None, **kwargs: Any
    ) -> EpisodeConfig:
        """Split env keyword arguments into `SwarmParams` fields, the `SimulationSpec`'s and
        env options.

        `owner` names the callable in the `TypeError` for an unknown keyword (the env's
        ``__init__``), as Python would. `env_kind` ("gymnasium" | "pettingzoo"): an option
        value that env does not take is refused with that env's values
        (`interface.check_env_options`), before the generic check that names both envs' values
        (a value of the wrong type still gets its TypeError there; the defaults fit both envs).
        The checks run in this order: unknown names, the env's option values, `SwarmParams`,
        `SimulationSpec`, then the config's own (`__post_init__`).
        """
        param_names = SwarmParams.field_names()
        accepted = (*param_names, *ENV_OPTION_NAMES, "render_mode")
        for name in kwargs:
            if name not in param_names and name not in ENV_OPTION_NAMES:
                raise unexpected_keyword(owner, name, accepted)
        if env_kind is not None:
            check_env_options(
                env_kind,
                **{
                    k: v
                    for k, v in kwargs.items()
                    if k in ENV_KIND_VALUES[env_kind] and isinstance(v, str)
                },
            )
        params = SwarmParams(**{k: v for k, v in kwargs.items() if k in param_names})
        simulation = SimulationSpec(
            **{k: v for k, v in kwargs.items() if k in SIMULATION_OPTION_NAMES}
        )
        options = {
            k: v
            for k, v in kwargs.items()
            if k not in param_names and k not in SIMULATION_OPTION_NAMES
        }
        return cls(params=params, simulation=simulation, **options)

    def replace(self, **changes: Any) -> EpisodeConfig:
        """This config with some env keyword arguments replaced (`SwarmParams` fields, the
        simulation's or options, by their env kwarg names), validated again."""
        param_names = SwarmParams.field_names()
        params = {k: v for k, v in changes.items() if k in param_names}
        spec = {k: v for k, v in changes.items() if k in SIMULATION_OPTION_NAMES}
        options = {k: v for k, v in changes.items() if k not in params and k not in spec}
        if options.get("observation", "local") != "local":  # (K belongs to the local layout)
            options.setdefault("neighbours", None)
        return dataclasses.replace(
            self,
            params=dataclasses.replace(self.params, **params) if params else self.params,
            simulation=dataclasses.replace(self.simulation, **spec) if spec else self.simulation,
            **options,
        )

    @property
    def dt(self) -> float:
        """The time step tau = T / m."""
        return self.simulation.time_step(self.params)

    @property
    def integrator(self) -> str:
        """``simulation.integrator``: em | ee | heun | erb | serb."""
        return self.simulation.integrator

    @property
    def jacobian(self) -> str:
        """``simulation.jacobian``: "frozen" or "exact" (erb, serb)."""
        return self.simulation.jacobian

    @property
    def phi_method(self) -> str:
        """``simulation.phi_method``, as given ("auto" resolved by the env's `StepPlan`)."""
        return self.simulation.phi_method

    @property
    def n_steps(self) -> int:
        """``simulation.n_steps``: m, the steps of an episode."""
        return self.simulation.n_steps

    @property
    def n_paths(self) -> int:
        """``simulation.n_paths``: the Brownian paths of an episode."""
        return self.simulation.n_paths

    @property
    def max_control(self) -> float:
        """``simulation.max_control``: u = max_control * action."""
        return self.simulation.max_control


def same_dynamics(a: SwarmParams, b: SwarmParams) -> bool:
    """True when a and b differ at most in the cost parameters (target, gamma)."""
    return dataclasses.replace(a, target=b.target, gamma=b.gamma) == b


def start_positions(
    config: EpisodeConfig, rng: np.random.Generator, initial_positions: Any = None
) -> np.ndarray:
    """x^0 of one episode, (N, d): uniform on [-1, 1]^d from `rng`, or `initial_positions`.

    The uniform draw is made either way, so the Brownian increments of a seeded episode do
    not depend on whether a start was given.
    """
    n, d = config.params.n_agents, config.params.dim
    x0 = uniform_positions(rng, n, d)
    if initial_positions is not None:
        x0 = as_positions(initial_positions, n, d, "initial_positions")
        if np.any(diverged_paths(x0, config.divergence_threshold)):
            raise ValueError(
                "initial_positions must lie inside the divergence threshold "
                f"(|x| <= {config.divergence_threshold})"
            )
    return x0


def episode_params(config: EpisodeConfig, target: Any = None) -> SwarmParams:
    """The `SwarmParams` of an episode: the config's, with xbar replaced by `target` if given."""
    if target is None:
        return config.params
    params = dataclasses.replace(config.params, target=target)  # checks and names `target`
    _check_target(params, config.divergence_threshold)
    return params
