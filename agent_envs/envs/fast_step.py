"""The native vector env's compiled prologue and epilogue (`agent_envs.native.step`, the
compiled path "step"): the calls around the integrator's step, and their reference check.

`compiled_prologue` turns a batch of actions into the controls, running costs and right-hand
sides F = L(x) x + u in one compiled call; `compiled_epilogue` turns the new state into the
path means, observations and divergence flags in another. `CompiledVectorStep`, a base of
`SwarmVectorEnv`, is the env's step around them (its `_step_compiled`: prologue, draws, the
integrator's fused step, epilogue), taken where its plan's envelope is the compiled step
(`StepPlan.envelope`).

`same_as_numpy` (with `compiled_agents.agents_same_as_numpy` and `combined_same_as_separate`:
`step_path_check`) is registered with the loader (`agent_envs.native.register_check`) when this
module is imported; the loader runs it when the path first loads, when an env that can use it
is made. It checks the module against the numpy calls it replaces, on fixed random data of
several shapes: the controls ("agents" and "common" bases), running costs and right-hand sides
of `prologue` against `controls_from_actions`, `mean_running_cost` and F = L(x) x + u; the path
means, observations and divergence flags of `epilogue` against `arrays.mean_axis`,
`global_observation` and `advance_paths`'s checks, every value bit for bit (signed zeros
included, values the clip cuts), on read-only states as the env passes them. Where numba is
missing or switched off (``AGENT_ENVS_NUMBA=0``) the path is off; where a value differs (a
numpy that sums in another order), or the module does not compile, off with a warning; the env
then steps with its numpy calls.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from agent_envs import arrays, native
from agent_envs.draws import GeneratorHandles, fill_brownian_increments
from agent_envs.envs.compiled_agents import agents_same_as_numpy, combined_same_as_separate
from agent_envs.envs.episode import mean_running_cost
from agent_envs.envs.interface import action_rows, controls_from_actions
from agent_envs.envs.observation import global_observation, observation_space
from agent_envs.integrators.exponential import GAVE_UP
from agent_envs.simulator import diverged_paths

if TYPE_CHECKING:
    from agent_envs.dynamics.linearization_cache import LinearizationCache
    from agent_envs.envs.episode_config import EpisodeConfig
    from agent_envs.envs.step_plan import StepPlan

#: (B, P, N, d) of the load check: one and several paths, N below, at and above numpy's
#: pairwise blocks (8, 128), d = 1, 2, 3 and 9 (a pairwise sum over the coordinates)
CHECK_SHAPES = ((2, 1, 100, 1), (2, 20, 100, 1), (2, 3, 5, 2), (1, 2, 130, 3), (1, 1, 300, 2),
                (2, 1, 1, 1), (1, 9, 17, 9), (1, 1, 8, 1), (1, 1, 128, 2))  # fmt: skip


def compiled_step() -> Any:
    """``native.loaded("step")``: the compiled module (`load_compiled_step` must have answered
    True)."""
    return native.loaded("step")


def load_compiled_step() -> bool:
    """``native.available("step")``: whether the native vector env may take its compiled
    prologue and epilogue (module docstring); loads and checks them on the first call."""
    return native.available("step")


def compiled_prologue(
    module: Any,
    actions: np.ndarray,
    max_control: float,
    x: np.ndarray,
    drift: np.ndarray,
    targets: np.ndarray,
    gamma: float,
    per_agent: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """`module.prologue` (the compiled module): for actions (B, R, d) (C-contiguous), the
    state x (B, P, N, d) and its drift L(x) x, targets (B, d): (controls u (B, N, d), running
    costs (B,), rhs F = L(x) x + u (B, P, N, d)), the numpy step's bits
    (`controls_from_actions`, `mean_running_cost`); None for a non-finite action (the numpy
    step then raises). Given `per_agent` (B, N), the per-agent costs too, in the same call
    (`module.prologue_agents`: `compiled_agents.compiled_agent_costs`'s values)."""
    b, _, d = actions.shape
    n = x.shape[-2]
    controls, costs, rhs = np.empty((b, n, d)), np.empty(b), np.empty(x.shape)
    args = (actions, max_control, x, drift, targets, gamma, controls, costs, rhs)
    if not (
        module.prologue(*args) if per_agent is None else module.prologue_agents(*args, per_agent)
    ):
        return None
    return controls, costs, rhs


def compiled_epilogue(
    module: Any,
    x_next: np.ndarray,
    drift_next: np.ndarray,
    threshold: float,
    targets: np.ndarray,
    fractions: np.ndarray,
    bounds: tuple[np.ndarray, np.ndarray],
    absolute: bool,
    agent_rows: tuple[tuple[np.ndarray, np.ndarray], bool, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`module.epilogue`: for the new state x_next (B, P, N, d) and its drift (C-contiguous),
    the divergence threshold, targets (B, d), time fractions (n + 1) / m (B,) and the
    observation space's (low, high) (float32): (E x (B, N, d), E drift (B, N, d), the
    "absolute" observations (B, obs) float32 (meaningless unless `absolute`), diverged (B,)),
    the numpy step's bits (`arrays.mean_axis`, `global_observation`, `advance_paths`'s
    checks). Given `agent_rows` ((low, high) of the agent space, relative, out (B, N, 3 d + 1)
    float32), the PettingZoo rows of the path means into out too, in the same call
    (`module.epilogue_agents`: `compiled_agents.compiled_agent_rows`'s values)."""
    b, _, n, d = x_next.shape
    low, high = bounds
    mean_positions, mean_drift = np.empty((b, n, d)), np.empty((b, n, d))
    observations = np.empty((b, low.shape[0]), dtype=np.float32)
    diverged = np.empty(b, dtype=np.bool_)
    args = (x_next, drift_next, threshold, targets, fractions, low, high, absolute,
            mean_positions, mean_drift, observations, diverged)  # fmt: skip
    if agent_rows is None:
        module.epilogue(*args)
    else:
        (agent_low, agent_high), relative, rows = agent_rows
        module.epilogue_agents(*args, agent_low, agent_high, relative, rows)
    return mean_positions, mean_drift, observations, diverged


class CompiledVectorStep:
    """The native vector env's step on its plan's compiled envelope (`StepPlan.envelope`
    "compiled-step" or "compiled-step+numpy-tail"): a base of `SwarmVectorEnv`, which provides
    the attributes below and the numpy step's `_advance`, `_finish_step`, `_state_info`."""

    num_envs: int
    config: EpisodeConfig
    plan: StepPlan
    model: LinearizationCache
    integrator: Any
    plan_fallbacks: Counter[str]
    np_randoms: list[Any]
    step_index: np.ndarray
    dt: float
    times: np.ndarray
    _positions: Any
    _mean_drift: Any
    _targets: Any
    _all_rows: np.ndarray
    _observation_bounds: tuple[np.ndarray, np.ndarray]
    _autoreset: np.ndarray
    _advance: Callable[..., tuple[Any, Any, Any]]
    _finish_step: Callable[..., tuple[Any, ...]]
    _state_info: Callable[..., dict[str, Any]]
    _generator_handles: Callable[[], GeneratorHandles]

    def _step_compiled(self, actions: Any) -> tuple[Any, ...] | None:
        """`step` for the common case, where every env steps (no autoreset in this call) and
        the actions are a float32 or float64 numpy array of shape (B, R d) or (B, R, d) (R = N,
        or 1 for the "common" basis), from the state whose L(x) the model keeps: the controls,
        running costs and right-hand sides in one compiled call (`compiled_prologue`), the
        draws, the integrator's fused step (or Euler-Maruyama's update and the kernel pass),
        and the divergence flags, path means and observation in another compiled call
        (`compiled_epilogue`), the same values bit for bit as the numpy step, which is about
        30 numpy calls over the batch (tests/test_fast_step.py). None, before any draw, where
        it does not apply (the numpy step then runs, and raises for bad actions); a fused step
        that gives up or does not apply takes the numpy step's `_advance` with the same draws
        (counted in `plan_fallbacks`). Runs where the plan's envelope is the compiled step
        (`StepPlan`: numpy, one block, every pass member by member, SERB or ERB on the fused
        step or Euler-Maruyama, the "agents" or "common" action basis, the path "step"
        available)."""
        b, spec, params = self.num_envs, self.config.simulation, self.config.params
        rows = action_rows(self.config.action_basis, params.n_agents)
        if (
            type(actions) is not np.ndarray
            or actions.dtype not in (np.float32, np.float64)
            or actions.shape not in ((b, rows * params.dim), (b, rows, params.dim))
        ):
            return None
        model, x = self.model, self._positions
        cached = model.cached_linearization(x)
        if cached is None or not (x.flags.c_contiguous and cached[1].flags.c_contiguous):
            return None
        operator, drift = cached
        module = native.loaded("step")
        if module is False:  # (the path "step" switched off after the env was made)
            return None
        a = np.ascontiguousarray(actions).reshape(b, rows, params.dim)
        found = compiled_prologue(
            module, a, spec.max_control, x, drift, self._targets, params.gamma
        )
        if found is None:
            return None  # (non-finite actions: the numpy step raises)
        controls, costs, rhs = found
        dw = fill_brownian_increments(
            self.np_randoms, self._all_rows, np.empty(x.shape), self.dt, self._generator_handles()
        )
        x_next = self._compiled_advance(operator, rhs, x, model.sigma * dw)
        every = self._all_rows >= 0  # (B,) True
        if x_next is None or x_next is GAVE_UP:
            if x_next is None:  # (GAVE_UP: counted by the model, `discard_linearization`)
                self.plan_fallbacks["fused-declined"] += 1
            # the fused step did not apply (say the compiled Lanczos switched off) or a
            # member's Lanczos gave up (its workspace discarded): the numpy step's advance
            # with the same draws (where it gave up, the integrator's general path tries the
            # fused step once more before its own phi-action: a rare step's cost, not bits)
            with arrays.hot_path_threads():
                x_next, drift_next, diverged = self._advance(
                    x, controls, self.times[:, None, None, None], dw
                )
            return self._finish_step(x, x_next, drift_next, diverged, controls, costs, every)
        drift_next = model.cached_linearization(x_next)[1]
        x_next, drift_next = np.ascontiguousarray(x_next), np.ascontiguousarray(drift_next)
        absolute = self.config.observation == "absolute"
        _, mean_drift, observations, diverged = compiled_epilogue(
            module, x_next, drift_next, self.config.divergence_threshold, self._targets,
            (self.step_index + 1) / spec.n_steps, self._observation_bounds, absolute,
        )  # fmt: skip
        numpy_tail = self.plan.envelope != "compiled-step"  # (not "absolute", or SAME_STEP)
        if numpy_tail or diverged.any():
            if not numpy_tail:
                self.plan_fallbacks["numpy-tail"] += 1
            if not absolute:
                observations = None  # (the numpy observation of the state the step leaves)
            return self._finish_step(
                x, x_next, mean_drift, diverged, controls, costs, every, observations
            )
        # `_finish_step` where every env stepped and moved (NEXT_STEP autoresets): the same
        # arrays with fewer passes over them
        self._positions, self._mean_drift = x_next, mean_drift
        self.step_index += 1
        truncated = self.step_index >= spec.n_steps
        info = self._state_info(controls, costs)
        self._autoreset = truncated.copy()
        return observations, -self.dt * costs, diverged, truncated, info

    def _compiled_advance(self, operator: Any, rhs: Any, x: Any, noise: Any) -> Any:
        """x^{n+1} of the compiled step from x with rhs F(x, u) and noise sigma dW: the
        integrator's fused step (None or `GAVE_UP` where it does not apply or gives up), or
        Euler-Maruyama's x + dt F + sigma dW and the kernel pass at x^{n+1} (its L(x^{n+1})
        then kept by the model)."""
        if self.plan.fused:  # (compiled: no numpy warnings to silence)
            return self.integrator.fused_step(self.model, operator, rhs, x, self.dt, noise)
        with np.errstate(over="ignore", invalid="ignore"):
            x_next = x + self.dt * rhs + noise
            x_next.flags.writeable = False
            self.model.interaction_drift(x_next)
        return x_next


def _same_bits(a: np.ndarray, b: Any) -> bool:
    b = np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def same_as_numpy(
    module: Any, shapes: tuple[tuple[int, int, int, int], ...] = CHECK_SHAPES
) -> bool:
    """Whether `module.prologue` and `module.epilogue` give the numpy step's values bit for bit
    on fixed random data of `shapes` (B, P, N, d), actions float32 and float64, states over
    six orders of magnitude, and one env beyond the divergence threshold."""
    rng = np.random.default_rng(20261127)
    for b, p, n, d in shapes:
        scale = 10.0 ** rng.uniform(-3, 3, (b, p, n, d))
        x = rng.standard_normal((b, p, n, d)) * scale
        drift = rng.standard_normal((b, p, n, d)) * scale
        x.flat[:2] = (-0.0, 0.0)  # signed zeros, and below, means the clip cuts
        drift.flat[-2:] = (-0.0, 0.0)
        x.flat[2::7] *= 1e4
        drift.flat[3::5] *= 1e3
        # read-only, as the env passes its state and drift (numba compiles read-only arrays
        # apart: this checks the machine code the env runs)
        x.flags.writeable = False
        drift.flags.writeable = False
        targets = rng.standard_normal((b, d))
        for dtype in (np.float32, np.float64):
            actions = rng.uniform(-2.0, 2.0, (b, n, d)).astype(dtype)
            actions[0, 0, 0] = -0.0
            controls, costs, rhs = np.empty((b, n, d)), np.empty(b), np.empty(x.shape)
            # the "agents" basis (a row per agent) and the "common" one (one row for all)
            for given, basis in ((actions, "agents"), (actions[:, :1].copy(), "common")):
                if not module.prologue(given, 25.0, x, drift, targets, 0.37, controls, costs,
                                       rhs):  # fmt: skip
                    return False
                want_u = controls_from_actions(given.astype(np.float64), basis, 25.0, n)
                if not (
                    _same_bits(controls, want_u)
                    and _same_bits(costs, mean_running_cost(x, want_u, targets, 0.37))
                    and _same_bits(rhs, drift + want_u[:, None])
                ):
                    return False
        bad = np.array(actions)
        bad[-1, -1, -1] = np.nan
        if module.prologue(bad, 25.0, x, drift, targets, 0.37, controls, costs, rhs):
            return False
        x_next = np.array(x)
        x_next[-1, -1, -1, -1] = 1e7  # beyond the threshold below: that env diverged
        x_next.flags.writeable = False
        fractions = rng.uniform(0.0, 1.0, b)
        fractions[0] = -0.0  # a tie with the time slot's bound 0.0: np.clip gives +0.0
        for threshold in (1e6, np.inf):
            # bounds the means cross (positions up to 1e7, drift up to 3e6): the clip cuts
            space = observation_space(n, d, min(threshold, 1e6), 1e5)
            means = np.empty((b, n, d)), np.empty((b, n, d))
            obs = np.empty((b, *space.shape), dtype=np.float32)
            flags = np.empty(b, dtype=np.bool_)
            module.epilogue(x_next, drift, threshold, targets, fractions, space.low, space.high,
                            True, *means, obs, flags)  # fmt: skip
            want_x, want_f = arrays.mean_axis(x_next, -3), arrays.mean_axis(drift, -3)
            want_obs = global_observation(want_x, want_f, targets, fractions, space)
            want_flags = np.any(diverged_paths(x_next, threshold), axis=-1) | ~np.all(
                np.isfinite(want_f), axis=(-2, -1)
            )
            if not (
                _same_bits(means[0], want_x)
                and _same_bits(means[1], want_f)
                and _same_bits(obs, want_obs)
                and _same_bits(flags, want_flags)
            ):
                return False
    return True


def step_path_check(module: Any) -> bool:
    """The load check of the path "step": `same_as_numpy` (the prologue and epilogue),
    `compiled_agents.agents_same_as_numpy` (the PettingZoo env's per-agent costs and rows) and
    `compiled_agents.combined_same_as_separate` (the two in one call each)."""
    return (
        same_as_numpy(module) and agents_same_as_numpy(module) and combined_same_as_separate(module)
    )


native.register_check("step", step_path_check, "the envs step with numpy calls")
