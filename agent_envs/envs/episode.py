"""The episode core shared by the Gymnasium and the PettingZoo swarm environments.

Both envs are thin adapters over `SwarmEpisode`: it validates the keyword arguments
(`EpisodeConfig`), holds the state of the `n_paths` Brownian paths, steps them with the core's
integrator (`agent_envs.integrators.make_integrator`) on increments drawn from the generator
the env passes in (its ``self.np_random``), takes the running cost of `eq:running_cost` with
`agent_envs.costs`, and flags divergence with `agent_envs.simulator.diverged_paths`. Nothing
here re-derives the dynamics: the drift, its linearization and the interaction drift of the
observation all come from `agent_envs.dynamics.SwarmModel`.

One step n -> n + 1 (tau = T / m, t_n = n tau)::

    c^n     = mean over paths of c(x^n, u^n)                  (eq:running_cost)
    dW^n    ~ N(0, tau I), shape (n_paths, N, d), from the env's generator
    x^{n+1} = integrator.step(model, x^n, u^n, t_n, tau, dW^n)

and the reward is ``-tau c^n`` (left rectangle rule of `eq:discrete_cost_functional`), so that
the rewards of an episode add up to minus the discrete cost functional on the env's paths.

The observation needs the interaction drift L(x^{n+1}) x^{n+1} at the new state, and the next
integrator step needs L(x^{n+1}) again (every scheme evaluates F(x, u) = L(x) x + u at the start
of the step). The episode's model, `agent_envs.dynamics.linearization_cache.LinearizationCache`,
keeps the last L(x), keyed by the identity of the (read-only) state array, so the kernel
matrix is built once per step instead of twice (the matrix-free operator of large swarms,
env kwarg `linear_operator`, likewise).
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections import Counter
from dataclasses import dataclass
from typing import Any

import numpy as np
from gymnasium import spaces

from agent_envs import arrays
from agent_envs.costs import agent_running_cost, running_cost
from agent_envs.dynamics.linearization_cache import LinearizationCache
from agent_envs.dynamics.operators import check_linear_operator
from agent_envs.dynamics.swarm import SwarmModel
from agent_envs.envs.interface import (
    ENV_KIND_VALUES,
    action_rows,
    check_env_options,
    check_option,
    controls_from_actions,
)
from agent_envs.envs.observation import global_observation
from agent_envs.envs.step_plan import StepPlan, planned_integrator, resolve_step_plan
from agent_envs.integrators import (
    DEFAULT_INTEGRATOR,
    DEFAULT_JACOBIAN,
    Integrator,
)
from agent_envs.params import SwarmParams
from agent_envs.simulator import (
    DEFAULT_DIVERGENCE_THRESHOLD,
    DEFAULT_MAX_CONTROL,
    DEFAULT_N_STEPS,
    DEFAULT_PHI_METHOD,
    ENV_N_PATHS,
    SimulationSpec,
    as_positions,
    brownian_increments,
    diverged_paths,
    uniform_positions,
)
from agent_envs.validation import (
    DIVERGENCE_THRESHOLD_RANGE,
    check_positive,
    real_array,
)

# The simulation defaults (DEFAULT_N_STEPS, DEFAULT_MAX_CONTROL, ...) are `SimulationSpec`'s,
# defined once in `agent_envs.simulator` and imported above (agent_envs.envs re-exports
# DEFAULT_MAX_CONTROL).

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


ENV_OPTION_NAMES = (
    "integrator",
    "jacobian",
    "phi_method",
    "n_steps",
    "n_paths",
    "max_control",
    "divergence_threshold",
    "linear_operator",
    "observation",
    "action_basis",
    "agent_reward",
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
    """Validated keyword arguments of both swarm envs (everything except `render_mode`).

    Build it with `EpisodeConfig.from_kwargs(**kwargs)`: the `SwarmParams` fields go to
    `params`, the rest are the fields below. A bad value raises `ValueError` (or `TypeError`)
    naming the argument and its range (`agent_envs.validation`); an unknown name raises
    Python's standard `TypeError` ("... got an unexpected keyword argument 'x'").

    Ranges: 1 <= n_steps <= 1e9; 1 <= n_paths <= 1e6 with n_paths N d <= 1e8;
    0 < max_control <= 1e6; 1 <= divergence_threshold <= 1e6 with |target| < it;
    linear_operator in "auto" | "dense" | "matrix_free" (see `SwarmModel`); observation,
    action_basis and agent_reward are the learner's interface (`agent_envs.envs.interface`:
    each env takes its own values of them; none changes the dynamics, the cost or the random
    draws). The first six
    fields are the env's `SimulationSpec` (`simulation`), checked by it, with its defaults (one
    Brownian path per episode: `ENV_N_PATHS`).
    """

    params: SwarmParams
    integrator: str = DEFAULT_INTEGRATOR
    jacobian: str = DEFAULT_JACOBIAN
    phi_method: str = DEFAULT_PHI_METHOD
    n_steps: int = DEFAULT_N_STEPS
    n_paths: int = ENV_N_PATHS
    max_control: float = DEFAULT_MAX_CONTROL
    divergence_threshold: float = DEFAULT_DIVERGENCE_THRESHOLD
    linear_operator: str = "auto"
    observation: str = "absolute"
    action_basis: str = "agents"
    agent_reward: str = "own"

    def __post_init__(self) -> None:
        if not isinstance(self.params, SwarmParams):
            raise TypeError(f"params must be a SwarmParams, got {type(self.params).__name__}")
        spec = self.simulation.for_params(self.params)
        set_ = object.__setattr__
        for name in ("n_steps", "n_paths", "max_control"):
            set_(self, name, getattr(spec, name))
        threshold = check_positive(
            "divergence_threshold", self.divergence_threshold, DIVERGENCE_THRESHOLD_RANGE
        )
        set_(self, "divergence_threshold", threshold)
        _check_target(self.params, threshold)
        check_linear_operator(self.linear_operator)
        for name in ("observation", "action_basis", "agent_reward"):
            check_option(name, getattr(self, name))

    @classmethod
    def from_kwargs(
        cls, owner: str = "EpisodeConfig.from_kwargs", /, env_kind: str | None = None, **kwargs: Any
    ) -> EpisodeConfig:
        """Split env keyword arguments into `SwarmParams` fields and env options.

        `owner` names the callable in the `TypeError` for an unknown keyword (the env's
        ``__init__``), as Python would. `env_kind` ("gymnasium" | "pettingzoo"): an option
        value that env does not take is refused with that env's values
        (`interface.check_env_options`), before the generic check that names both envs' values
        (a value of the wrong type still gets its TypeError there; the defaults fit both envs).
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
        return cls(params=params, **{k: v for k, v in kwargs.items() if k not in param_names})

    @property
    def dt(self) -> float:
        """The time step tau = T / m."""
        return self.params.horizon / self.n_steps

    @property
    def simulation(self) -> SimulationSpec:
        """The env's discretization as the core's one `SimulationSpec` (seed: None; the env
        draws from its own generator)."""
        return SimulationSpec(
            self.integrator,
            self.jacobian,
            self.phi_method,
            self.n_steps,
            self.n_paths,
            self.max_control,
        )


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


def _quiet_overflow(x: Any) -> Any:
    """numpy's errstate ignoring overflow/invalid (a diverging step is flagged, not warned);
    a no-op context for torch, which does not warn."""
    if isinstance(x, np.ndarray):
        return np.errstate(over="ignore", invalid="ignore")
    return contextlib.nullcontext()


def mean_interaction_drift(model: SwarmModel, x: Any) -> Any:
    """E over the paths of the interaction drift L(x) x: x (..., P, N, d) -> (..., N, d).

    Marks a numpy x read-only first, so that a `LinearizationCache` keeps L(x) for the
    next integrator step from this state. numpy arrays or torch tensors.
    """
    if isinstance(x, np.ndarray):
        x.flags.writeable = False
    with _quiet_overflow(x):
        return arrays.mean_axis(model.interaction_drift(x), -3)


def mean_running_cost(x: Any, control: Any, target: Any, gamma: float) -> Any:
    """c(x^n, u^n) of `eq:running_cost`, mean over the paths.

    x (..., P, N, d), control (..., N, d) (the same for every path), target (..., d);
    returns shape (...). Batched over leading (env) axes; numpy arrays or torch tensors.
    """
    per_path = running_cost(x, control[..., None, :, :], target[..., None, None, :], gamma)
    return arrays.mean_axis(per_path, -1)


def advance_paths(
    integrator: Integrator,
    model: SwarmModel,
    x: np.ndarray,
    control: np.ndarray,
    t: float | np.ndarray,
    dt: float,
    dw: np.ndarray,
    divergence_threshold: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One integrator step of every path, with the divergence check of the envs.

    Args:
        x: x^n, (..., P, N, d); leading axes are envs.
        control: u^n, (..., N, d), held over the step and the same for every path.
        t: t_n, a float or an array broadcastable to x (one time per env).
        dw: Brownian increments, the shape of x.

    numpy arrays or torch tensors (all in one library).

    Returns:
        x^{n+1} (..., P, N, d); E interaction drift at x^{n+1}, (..., N, d); and the (...)
        flags "diverged": some path of the env left the divergence threshold, or it or the
        interaction drift became non-finite. Entries of diverged envs are meaningless.
    """
    xp = arrays.namespace(x)
    with _quiet_overflow(x):
        x_next = integrator.step(model, x, control[..., None, :, :], t, dt, dw)
    diverged = xp.any(diverged_paths(x_next, divergence_threshold), axis=-1)
    drift = mean_interaction_drift(model, x_next)
    diverged = diverged | ~xp.all(xp.isfinite(drift), axis=(-2, -1))
    return x_next, drift, diverged


@dataclass(frozen=True)
class StepOutcome:
    """What one `SwarmEpisode.step` did.

    Attributes:
        start_positions: x^n, (n_paths, N, d), the state the running cost is taken at.
        control: u^n, (N, d), the control applied over the step (after clipping).
        running_cost: c(x^n, u^n) of `eq:running_cost`, mean over the paths.
        diverged: True when x^{n+1} left the divergence threshold, or it or its interaction
            drift became non-finite, on some path; the episode then keeps x^n and t_n.
        truncated: True when the step reached the horizon T (n + 1 = m) without diverging.
    """

    start_positions: np.ndarray
    control: np.ndarray
    running_cost: float
    diverged: bool
    truncated: bool


class SwarmEpisode:
    """State and stepping of one episode of the controlled swarm, for both env adapters.

    Attributes:
        config: the validated `EpisodeConfig`.
        params: the `SwarmParams` of the current episode (target included).
        model: the `SwarmModel` of `params` (the integrators and controllers use it).
        integrator: the `Integrator` named by `config.integrator`.
        positions: (n_paths, N, d) current state (read-only array).
        step_index: n, the number of steps taken since reset.
        diverged: True once a step diverged (the episode is then over).
        plan: the `StepPlan` of a step, resolved here once (`env` names the adapter:
            "gymnasium" or "pettingzoo"); the integrator is built with its `phi_method`.
        fallbacks: the mid-step fallbacks counted (`step_plan.FALLBACKS`), a `Counter`.
    """

    def __init__(self, config: EpisodeConfig, env: str = "gymnasium", threads: int = 1) -> None:
        self.config = config
        self.params = config.params
        self.fallbacks: Counter[str] = Counter()
        self.model: LinearizationCache = LinearizationCache(
            self.params, config.linear_operator, fallbacks=self.fallbacks, threads=threads
        )
        self.plan: StepPlan = resolve_step_plan(config, self.model, env=env, threads=threads)
        self.integrator: Integrator = planned_integrator(config, self.plan)
        arrays.prepare_hot_path()
        self.dt = config.dt
        self.positions: np.ndarray | None = None
        self.step_index = 0
        self.diverged = False
        self._mean_drift: np.ndarray | None = None
        self._target = self.params.target_vector

    # ----------------------------------------------------------------- state
    @property
    def n_agents(self) -> int:
        return self.params.n_agents

    @property
    def dim(self) -> int:
        return self.params.dim

    @property
    def target(self) -> np.ndarray:
        """xbar as a (d,) array (a copy)."""
        return self._target.copy()

    @property
    def time(self) -> float:
        """t_n = n T / m."""
        return self.params.horizon * self.step_index / self.config.n_steps

    @property
    def time_fraction(self) -> float:
        """t_n / T = n / m."""
        return self.step_index / self.config.n_steps

    @property
    def done(self) -> bool:
        """True when the episode has ended (horizon reached or diverged)."""
        return self.diverged or self.step_index >= self.config.n_steps

    @property
    def mean_positions(self) -> np.ndarray:
        """E x over the paths: (N, d), a new array (`arrays.mean_axis`, as the native vector
        env's observation: the same bits)."""
        return arrays.mean_axis(self._require_state(), 0)

    @property
    def mean_interaction_drift(self) -> np.ndarray:
        """E (1/N) sum_l p(x_k, x_l)(x_l - x_k) over the paths: (N, d), a new array."""
        self._require_state()
        return self._mean_drift.copy()

    def _require_state(self) -> np.ndarray:
        if self.positions is None:
            raise RuntimeError("the episode has not been reset; call reset() first")
        return self.positions

    # ---------------------------------------------------------------- stepping
    def reset(
        self, rng: np.random.Generator, initial_positions: Any = None, target: Any = None
    ) -> None:
        """Start an episode at t = 0.

        The uniform start on [-1, 1]^d is always drawn from `rng` (then replaced by
        `initial_positions` if given), so that the Brownian increments of the episode do not
        depend on whether a start was given. `target` overrides xbar for this episode.
        """
        n, d = self.config.params.n_agents, self.config.params.dim
        x0 = start_positions(self.config, rng, initial_positions)
        params = episode_params(self.config, target)
        if params != self.params:
            # target and gamma are cost parameters: a new target keeps the dynamics model
            # (and its kernel); only a change of the dynamics would rebuild it.
            if not same_dynamics(params, self.params):
                self.model = LinearizationCache(
                    params,
                    self.config.linear_operator,
                    fallbacks=self.fallbacks,
                    threads=self.model.threads,
                )
            self.params = params
            self._target = params.target_vector
        x = np.broadcast_to(x0, (self.config.n_paths, n, d)).copy()
        drift = mean_interaction_drift(self.model, x)
        if not np.all(np.isfinite(drift)):
            raise ValueError(
                "kernel: the interaction drift is not finite at the initial positions (a user "
                "kernel must return finite values there)"
            )
        self.positions, self._mean_drift = x, drift
        self.step_index = 0
        self.diverged = False

    def step(self, rng: np.random.Generator, control: np.ndarray) -> StepOutcome:
        """Advance all paths by one step under the control u^n (N, d) (already validated)."""
        x = self._require_state()
        if self.done:
            raise RuntimeError(
                "the episode is over (horizon reached or diverged); call reset() first"
            )
        cost = float(mean_running_cost(x, control, self._target, self.params.gamma))
        dw = brownian_increments(rng, x.shape, self.dt)
        # BLAS limited to one thread while stepping (see agent_envs.arrays.hot_path_threads).
        with arrays.hot_path_threads():
            x_next, drift, diverged_flag = advance_paths(
                self.integrator,
                self.model,
                x,
                control,
                self.time,
                self.dt,
                dw,
                self.config.divergence_threshold,
            )
        diverged = bool(diverged_flag)
        if diverged:
            self.diverged = True
        else:
            self.positions, self._mean_drift = x_next, drift
            self.step_index += 1
        return StepOutcome(
            start_positions=x,
            control=control,
            running_cost=cost,
            diverged=diverged,
            truncated=not diverged and self.step_index >= self.config.n_steps,
        )

    # ------------------------------------------------------------------ rewards
    def reward(self, outcome: StepOutcome) -> float:
        """-tau c(x^n, u^n), mean over the paths."""
        return -self.dt * outcome.running_cost

    def agent_costs(self, outcome: StepOutcome) -> np.ndarray:
        """|x_k^n - xbar|^2 + gamma |u_k^n|^2, mean over the paths: (N,)."""
        costs = agent_running_cost(
            outcome.start_positions, outcome.control, self._target, self.params.gamma
        )
        return costs.mean(axis=0)

    def agent_rewards(self, outcome: StepOutcome) -> np.ndarray:
        """-tau/N (|x_k^n - xbar|^2 + gamma |u_k^n|^2), mean over the paths: (N,).

        They add up to `reward(outcome)` (up to round-off). With ``agent_reward="team"`` every
        entry is `reward(outcome)`, the swarm's reward.
        """
        if self.config.agent_reward == "team":
            return np.full(self.n_agents, self.reward(outcome))
        return -(self.dt / self.n_agents) * self.agent_costs(outcome)

    def control_from_action(self, action: Any, name: str = "action") -> np.ndarray:
        """u = max_control * clip(action, -1, 1) as an (N, d) float64 array (in the config's
        ``action_basis``: `agent_envs.envs.interface.controls_from_actions`).

        `action` must have rows d entries, shaped (rows d,) or (rows, d) (rows = N, or 1 for
        ``action_basis="common"``; (N,) for d = 1), of a real
        numeric dtype (`agent_envs.validation.real_array`): strings, bools and complex numbers
        raise `TypeError` (a complex part is never dropped silently); an object array is
        accepted when every entry is an int or a float. A NaN or infinite entry, or an int too
        large for a float, raises `ValueError`; a finite entry outside [-1, 1] is clipped.
        """
        n, d = self.config.params.n_agents, self.config.params.dim
        rows = action_rows(self.config.action_basis, n)
        arr = real_array(name, action)
        if arr.shape not in ((rows * d,), (rows, d)):
            raise ValueError(
                f"{name} must have shape ({rows * d},) or ({rows}, {d}), got {arr.shape}"
            )
        return controls_from_actions(
            arr.reshape(rows, d), self.config.action_basis, self.config.max_control, n
        )


class EpisodeAttributes:
    """Read-only attributes both env adapters expose (`env.unwrapped.params`, ...).

    The adapter provides `self.episode` (a `SwarmEpisode`) and `self.config` (its
    `EpisodeConfig`).
    """

    episode: SwarmEpisode
    config: EpisodeConfig

    @property
    def params(self) -> SwarmParams:
        """SwarmParams of the current episode (target included)."""
        return self.episode.params

    @property
    def model(self) -> SwarmModel:
        """The SwarmModel the integrator and the controllers use."""
        return self.episode.model

    @property
    def max_control(self) -> float:
        """u = max_control * action."""
        return self.config.max_control

    @property
    def n_steps(self) -> int:
        """m, the number of steps of an episode."""
        return self.config.n_steps

    @property
    def n_paths(self) -> int:
        """Brownian paths simulated together."""
        return self.config.n_paths

    @property
    def dt(self) -> float:
        """tau = T / m."""
        return self.episode.dt

    @property
    def integrator_name(self) -> str:
        return self.config.integrator

    @property
    def plan(self) -> StepPlan:
        """Which code a step runs (`agent_envs.envs.step_plan.StepPlan`), resolved when the
        env was made."""
        return self.episode.plan

    @property
    def plan_fallbacks(self) -> Counter[str]:
        """The mid-step fallbacks of this env's steps so far, by kind
        (`agent_envs.envs.step_plan.FALLBACKS`): a `collections.Counter`."""
        return self.episode.fallbacks

    def _plan_repr(self, name: str) -> str:
        """``<Class<name> plan>``: the env's name and its step plan."""
        return f"<{type(self).__name__}<{name}> {self.plan.describe()}>"

    @property
    def jacobian(self) -> str:
        return self.config.jacobian

    @property
    def positions(self) -> np.ndarray | None:
        """(n_paths, N, d) current state (read-only; None before the first reset)."""
        return self.episode.positions

    @property
    def time(self) -> float:
        """t_n = n tau."""
        return self.episode.time

    @property
    def step_index(self) -> int:
        """n, the number of steps taken since reset."""
        return self.episode.step_index

    def _global_observation(self, space: spaces.Box, layout: str = "absolute") -> np.ndarray:
        """The Gymnasium observation vector (= the PettingZoo global state, "absolute") of the
        episode in `layout`."""
        ep = self.episode
        return global_observation(
            ep.mean_positions,
            ep.mean_interaction_drift,
            ep.target,
            ep.time_fraction,
            space,
            layout,
        )
