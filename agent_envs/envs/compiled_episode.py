"""The single envs' step on the compiled envelope: `SwarmEpisode.step` in three compiled calls.

Where the episode's plan says so (`StepPlan.envelope` "compiled-step" or
"compiled-step+numpy-tail" for a single env: `step_plan.resolve_step_plan`), the Gymnasium
and the PettingZoo env step one episode of P paths (x^n of shape (P, N, d)) with the native
vector env's compiled prologue and epilogue (`agent_envs.envs.fast_step`, the compiled path
"step") around the integrator's fused step, as a batch of one env (B = 1)::

    u^n, c(x^n, u^n), F = L(x^n) x^n + u^n      compiled_prologue (from the action)
    dW^n ~ N(0, tau I) (P, N, d)                  the env's generator, as `brownian_increments`
    x^{n+1}                                       the integrator's fused step (SERB/ERB on
                                                  the Lanczos) or its own step (numpy)
    E x^{n+1}, E L(x^{n+1}) x^{n+1}, diverged,    compiled_epilogue
    the "absolute" observation

The PettingZoo env asks for its per-agent costs and observation rows in the prologue's and
the epilogue's calls (`compiled_agents.AgentOutputs`: `prologue_agents`, `epilogue_agents`).

These are the numpy step's values bit for bit (`fast_step.same_as_numpy` checks the two
compiled calls when the path loads; tests/test_compiled_episode.py checks whole episodes). The
call returns None, before any draw, wherever it does not apply (an action that is not a
float32/float64 numpy array of the action's shape, or not finite; a state whose L(x) the model
does not keep; the path "step" switched off after the env was made): the numpy step
(`SwarmEpisode.step`) then runs and validates as before. A fused step that does not apply
or gives up takes the integrator's general step with the same draws (counted in the env's
``plan_fallbacks``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from agent_envs import arrays, native
from agent_envs.envs.compiled_agents import AgentOutputs
from agent_envs.envs.episode import StepOutcome, advance_paths, checked_advance
from agent_envs.envs.fast_step import compiled_epilogue, compiled_prologue
from agent_envs.integrators.exponential import GAVE_UP

if TYPE_CHECKING:
    from agent_envs.envs.episode import SwarmEpisode

_FLOATS = (np.dtype(np.float32), np.dtype(np.float64))  # (dtypes: `in` compares no types)


class CompiledOutcome(NamedTuple):
    """What one compiled episode step did: the `StepOutcome`, and (where the step did not
    diverge) the path means E x^{n+1} (N, d) and, for the "absolute" layout, the observation
    (2 N d + d + 1,) float32 (None otherwise: the adapter builds its layout from the means).
    Where `AgentOutputs` were asked: the per-agent costs (N,) of x^n and u^n, and (with their
    bounds, where the means are given) the agent observation rows (N, 3 d + 1) float32."""

    outcome: StepOutcome
    mean_positions: np.ndarray | None
    observation: np.ndarray | None
    agent_costs: np.ndarray | None = None
    agent_rows: np.ndarray | None = None


def compiled_episode_step(
    episode: SwarmEpisode,
    rng: np.random.Generator,
    action: Any,
    bounds: tuple[np.ndarray, np.ndarray],
    absolute: bool,
    agents: AgentOutputs | None = None,
) -> CompiledOutcome | None:
    """One step of `episode` from the raw `action` (rows d entries, (rows d,) or (rows, d);
    rows = N, or 1 for the "common" basis) on the compiled envelope (module docstring), or
    None before any draw where it does not apply. `bounds` are the Gymnasium observation
    space's (low, high) (2 N d + d + 1,) float32 (the global state's, for the PettingZoo env);
    `absolute` asks for that observation, `agents` for the PettingZoo env's per-agent outputs
    in the same compiled calls (`CompiledOutcome`)."""
    if type(action) is not np.ndarray or action.dtype not in _FLOATS:
        return None
    shapes, rows, d = episode.action_shapes
    x = episode.positions
    if action.shape not in shapes or x is None or episode.done:
        return None
    model = episode.model
    cached = model.cached_linearization(x)
    module = native.loaded("step")
    if cached is None or module is False or not x.flags.c_contiguous:
        return None
    operator, drift = cached
    spec, params = episode.config.simulation, episode.params
    targets = episode.targets
    if not action.flags.c_contiguous:
        action = np.ascontiguousarray(action)
    per_agent = None if agents is None else np.empty((1, x.shape[-2]))
    found = compiled_prologue(
        module,
        action.reshape(1, rows, d),
        spec.max_control,
        x[None],
        drift[None],
        targets,
        params.gamma,
        per_agent,
    )
    if found is None:
        return None  # (a non-finite action: the numpy step raises)
    controls, costs, rhs = found
    control = controls[0]
    dw = rng.standard_normal(x.shape)  # `brownian_increments`: the same draws and bits
    dw *= np.sqrt(episode.dt)
    rhs = rhs.reshape(x.shape)
    rhs.flags.writeable = False  # (read-only: the fused step's compiled call takes it as is)
    x_next = _advance(episode, operator, rhs, x, control, dw)
    agent_costs = None if per_agent is None else per_agent[0]
    if x_next is None or x_next is GAVE_UP:
        found = _general_advance(episode, x, control, costs, dw, x_next is GAVE_UP)
        return found._replace(agent_costs=agent_costs)
    cached_next = model.cached_linearization(x_next)
    if cached_next is None or not (x_next.flags.c_contiguous and cached_next[1].flags.c_contiguous):
        found = _numpy_tail(episode, x, x_next, control, costs)  # (not expected: no such step)
        return found._replace(agent_costs=agent_costs)
    agent_rows = None
    if agents is not None and agents.bounds is not None:
        agent_rows = (
            agents.bounds,
            agents.relative,
            np.empty((1, x.shape[-2], 3 * d + 1), np.float32),
        )
    means, mean_drift, observations, diverged = compiled_epilogue(
        module,
        x_next[None],
        cached_next[1][None],
        episode.config.divergence_threshold,
        targets,
        np.array([(episode.step_index + 1) / spec.n_steps]),
        bounds,
        absolute,
        agent_rows,
    )
    cost = float(costs[0])
    if diverged[0]:
        episode.diverged = True
        if episode.plan.envelope == "compiled-step":  # (the numpy observation of x^n follows)
            episode.fallbacks["numpy-tail"] += 1
        outcome = StepOutcome(x, control, cost, True, False)
        return CompiledOutcome(outcome, None, None, agent_costs)
    episode.positions, episode._mean_drift = x_next, mean_drift[0]
    episode.step_index += 1
    truncated = episode.step_index >= spec.n_steps
    outcome = StepOutcome(x, control, cost, False, truncated)
    rows_found = None if agent_rows is None else agent_rows[2][0]
    observation = observations[0] if absolute else None
    return CompiledOutcome(outcome, means[0], observation, agent_costs, rows_found)


def _advance(episode: SwarmEpisode, operator: Any, rhs: Any, x: Any, control: Any, dw: Any) -> Any:
    """x^{n+1} from x (P, N, d) under the control u (N, d) with F(x, u) = `rhs` and the draws
    dW: the integrator's fused step (None or `GAVE_UP` where it does not apply or gives up),
    or its own `step` (the numpy step's call: any scheme, any phi-action) and the kernel pass
    at x^{n+1} (its L(x^{n+1}) then kept by the model for the epilogue and the next step)."""
    model, integrator, dt = episode.model, episode.integrator, episode.dt
    if episode.plan.fused:
        noise = model.sigma * dw
        noise.flags.writeable = False
        return integrator.fused_step(model, operator, rhs, x, dt, noise)
    with np.errstate(over="ignore", invalid="ignore"):
        with arrays.hot_path_threads():
            x_next = integrator.step(model, x, control[None], episode.time, dt, dw)
        x_next.flags.writeable = False
        model.interaction_drift(x_next)
    return x_next


def _general_advance(
    episode: SwarmEpisode,
    x: np.ndarray,
    control: np.ndarray,
    costs: np.ndarray,
    dw: np.ndarray,
    gave_up: bool,
) -> CompiledOutcome:
    """The rest of the step where the fused step did not apply (`advance_paths`: the
    integrator's step, which counts "fused-declined") or gave up (counted "fused-gave-up" by
    the model: the integrator's general step, as its own `step` takes it then), with the same
    draws dW; the numpy step's state update and outcome."""
    t, dt, threshold = episode.time, episode.dt, episode.config.divergence_threshold
    with arrays.hot_path_threads():
        if gave_up:
            with np.errstate(over="ignore", invalid="ignore"):
                x_next = episode.integrator.general_step(
                    episode.model, x, control[None], t, dt, episode.model.sigma * dw
                )
            return _numpy_tail(episode, x, x_next, control, costs)
        found = advance_paths(episode.integrator, episode.model, x, control, t, dt, dw, threshold)
    return _finish(episode, x, control, costs, *found)


def _numpy_tail(
    episode: SwarmEpisode, x: np.ndarray, x_next: np.ndarray, control: np.ndarray, costs: Any
) -> CompiledOutcome:
    """The numpy step's checks and path means at x^{n+1} (`checked_advance`), then `_finish`."""
    found = checked_advance(episode.model, x_next, episode.config.divergence_threshold)
    return _finish(episode, x, control, costs, *found)


def _finish(
    episode: SwarmEpisode,
    x: np.ndarray,
    control: np.ndarray,
    costs: Any,
    x_next: np.ndarray,
    drift: np.ndarray,
    flag: Any,
) -> CompiledOutcome:
    """`SwarmEpisode.commit_step` from x^{n+1}, its mean drift and the divergence flag (the
    adapter then builds the observation by numpy)."""
    outcome = episode.commit_step(x, control, float(costs[0]), x_next, drift, flag)
    return CompiledOutcome(outcome, None, None)
