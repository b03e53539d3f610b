"""Native vectorized `agent_envs/Swarm-v0`: B envs x P paths stepped as one batch.

    envs = gym.make_vec("agent_envs/Swarm-v0", num_envs=64,
                        vectorization_mode="vector_entry_point", n_agents=100)

returns a `SwarmVectorEnv`. Env i of the batch is the single env `gym.make("agent_envs/Swarm-v0",
**kwargs)` reset with seed s + i: same observations, rewards, terminations, truncations and
infos as `gymnasium.vector.SyncVectorEnv` over those envs, episode after episode (tested in
tests/test_vector_env.py). The state of all envs is one (B, P, N, d) array and one step is one
call of the core's batched functions (`agent_envs.envs.episode.advance_paths`,
`mean_running_cost`, `agent_envs.envs.observation.global_observation`); the only per-env
Python work is the random draws, which come from each env's own generator so that every env
sees the numbers its single twin would draw.

Exactness: each env's linear algebra is the single env's. The phi-function strategy "auto"
depends on how many matrices a call holds (`agent_envs.integrators.phi_functions.
auto_phi_method`), so the vector env fixes the strategy the single env picks for its own P
paths. "expm" and "eigh" are per-matrix LAPACK calls, and the Krylov iterations (Lanczos for a
symmetric matrix, Arnoldi otherwise) stop member by member, so every env matches its single
twin bit for bit.

Arrays: numpy by default. With ``device="cuda"`` (or any torch device, or ``backend="torch"`` for
torch on the CPU) the state, the kernel matrices, the integrator steps, costs and observations are
torch tensors on that device (the core is written once against the Array API, `agent_envs.arrays`).
The Brownian increments are still drawn by each env's numpy generator and moved to the device in one
transfer per step, so the torch env follows the numpy env to round-off (tests/test_vector_env.py
compares them on the CPU). Observations, rewards and flags come out as numpy arrays unless
``tensor_output=True`` (then torch tensors on the device); infos are numpy.
"""

from __future__ import annotations

from collections import Counter
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from agent_envs import arrays, native
from agent_envs.draws import GeneratorHandles, fill_brownian_increments
from agent_envs.envs.attributes import EnvAttributes
from agent_envs.envs.episode import mean_running_cost
from agent_envs.envs.episode_config import (
    EpisodeConfig,
    episode_params,
    reset_options,
    start_positions,
)
from agent_envs.envs.fast_step import CompiledVectorStep
from agent_envs.envs.interface import action_rows, controls_from_actions
from agent_envs.envs.observation import (
    global_observation,
    interaction_drift_bound,
    observation_space,
)
from agent_envs.envs.step_plan import planned_step
from agent_envs.envs.vector_blocks import BLOCK_BYTES, EnvBlocks
from agent_envs.envs.vector_inputs import (
    SeedArg,
    batch_actions,
    check_autoreset_mode,
    check_num_envs,
    check_render_mode,
    env_seeds,
    resolve_arrays,
)


class SwarmVectorEnv(EnvAttributes, CompiledVectorStep, VectorEnv):
    r"""B copies of `agent_envs/Swarm-v0` stepped together as one batch of arrays.

    ## Description

    The swarm control problem of `agent_envs.envs.swarm_env.SwarmEnv` (same dynamics,
    integrators, rewards and episode end), for `num_envs` independent envs. All envs share
    the keyword arguments; each has its own random generator, step counter, target and
    divergence flag.

    ## Spaces

    `single_observation_space` and `single_action_space` are the single env's
    (`Box((2 N d + d + 1,), float32)` and `Box(-1, 1, (N d,), float32)`);
    `observation_space` and `action_space` are their batches (leading axis B). Actions may
    also be given as (B, N, d).

    ## Rewards, episode end

    As the single env, per env: reward -tau c(x^n, u^n) (`eq:running_cost`), `truncated`
    after m = `n_steps` steps, `terminated` (and `info["diverged"]`) when a step diverges;
    the other envs go on.

    ## Autoreset

    `autoreset_mode` is Gymnasium's `AutoresetMode.NEXT_STEP` (default, as `SyncVectorEnv`):
    the step after an env's episode ended resets it (its action is ignored, reward 0,
    terminated and truncated False, info the reset info). With `AutoresetMode.SAME_STEP` an
    ended env is reset within the step; `info["final_obs"]` (object array) and
    `info["final_info"]` then hold its last observation and step info.

    ## Seeding

    `reset(seed=s)` seeds env i with s + i (a list gives one seed per env, None leaves an env's
    generator running; a first reset without seed draws fresh entropy). The generators are
    `gymnasium.utils.seeding.np_random(seed)`, the single env's.

    ## Info

    Gymnasium's vector convention: one array per key with a leading axis B and a boolean mask
    `"_key"` telling which envs filled it. Keys: `positions` (B, P, N, d), `time` (B,),
    `diverged` (B,) from every env; `control` (B, N, d) and `running_cost` (B,) from the envs
    that stepped (not from those being reset).

    ## Arguments

    `num_envs` (B >= 1); `autoreset_mode`; `device` ("cpu": numpy; "cuda", "cuda:1", ...:
    torch on that device); `backend` (None: numpy on "cpu", torch otherwise; "torch" with
    device "cpu" runs torch on the CPU); `tensor_output` (return torch tensors instead of
    numpy arrays; torch only); `num_threads` (see Threads); and every keyword argument of the
    single env except
    `render_mode` (the native env does not render; use `vectorization_mode="sync"` for
    rendering). Bad values raise `ValueError`/`TypeError` naming the argument.

    ## Threads

    `num_threads` (default 1; numpy backend with numba): the compiled passes of a step over the
    batch's B x P systems (the kernel pass, and SERB's or ERB's fused step with the frozen
    Jacobian, where the phi-action is the Lanczos) run on that many of numba's threads, in
    contiguous spans of systems; the matrix-free operator (large N) is not threaded. Every system
    is computed alone, so observations, rewards and infos are the same bit for bit as with one
    thread (tests/test_compiled_threads.py); the draws, the costs and the rest of the step stay
    on the calling thread. At most numba's ``NUMBA_NUM_THREADS`` (the CPUs it sees). The default
    keeps one thread, as the BLAS pools of the hot path: several env processes (Ray trials,
    subprocess vector envs) on one machine would otherwise oversubscribe its cores. The first
    reset of an env with threads starts numba's threading layer (TBB where installed, else
    OpenMP, else numba's workqueue); its constructor does not, so Gymnasium's AsyncVectorEnv,
    which makes one env in the parent and then forks, works with threads (tested). With GNU
    OpenMP (numba's choice without TBB), a process forked after the threads started is
    terminated by numba when it runs threads itself ("fork() called from a process already
    using GNU OpenMP"): start subprocesses with "spawn" or "forkserver" (SB3's SubprocVecEnv
    does), or set ``NUMBA_THREADING_LAYER=workqueue``, which survives a fork but aborts the
    process if two Python threads step threaded envs at once (TBB and OpenMP allow that).
    docs/benchmarks.md has the speed-ups measured.

    ## Attributes

    config (`EpisodeConfig`), model, integrator, phi_method (the resolved strategy),
    num_threads, dt, n_steps, n_paths, positions (B, P, N, d), step_index (B,), targets (B, d),
    np_randoms (one generator per env), plan (the `agent_envs.envs.step_plan.StepPlan`: which
    code a step runs, its blocks and whether the compiled step applies, resolved when the env is
    made; `repr(env)` shows it), plan_fallbacks (a `Counter` of the mid-step fallbacks so far:
    `step_plan.FALLBACKS`).

    ## Version History

    - v0: the `vector_entry_point` of `agent_envs/Swarm-v0` since the native vector env was
      added; bit-identical to `SyncVectorEnv` over the single env for every phi strategy.
    """

    metadata: ClassVar[dict[str, Any]] = {
        "render_modes": [],
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }

    def __init__(
        self,
        num_envs: int = 1,
        *,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        device: Any = "cpu",
        backend: str | None = None,
        tensor_output: bool = False,
        num_threads: int = 1,
        render_mode: str | None = None,
        **kwargs: Any,
    ) -> None:
        self.num_envs = check_num_envs(num_envs)
        check_render_mode(render_mode)
        self.backend, self._xp, self._device, self.num_threads = resolve_arrays(
            backend, device, tensor_output, num_threads
        )
        self.tensor_output = tensor_output
        mode = check_autoreset_mode(autoreset_mode)
        self.config = EpisodeConfig.from_kwargs(
            f"{type(self).__name__}.__init__", env_kind="gymnasium", **kwargs
        )
        self.device = "cpu" if self._device is None else str(self._device)
        self.render_mode = None
        self.metadata = {**type(self).metadata, "autoreset_mode": mode}
        self.autoreset_mode = mode
        #: the mid-step fallbacks so far (`step_plan.FALLBACKS`), shared by the block models
        self.plan_fallbacks: Counter[str] = Counter()
        # which code a step runs, once, with the model and the integrator: the phi strategy of
        # the single env's P paths, the blocks (numpy: of about BLOCK_BYTES of kernel matrices,
        # each with its own model, unless every pass runs member by member; torch: one, a
        # device wants one batch) and whether the compiled prologue and epilogue apply
        # (`_step_compiled`)
        self.model, self.plan, self.integrator = planned_step(
            self.config,
            self.plan_fallbacks,
            cache_tensors=True,
            threads=self.num_threads,
            env="vector",
            backend=self.backend,
            device=self.device,
            num_envs=self.num_envs,
            block_bytes=BLOCK_BYTES,
            same_step_autoreset=mode is AutoresetMode.SAME_STEP,
        )
        self._blocks = EnvBlocks(
            self.model, self.config, self.num_envs, self.plan.envs_per_block, self.plan_fallbacks
        )
        arrays.prepare_hot_path()
        native.available("noise")  # (numba's load when the env is made, not in its first step)
        self._make_spaces()
        b, p = self.num_envs, self.config.simulation.n_paths
        n, d = self.config.params.n_agents, self.config.params.dim
        self._all_rows = np.arange(b)
        self.np_randoms: list[np.random.Generator | None] = [None] * b
        self._handles: GeneratorHandles | None = None
        self._positions = self._on_device(np.zeros((b, p, n, d)))
        self._mean_drift = self._on_device(np.zeros((b, n, d)))
        target = self.config.params.target_vector
        self._targets = self._on_device(np.broadcast_to(target, (b, d)).copy())
        self.step_index = np.zeros(b, dtype=np.int64)
        self._autoreset = np.zeros(b, dtype=bool)
        self._has_reset = False

    def _make_spaces(self) -> None:
        """The single env's spaces, their batches, and the observation bounds (float32) of the
        compiled epilogue."""
        n, d = self.config.params.n_agents, self.config.params.dim
        rows = action_rows(self.config.action_basis, n)
        self.single_action_space = spaces.Box(-1.0, 1.0, shape=(rows * d,), dtype=np.float32)
        self.single_observation_space = observation_space(
            n,
            d,
            self.config.divergence_threshold,
            interaction_drift_bound(self.model.kernel),
            self.config.observation,
        )
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        space = self.single_observation_space
        self._observation_bounds = (
            np.ascontiguousarray(space.low, dtype=np.float32),
            np.ascontiguousarray(space.high, dtype=np.float32),
        )

    # ----------------------------------------------------------------- attributes
    @property
    def positions(self) -> np.ndarray:
        """(B, P, N, d) current states as a numpy array: the (read-only) state itself on the
        numpy backend, a copy on torch (a CPU tensor's numpy view would be writable)."""
        if isinstance(self._positions, np.ndarray):
            return self._positions
        return np.array(arrays.to_numpy(self._positions))

    @property
    def targets(self) -> np.ndarray:
        """(B, d) targets xbar of the current episodes (a numpy copy)."""
        return np.array(arrays.to_numpy(self._targets))

    @property
    def times(self) -> np.ndarray:
        """t_n = n T / m per env: (B,)."""
        return self.config.params.horizon * self.step_index / self.config.simulation.n_steps

    # ----------------------------------------------------------------- helpers
    def _rng(self, i: int) -> np.random.Generator:
        rng = self.np_randoms[i]
        if rng is None:
            rng, _ = seeding.np_random()
            self.np_randoms[i] = rng
        return rng

    def _generator_handles(self) -> GeneratorHandles:
        """`GeneratorHandles` of the envs' generators (`np_randoms`, all set), built again
        when one of them was replaced (a seeded reset): all draws of a step in one compiled
        call (`fill_brownian_increments`)."""
        if self._handles is None or not self._handles.holds(self.np_randoms):
            self._handles = GeneratorHandles(self.np_randoms)
        return self._handles

    def _on_device(self, a: np.ndarray) -> Any:
        """A host numpy array in the env's array library, on its device (numpy: itself)."""
        if self._device is None:
            return a
        import torch

        return torch.as_tensor(a, device=self._device)

    def _output(self, a: Any) -> Any:
        """What step/reset return: a numpy array, or a tensor on the device (tensor_output)."""
        if self.tensor_output:
            return a if arrays.is_torch(a) else self._on_device(np.asarray(a))
        return arrays.to_numpy(a)

    def _observations(self) -> Any:
        return global_observation(
            arrays.mean_axis(self._positions, -3),
            self._mean_drift,
            self._targets,
            self.step_index / self.config.simulation.n_steps,
            self.single_observation_space,
            self.config.observation,
        )

    def _reset_envs(self, mask: np.ndarray, seeds: list[int | None], options: Any) -> None:
        """Start new episodes in the envs of `mask` (same draws as `SwarmEpisode.reset`)."""
        opts = reset_options(options, strict=True)
        params = episode_params(self.config, opts["target"])
        rows = np.flatnonzero(mask)
        starts = np.empty((len(rows), 1, *self._positions.shape[-2:]))
        for k, i in enumerate(rows):
            if seeds[i] is not None:
                self.np_randoms[i], _ = seeding.np_random(seeds[i])
            starts[k, 0] = start_positions(self.config, self._rng(i), opts["initial_positions"])
        xp = self._xp
        rows_on_device = self._on_device(rows)
        positions = xp.asarray(self._positions, copy=True)
        positions[rows_on_device] = self._on_device(starts)  # the same start for every path
        drift = self._mean_drift_of(positions)
        if not bool(xp.all(xp.isfinite(drift[rows_on_device]))):
            raise ValueError("the interaction drift is not finite at the initial positions")
        targets = xp.asarray(self._targets, copy=True)
        targets[rows_on_device] = self._on_device(params.target_vector)
        self._positions, self._mean_drift, self._targets = positions, drift, targets
        self.step_index[mask] = 0
        self._autoreset[mask] = False

    def _mean_drift_of(self, positions: Any) -> Any:
        """E interaction drift (B, N, d) of `positions` (B, P, N, d), block by block; the block
        models keep L(x) of their views for the next step (`EnvBlocks.mean_drift`)."""
        return self._blocks.mean_drift(positions)

    def _advance(self, x: Any, controls: Any, times: Any, dw: Any) -> tuple[Any, Any, Any]:
        """`advance_paths` of the whole batch, one block of envs at a time (`EnvBlocks.advance`,
        `BLOCK_BYTES`): every env's arithmetic is the same as in one call."""
        threshold = self.config.divergence_threshold
        return self._blocks.advance(self.integrator, x, controls, times, self.dt, dw, threshold)

    def _state_info(self, control: Any = None, running_cost: Any = None) -> dict[str, Any]:
        """The info of the current state, every key filled by every env; a reset's info has
        the step keys too (zero control, zero running cost, as the single env's), a step's
        its own `control` (B, N, d) and `running_cost` (B,) where given."""
        every = np.ones(self.num_envs, dtype=bool)
        n, d = self.config.params.n_agents, self.config.params.dim
        if control is None:
            control = np.zeros((self.num_envs, n, d))
        if running_cost is None:
            running_cost = np.zeros(self.num_envs)
        return {
            "positions": np.array(self.positions),
            "_positions": every,
            "time": self.times,
            "_time": every.copy(),
            "diverged": np.zeros(self.num_envs, dtype=bool),
            "_diverged": every.copy(),
            "control": control,
            "_control": every.copy(),
            "running_cost": running_cost,
            "_running_cost": every.copy(),
        }

    def _controls(self, actions: Any, stepping: Any, every: bool = False) -> Any:
        """u = max_control * clip(a, -1, 1) per env: (B, N, d) (rows not stepping ignored).

        `actions` may be a numpy array (or nested sequence) or a torch tensor, checked by
        `vector_inputs.batch_actions`; `stepping` is the (B,) mask on the env's device, `every`
        whether it is all True (then no row is masked: the same controls with two passes over
        the batch fewer).
        """
        n, d = self.config.params.n_agents, self.config.params.dim
        shape = (self.num_envs, action_rows(self.config.action_basis, n), d)
        arr = batch_actions(
            actions, shape, stepping, every, self._xp, self._on_device, self._device,
            self._positions.dtype,
        )  # fmt: skip
        return controls_from_actions(
            arr, self.config.action_basis, self.config.simulation.max_control, n
        )

    # ------------------------------------------------------------------ API
    def reset(
        self, *, seed: SeedArg = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset every env (or those of ``options["reset_mask"]``); see the class docstring."""
        seeds = env_seeds(seed, self.num_envs)
        if self.num_threads > 1:
            # the threaded passes' one-time load (it starts numba's threads) falls in the first
            # reset, not in the constructor, so that a process may fork after making an env
            # (see Threads)
            native.load_compiled_threads(self.num_threads)
        options = dict(options or {})
        mask = options.pop("reset_mask", None)
        if mask is None:
            mask = np.ones(self.num_envs, dtype=bool)
        else:
            mask = np.asarray(mask)
            if mask.shape != (self.num_envs,) or mask.dtype != np.bool_:
                raise ValueError(
                    f"options['reset_mask'] must be a bool array of shape ({self.num_envs},)"
                )
            if not self._has_reset and not np.all(mask):
                raise ValueError("the first reset must reset every env (no reset_mask)")
        self._reset_envs(mask, seeds, options)
        self._has_reset = True
        info = self._state_info()
        # as SyncVectorEnv: zeros (and a False mask) where an env was not reset
        for key in ("positions", "time", "diverged", "control", "running_cost"):
            rows = mask.reshape((-1,) + (1,) * (info[key].ndim - 1))
            info[key] = np.where(rows, info[key], np.zeros_like(info[key]))
            info[f"_{key}"] = mask.copy()
        return self._output(self._observations()), info

    def step(
        self, actions: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Step every env once (NEXT_STEP: the envs that ended last step are reset instead)."""
        if not self._has_reset:
            raise RuntimeError("call reset() before step()")
        if self.plan.compiled_step and not self._autoreset.any():
            found = self._step_compiled(actions)
            if found is not None:
                return found
            self.plan_fallbacks["compiled-step-declined"] += 1
        b, p = self.num_envs, self.config.simulation.n_paths
        n, d = self.config.params.n_agents, self.config.params.dim
        resetting = self._autoreset.copy()
        stepping = ~resetting
        every = not resetting.any()  # the common case: no env autoresets in this call
        stepping_on_device = self._on_device(stepping)
        controls = self._controls(actions, stepping_on_device, every)
        x = self._positions

        costs = mean_running_cost(x, controls, self._targets, self.config.params.gamma)
        # Each env draws from its own generator, as its single twin does; the batch then
        # moves to the device in one transfer. (After the first reset every env has one.)
        rows = np.flatnonzero(stepping)
        handles = None
        if every and None not in self.np_randoms:
            rngs = self.np_randoms
            handles = self._generator_handles()
        else:
            rngs = [self._rng(i) for i in rows]
        dw = fill_brownian_increments(rngs, rows, np.zeros((b, p, n, d)), self.dt, handles)
        with arrays.hot_path_threads():  # BLAS on one thread, as the single env's step
            x_next, drift_next, diverged_on_device = self._advance(
                x, controls, self._on_device(self.times[:, None, None, None]), self._on_device(dw)
            )
        return self._finish_step(x, x_next, drift_next, diverged_on_device, controls, costs,
                                 stepping)  # fmt: skip

    def _finish_step(
        self,
        x: Any,
        x_next: Any,
        drift_next: Any,
        diverged_on_device: Any,
        controls: Any,
        costs: Any,
        stepping: np.ndarray,
        observations: Any = None,
    ) -> tuple[Any, Any, Any, Any, dict[str, Any]]:
        """The rest of `step` after the integrator's step from x to x_next (E drift
        `drift_next` (B, N, d), flags `diverged_on_device`): the new state, rewards, flags,
        info and autoresets; `stepping` the (B,) mask of the envs that stepped (the others
        autoreset in this call); `observations` the observation of the new state where the
        caller has it (else computed here)."""
        b, xp = self.num_envs, self._xp
        resetting = ~stepping
        every = bool(stepping.all())
        stepping_on_device = self._on_device(stepping)
        diverged = arrays.to_numpy(diverged_on_device) & stepping
        moved = stepping & ~diverged
        if np.all(moved):
            self._positions, self._mean_drift = x_next, drift_next
            self.step_index += 1
        else:
            # Diverged envs keep x^n (as the single env); the others take x^{n+1}. The drift
            # of the assembled state is recomputed, which also caches L for the next step.
            moved_on_device = self._on_device(moved)
            self._positions = xp.where(moved_on_device[:, None, None, None], x_next, x)
            self.step_index[moved] += 1
            if np.any(resetting):
                self._reset_envs(resetting, [None] * b, None)
            else:
                self._mean_drift = self._mean_drift_of(self._positions)

        # the episode's steps so far, the diverging one included: gym.make's TimeLimit counts
        # calls, so a single env that diverges on its last step is terminated and truncated
        elapsed = self.step_index + diverged
        truncated = stepping & (elapsed >= self.config.simulation.n_steps)
        terminated = diverged.copy()
        if observations is None or not np.all(moved):
            observations = self._observations()
        if every:  # (controls and costs are this call's own arrays)
            rewards = arrays.to_numpy(-self.dt * costs)
            info = self._state_info(arrays.to_numpy(controls), arrays.to_numpy(costs))
        else:
            info = self._state_info()
            # envs that autoreset in this call: reward 0 and their reset info (zero control
            # and cost)
            rewards = arrays.to_numpy(xp.where(stepping_on_device, -self.dt * costs, 0.0))
            control_rows = stepping_on_device[:, None, None]
            info["control"] = arrays.to_numpy(xp.where(control_rows, controls, 0.0))
            info["running_cost"] = arrays.to_numpy(xp.where(stepping_on_device, costs, 0.0))
        info["diverged"] = diverged.copy()

        ended = terminated | truncated
        if self.autoreset_mode == AutoresetMode.SAME_STEP and np.any(ended):
            info = self._same_step_reset(ended, self._output(observations), info)
            observations = self._observations()
        else:
            self._autoreset = ended
        return (
            self._output(observations),
            self._output(rewards),
            self._output(terminated),
            self._output(truncated),
            info,
        )

    def _same_step_reset(
        self, ended: np.ndarray, observations: Any, info: dict[str, Any]
    ) -> dict[str, Any]:
        """Reset the ended envs now; their last observation and info go to final_obs/info."""
        final_obs = np.full(self.num_envs, None, dtype=object)
        for i in np.flatnonzero(ended):
            final_obs[i] = observations[i]
        final_info = {}
        for key in [k for k in info if not k.startswith("_")]:
            rows = ended.reshape((-1,) + (1,) * (info[key].ndim - 1))
            final_info[key] = np.where(rows, info[key], np.zeros_like(info[key]))
            final_info[f"_{key}"] = info[f"_{key}"] & ended
        self._reset_envs(ended, [None] * self.num_envs, None)
        reset_info = self._state_info()
        for key in ("positions", "time", "diverged", "control", "running_cost"):
            info[key] = np.where(
                ended.reshape((-1,) + (1,) * (info[key].ndim - 1)), reset_info[key], info[key]
            )
        info["final_obs"], info["_final_obs"] = final_obs, ended.copy()
        info["final_info"], info["_final_info"] = final_info, ended.copy()
        return info

    def __repr__(self) -> str:
        """Gymnasium's ``SwarmVectorEnv(id, num_envs=B)`` with the step plan."""
        return f"{super().__repr__()[:-1]}, plan: {self.plan.describe()})"

    def close_extras(self, **kwargs: Any) -> None:
        """Nothing to release (no subprocesses, no renderer)."""


def make_swarm_vector_env(num_envs: int = 1, **kwargs: Any) -> SwarmVectorEnv:
    """`vector_entry_point` of `agent_envs/Swarm-v0`: `SwarmVectorEnv(num_envs, **kwargs)`."""
    return SwarmVectorEnv(num_envs, **kwargs)
