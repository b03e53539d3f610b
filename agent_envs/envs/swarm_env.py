"""Gymnasium adapter `agent_envs/Swarm-v0`: one controller sets every agent's control.

The numerics live in `agent_envs.envs.episode.SwarmEpisode`; this module turns it into a
`gymnasium.Env` (spaces, seeding, `info`, rendering) and provides the registered entry point
`make_swarm_env`, which adds the `TimeLimit` of the episode's own m = `n_steps`.
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from agent_envs import native
from agent_envs.envs.attributes import EpisodeAttributes
from agent_envs.envs.compiled_episode import CompiledOutcome, compiled_episode_step
from agent_envs.envs.episode import SwarmEpisode
from agent_envs.envs.episode_config import EpisodeConfig, reset_options
from agent_envs.envs.interface import action_rows
from agent_envs.envs.observation import (
    global_observation,
    interaction_drift_bound,
    observation_space,
)
from agent_envs.envs.rendering import SwarmRenderer, check_render_mode
from agent_envs.validation import check_seed

ENV_ID = "agent_envs/Swarm-v0"


class SwarmEnv(EpisodeAttributes, gym.Env[np.ndarray, np.ndarray]):
    r"""Drive a stochastic, possibly stiff swarm of N agents to a target at least cost.

    ## Description

    N agents x_k in R^d follow the controlled SDE of the paper (`eq:dynamics`)

        dx_k = ( (1/N) sum_l p(x_k, x_l)(x_l - x_k) + u_k ) dt + sigma dW_k,

    with the Cucker-Smale kernel p(x, y) = 1/(eps (alpha^2 + |x - y|^2)) (`eq:symmker`; small
    eps makes the interaction stiff) or its non-symmetric version with eps_l linear in l from
    eps_min to eps_max (`eq:nonsymmker`). One step of the env is one step tau = T/m of the
    chosen integrator ("serb", the stochastic exponential Rosenbrock-Euler scheme of
    `eq:serb`, by default), with the control u held fixed over the step. `n_paths` Brownian
    paths start from the same positions and are driven by the same control; the expectations
    of the problem are means over these paths. The goal is the fully discrete control problem
    `eq:discrete_cost_functional`:

        minimize  tau sum_{n=0}^{m-1} E[ (1/N) sum_k |x_k^n - xbar|^2 + gamma |u_k^n|^2 ].

    ## Action Space

    `Box(-1, 1, (N d,), float32)`, agent-major (entry k d + i is coordinate i of agent k).
    The control is u = max_control * clip(action, -1, 1), reshaped (N, d): an action outside
    [-1, 1] is clipped (not an error); a NaN or infinite entry, or a shape other than (N d,) or
    (N, d), raises `ValueError`. Actions must have a real numeric dtype (ints or floats):
    strings, bools and complex numbers raise `TypeError` (an imaginary part is never dropped);
    an object array is accepted when every entry is an int or a float. The default
    `max_control = 150` leaves the paper's turnpike cheap control (`eq:cheap_ctr`, beta = 12,
    N = 100, m = 50) unclipped: `benchmarks/max_control.py` measures its largest |u_k^n| (the
    figures are on the docs page "Environments > Gymnasium", "Why max_control = 150").

    ## Observation Space

    `Box((2 N d + d + 1,), float32)`, (N, d) blocks flattened agent-major:

    | slice                  | content                                                      |
    |------------------------|--------------------------------------------------------------|
    | [0, N d)               | E x_k, the agents' positions (mean over the paths)          |
    | [N d, 2 N d)           | E (1/N) sum_l p(x_k, x_l)(x_l - x_k), the interaction drift |
    | [2 N d, 2 N d + d)     | the target xbar                                              |
    | 2 N d + d              | t / T, the elapsed fraction of the horizon                   |

    Bounds: positions and target in [-divergence_threshold, divergence_threshold], drift in
    [-mean(1/eps)/(2 alpha), mean(1/eps)/(2 alpha)], t/T in [0, 1]. Use
    `agent_envs.envs.observation.split_observation(obs, N, d)` to take it apart (batched over
    leading axes, VecEnv observations included). With it the turnpike control is
    u = beta (xbar - E x) - E drift.

    ## Rewards

    r^n = -tau c(x^n, u^n), with the running cost of `eq:running_cost`

        c(x, u) = (1/N) sum_k ( |x_k - xbar|^2 + gamma |u_k|^2 )

    taken at the state x^n at the *start* of the step (left rectangle rule) and averaged over
    the paths. So the rewards of an episode add up to minus the discrete cost functional
    `eq:discrete_cost_functional` estimated on the env's paths:
    sum_n r^n = -agent_envs.costs.discrete_cost(positions, controls, xbar, gamma, tau).mean()
    (tested to 1e-12).

    ## Starting State

    Positions drawn uniform on [-1, 1]^d from `self.np_random` (the paper's start), the same
    for every path. `reset(options={"initial_positions": x0})` with x0 of shape (N,) (d = 1) or
    (N, d) replaces them, and `options={"target": xbar}` replaces the target for the episode.
    The uniform draw is made either way, so the Brownian increments of a seeded episode do not
    depend on the options. Any other option key raises `ValueError` (a typo never passes
    silently). `reset(seed=s)` takes an int in [0, 2**32 - 1]; bools, floats, strings and
    negative ints are rejected with a named error.

    ## Episode End

    - Truncation: after m = `n_steps` steps (t = T), `truncated=True`. `gym.make` adds a
      `TimeLimit(n_steps)` as well, so `env.spec.max_episode_steps == n_steps` for any
      `n_steps`.
    - Termination: if a step makes some path non-finite or leave
      [-divergence_threshold, divergence_threshold] (e.g. Euler-Maruyama on a stiff kernel),
      `terminated=True` and `info["diverged"] = True`. The env keeps the last finite state
      x^n and time t_n, returns it as the observation and in `info["positions"]`, and the
      reward -tau c(x^n, u^n) is finite: nothing is NaN. With n_paths > 1 one diverging path
      ends the episode.

    ## Info

    `positions` (n_paths, N, d) after the step, `control` (N, d) the applied u,
    `time` the time after the step, `running_cost` c(x^n, u^n), `diverged` (bool).
    `reset` returns the same keys (clients such as TorchRL build their specs from the reset
    info): `positions`, `control` (zeros: nothing applied yet), `time` (0.0), `running_cost`
    (0.0: nothing accrued yet) and `diverged` (False).

    ## Rendering

    `render_mode="rgb_array"` returns uint8 (H, W, 3) frames, `"human"` draws in a pyplot
    window (nothing with a non-interactive backend). d = 1 plots every agent's path-mean
    position against time with the target as a dashed line; d >= 2 a scatter of the first two
    coordinates. An env that has rendered can be pickled and deep-copied (the copy draws a new
    figure).

    ## Arguments

    Every keyword argument, its default and the values it accepts:

    | kwarg | default | meaning | accepted |
    |---|---|---|---|
    | n_agents | 100 | N | int in [2, 1e7] |
    | dim | 1 | d | int >= 1, N d <= 1e7 |
    | kernel | "symmetric" | p(x, y): `eq:symmker` or `eq:nonsymmker` | those two, or an object |
    | alpha | 0.1 | kernel length scale | [1e-6, 1e6] |
    | epsilon | 0.05 | symmetric kernel stiffness (small = stiff) | [1e-12, 1e12] |
    | epsilon_min, _max | 0.01, 0.1 | non-symmetric kernel's eps_l | [1e-12, 1e12], min <= max |
    | sigma | 0.01 | noise level | [0, 1e6] |
    | horizon | 1.0 | T | [1e-6, 1e6] |
    | target | 0.7 | xbar, scalar or length-d sequence | in [-1e6, 1e6], \|xbar\| < R |
    | gamma | 0.01 | control weight of the running cost | [0, 1e6] |
    | integrator | "serb" | the scheme of one step | "em", "ee", "heun", "erb", "serb" |
    | jacobian | "frozen" | linearization of erb/serb | "frozen" (L(x)), "exact" (dF/dx) |
    | phi_method | "auto" | phi-function actions | "auto", "expm", "eigh", "krylov" |
    | linear_operator | "auto" | N x N matrices or kernel sums | "auto", "dense", "matrix_free" |
    | n_steps | 50 | m; tau = T / m; the episode length | int in [1, 1e9] |
    | n_paths | 1 | Brownian paths under one control | int in [1, 1e6], n_paths N d <= 1e8 |
    | max_control | 150.0 | u = max_control * clip(action, -1, 1) | (0, 1e6] |
    | divergence_threshold | 1e4 | R: max \|x\| before a step diverges | [1, 1e6] |
    | observation | "absolute" | layout (Env options) | "absolute", "relative", "modes", "summary" |
    | action_basis | "agents" | action -> u (Env options) | "agents", "modes", "common" |
    | agent_reward | "own" | PettingZoo's per-agent reward | "own" here (PettingZoo: also "team") |
    | neighbours | None | K of PettingZoo's "local" layout | none here (PettingZoo: [1, 1024]) |
    | render_mode | None | see Rendering | None, "rgb_array", "human" |
    | num_threads | 1 | threads of the compiled passes over the paths | int in [1, numba's] |

    ## Env options (the learner's interface)

    `observation` and `action_basis` change what a learner sees and moves, never the dynamics,
    the cost or the random draws (`agent_envs.envs.interface`; docs page "Env options").
    Observation: "relative" puts E x_k - xbar in the first block; "modes" puts the
    centre-and-differences coordinates of E x - xbar and of the drift in the first two blocks
    (entry 0: the centre's offset from the target); "summary" is `Box((3 d + 1,))`: the centre's
    offset, the spread sqrt(mean_k (x_k - c)^2), xbar, t / T. Action: "modes" reads the action
    as those coordinates (entry 0 moves every agent alike, over the whole control range);
    "common" is `Box(-1, 1, (d,))`, one control max_control * clip(a, -1, 1) for every agent.

    The defaults are the paper's stiff setting. A kernel object has `value`, `grad_x`,
    `grad_y` and `symmetric` and answers in the library of its input (numpy or torch; docs page
    "Numerical core", "Your own kernel"). `linear_operator="auto"` is matrix-free for
    numpy states with the Cucker-Smale kernel when d = 1 and N >= 1000 or d = 2 and N >= 2000,
    or whenever the dense matrices of a step would exceed 2 GiB; dense otherwise (docs page
    "Large swarms"). Bad values raise `ValueError`/`TypeError` naming the argument and its
    accepted range: numbers must be ints or floats (numpy's included; bools, strings, complex
    numbers and None are rejected), finite, and in the range above (an int too large for a
    float is a `ValueError`, not an `OverflowError`). `agent_envs.validation` derives the ranges
    so that every accepted combination gives finite rewards and observations inside the
    spaces. The dense kernel matrix needs n_paths N^2 entries per step; that memory is not
    capped. An unknown keyword raises Python's own
    `TypeError("SwarmEnv.__init__() got an unexpected keyword argument 'x'")`.

    `num_threads` (needs numba, the `fast` extra) runs the compiled passes of a step over the
    env's n_paths systems (the kernel pass; SERB's or ERB's fused step with the frozen Jacobian)
    on that many of numba's threads: the same results bit for bit, faster where n_paths is large
    (the paper's 20 paths). No effect with one path, with the matrix-free operator (large N),
    or, for the fused step, where the phi-action is not the Lanczos (N below about 49). It
    changes no dynamics and is not part of the episode's configuration;
    `agent_envs.envs.vector_env.SwarmVectorEnv` ("Threads") says more.

    ## Attributes (on `env.unwrapped`)

    params, model, max_control, n_steps, n_paths, dt, integrator_name, jacobian, positions
    (n_paths, N, d), time, step_index, episode (the shared `SwarmEpisode`), num_threads, plan
    (the `StepPlan`: which code a step runs, resolved when the env is made; `repr(env.unwrapped)`
    shows it), plan_fallbacks (a `Counter` of the mid-step fallbacks so far).

    ## Version History

    - v0: the only version. Within v0 the dynamics, spaces and rewards have not changed;
      added since the first release: range checks on every argument and real-dtype actions,
      the reset info with the step's keys, the `reset` option check, the native vector env
      as `vector_entry_point`, `linear_operator` (matrix-free large swarms), and the env
      options `observation` and `action_basis` (defaults unchanged). The
      integrators' round-off changed once (the Array API core with Lanczos phi-actions), which
      moves trained policies' results, not the references' (docs page "Changelog").
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["human", "rgb_array"], "render_fps": 10}

    def __init__(self, render_mode: str | None = None, num_threads: int = 1, **kwargs: Any) -> None:
        self.config = EpisodeConfig.from_kwargs(
            f"{type(self).__name__}.__init__", env_kind="gymnasium", **kwargs
        )
        threads = native.check_compiled_threads(num_threads, "num_threads")
        self.episode = SwarmEpisode(self.config, "gymnasium", threads)
        self.render_mode = check_render_mode(render_mode)
        params = self.config.params
        n, d = params.n_agents, params.dim
        rows = action_rows(self.config.action_basis, n)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(rows * d,), dtype=np.float32)
        self.observation_space = observation_space(
            n,
            d,
            self.config.divergence_threshold,
            interaction_drift_bound(self.episode.model.kernel),
            self.config.observation,
        )
        self._renderer = (
            None
            if self.render_mode is None
            else SwarmRenderer(self.render_mode, params.horizon, self.metadata["render_fps"])
        )
        # the compiled step's constants (`compiled_episode_step`)
        self._compiled_step = self.plan.compiled_step
        self._observation_bounds = (self.observation_space.low, self.observation_space.high)
        self._absolute = self.config.observation == "absolute"

    def __repr__(self) -> str:
        # (str(env) stays Gymnasium's "<SwarmEnv<id>>", which the wrappers print)
        return self._plan_repr(ENV_ID if self.spec is None else self.spec.id)

    @property
    def num_threads(self) -> int:
        """Threads of the compiled passes over the env's paths (its model's `threads`)."""
        return self.episode.model.threads

    # ------------------------------------------------------------------ API
    def _observation(self) -> np.ndarray:
        return self._global_observation(self.observation_space, self.config.observation)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=check_seed(seed))
        if self.num_threads > 1:
            # the threaded passes' one-time load (it starts numba's threads) falls in the first
            # reset, not in the constructor: Gymnasium's AsyncVectorEnv makes an env in the
            # parent to read its spaces and then forks, and a fork after GNU OpenMP started
            # terminates the children that use it
            native.load_compiled_threads(self.num_threads)
        self.episode.reset(self.np_random, **reset_options(options, strict=True))
        if self._renderer is not None:
            self._renderer.reset(0.0, self.episode.mean_positions, self.episode.target)
            if self.render_mode == "human":
                self.render()
        info = {
            "positions": self.episode.positions.copy(),
            "control": np.zeros((self.episode.n_agents, self.episode.dim)),
            "time": 0.0,
            "running_cost": 0.0,
            "diverged": False,
        }
        return self._observation(), info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        episode = self.episode
        found = None
        if self._compiled_step:  # the plan's compiled envelope (`compiled_episode_step`)
            found = compiled_episode_step(
                episode, self.np_random, action, self._observation_bounds, self._absolute
            )
            if found is None:
                episode.fallbacks["compiled-step-declined"] += 1
        if found is None:
            outcome = episode.step(self.np_random, episode.control_from_action(action))
            observation = None
        else:
            outcome, observation = found.outcome, self._compiled_observation(found)
        if self._renderer is not None and not outcome.diverged:
            self._renderer.record(episode.time, episode.mean_positions)
            if self.render_mode == "human":
                self.render()
        info = {
            "positions": episode.positions.copy(),
            "control": outcome.control,
            "time": episode.time,
            "running_cost": outcome.running_cost,
            "diverged": outcome.diverged,
        }
        if observation is None:
            observation = self._observation()
        reward = float(-episode.dt * outcome.running_cost)  # (`SwarmEpisode.reward`)
        return observation, reward, outcome.diverged, outcome.truncated, info

    def _compiled_observation(self, found: CompiledOutcome) -> np.ndarray | None:
        """The observation after a compiled step: the epilogue's ("absolute"), the layout's
        from its path means, or None (a diverged or general step: `_observation`)."""
        if found.observation is not None or found.mean_positions is None:
            return found.observation
        ep = self.episode
        return global_observation(
            found.mean_positions, ep._mean_drift, ep._target, ep.time_fraction,
            self.observation_space, self.config.observation,
        )  # fmt: skip

    def render(self) -> np.ndarray | None:
        if self._renderer is None:
            gym.logger.warn(
                "You are calling render method without specifying any render mode. "
                f'You can specify the render_mode at initialization, e.g. gym.make("{ENV_ID}", '
                'render_mode="rgb_array")'
            )
            return None
        return self._renderer.render()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()


def make_swarm_env(**kwargs: Any) -> gym.Env:
    """Entry point of `agent_envs/Swarm-v0`: `SwarmEnv(**kwargs)` in a `TimeLimit(n_steps)`.

    The horizon m = `n_steps` is a keyword argument, so a fixed `max_episode_steps` in the
    registration would be wrong for every other m (too short above it). The id is therefore
    registered without one and this entry point adds `TimeLimit(env, env.n_steps)`: episodes
    last exactly `n_steps` steps and `gym.make(...).spec.max_episode_steps == n_steps`. The
    env itself also truncates at `n_steps` (it cannot step past t = T), so both agree.
    """
    env = SwarmEnv(**kwargs)
    return gym.wrappers.TimeLimit(env, max_episode_steps=env.n_steps)


# gym.make reads the render modes from the entry point's metadata.
make_swarm_env.metadata = SwarmEnv.metadata  # type: ignore[attr-defined]
