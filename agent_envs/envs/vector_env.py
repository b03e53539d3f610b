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
from collections.abc import Sequence
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from agent_envs import arrays, native
from agent_envs.dynamics.linearization_cache import LinearizationCache
from agent_envs.envs import fast_step  # noqa: F401  (registers the "step" path's check)
from agent_envs.envs.episode import (
    EpisodeConfig,
    advance_paths,
    episode_params,
    mean_interaction_drift,
    mean_running_cost,
    reset_options,
    start_positions,
)
from agent_envs.envs.interface import action_rows, controls_from_actions
from agent_envs.envs.observation import (
    global_observation,
    interaction_drift_bound,
    observation_space,
)
from agent_envs.envs.step_plan import StepPlan, planned_integrator, resolve_step_plan
from agent_envs.integrators import Integrator
from agent_envs.integrators.exponential import GAVE_UP
from agent_envs.simulator import GeneratorHandles, fill_brownian_increments
from agent_envs.validation import check_seed, real_array

#: Bytes of kernel matrices one block of envs holds at most (numpy passes over the whole batch:
#: without numba, or a kernel or Jacobian numba does not serve): the envs are stepped in
#: balanced blocks of at most this size, so that a block's P(x) (B_block x P x N x N floats)
#: stays in the cache while the Krylov iteration multiplies with it, instead of streaming the
#: whole batch's P from memory at every product (N = 100, 20 paths, B = 16: 25.6 MB per product
#: in one batch). 8 MiB measured best of 1, 2, 4, 8 MiB and one batch on a 32 MiB L3
#: (benchmarks/bench_throughput.py prints the vector env's figures). Where every pass runs
#: member by member (`step_plan.member_by_member`), one block (`StepPlan.blocks`).
BLOCK_BYTES = 2**23

#: Autoreset modes the native env implements (Gymnasium's names).
AUTORESET_MODES = (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP)

SeedArg = int | Sequence[int | None] | None


def single_env_phi_method(config: EpisodeConfig) -> str:
    """The phi strategy a single env with this config uses ("auto" resolved for its P paths):
    its `StepPlan.phi_method` (`agent_envs.envs.step_plan.resolve_phi_method`).

    The integrators apply phi to dt L(x) (frozen: N x N, acting on the d columns) or to the
    exact Jacobian (Nd x Nd); "auto" picks by matrix size, symmetry and the number of matrices
    in the call, which for a single env is its number of paths ("krylov" on a matrix-free
    operator).
    """
    model = LinearizationCache(config.params, config.linear_operator)
    return resolve_step_plan(config, model).phi_method


class SwarmVectorEnv(VectorEnv):
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
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)):
            raise TypeError(f"num_envs must be an int >= 1, got {num_envs!r}")
        if num_envs < 1:
            raise ValueError(f"num_envs must be an int >= 1, got {num_envs}")
        if render_mode is not None:
            raise ValueError(
                f"render_mode={render_mode!r}: the native vector env does not render; use "
                "gym.make_vec(..., vectorization_mode='sync', render_mode=...)"
            )
        if backend is None:
            backend = "numpy" if device in (None, "cpu") else "torch"
        self._xp, self._device, _ = arrays.resolve(backend, device)
        if self._device is not None and self._device.type == "cuda":
            import torch

            if not torch.cuda.is_available():
                raise ValueError(f"device={device!r}: torch sees no CUDA device here")
        self.backend = backend
        if not isinstance(tensor_output, bool):
            raise TypeError(f"tensor_output must be a bool, got {tensor_output!r}")
        if tensor_output and backend != "torch":
            raise ValueError("tensor_output=True needs backend='torch' (or a torch device)")
        self.tensor_output = tensor_output
        self.num_threads = native.check_compiled_threads(num_threads, "num_threads")
        if self.num_threads > 1 and backend != "numpy":
            raise ValueError(
                "num_threads > 1 needs the numpy backend (its compiled passes run on the "
                f"threads); backend={backend!r} runs torch's own"
            )
        try:
            mode = AutoresetMode(autoreset_mode)
        except ValueError:
            mode = None
        if mode not in AUTORESET_MODES:
            allowed = [m.value for m in AUTORESET_MODES]
            raise ValueError(f"autoreset_mode must be one of {allowed}, got {autoreset_mode!r}")
        self.config = EpisodeConfig.from_kwargs(
            f"{type(self).__name__}.__init__", env_kind="gymnasium", **kwargs
        )
        self.num_envs = int(num_envs)
        self.device = "cpu" if self._device is None else str(self._device)
        self.render_mode = None
        self.metadata = {**type(self).metadata, "autoreset_mode": mode}
        self.autoreset_mode = mode

        params = self.config.params
        n, d = params.n_agents, params.dim
        #: the mid-step fallbacks so far (`step_plan.FALLBACKS`), shared by the block models
        self.plan_fallbacks: Counter[str] = Counter()
        self.model = LinearizationCache(
            params,
            self.config.linear_operator,
            cache_tensors=True,
            fallbacks=self.plan_fallbacks,
            threads=self.num_threads,
        )
        # which code a step runs, once: the phi strategy of the single env's P paths, the
        # blocks (numpy: of about BLOCK_BYTES of kernel matrices, each with its own model, unless
        # every pass runs member by member; torch: one, a device wants one batch) and whether
        # the compiled prologue and epilogue apply (`_step_compiled`)
        self.plan: StepPlan = resolve_step_plan(
            self.config,
            self.model,
            env="vector",
            backend=backend,
            device=self.device,
            threads=self.num_threads,
            num_envs=self.num_envs,
            block_bytes=BLOCK_BYTES,
            same_step_autoreset=mode is AutoresetMode.SAME_STEP,
        )
        self.phi_method = self.plan.phi_method
        self.integrator: Integrator = planned_integrator(self.config, self.plan)
        envs_per_block = self.plan.envs_per_block
        self._blocks = [
            slice(i, min(i + envs_per_block, self.num_envs))
            for i in range(0, self.num_envs, envs_per_block)
        ]
        # (their threaded passes load in the first reset)
        self._block_models = [self.model] + [
            LinearizationCache(
                params,
                self.config.linear_operator,
                fallbacks=self.plan_fallbacks,
                threads=self.num_threads,
            )
            for _ in self._blocks[1:]
        ]
        # the block views of the current state the block models last saw (their cache keys)
        self._block_views: list[Any] = []
        self._block_views_of: Any = None
        arrays.prepare_hot_path()
        native.available("noise")  # (numba's load when the env is made, not in its first step)
        self.dt = self.config.dt
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

        self._all_rows = np.arange(self.num_envs)
        space = self.single_observation_space
        self._observation_bounds = (
            np.ascontiguousarray(space.low, dtype=np.float32),
            np.ascontiguousarray(space.high, dtype=np.float32),
        )

        b, p = self.num_envs, self.config.n_paths
        self.np_randoms: list[np.random.Generator | None] = [None] * b
        self._handles: GeneratorHandles | None = None
        self._positions = self._on_device(np.zeros((b, p, n, d)))
        self._mean_drift = self._on_device(np.zeros((b, n, d)))
        self._targets = self._on_device(np.broadcast_to(params.target_vector, (b, d)).copy())
        self.step_index = np.zeros(b, dtype=np.int64)
        self._autoreset = np.zeros(b, dtype=bool)
        self._has_reset = False

    # ----------------------------------------------------------------- attributes
    @property
    def n_steps(self) -> int:
        """m, the number of steps of an episode."""
        return self.config.n_steps

    @property
    def n_paths(self) -> int:
        """Brownian paths per env."""
        return self.config.n_paths

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
        return self.config.params.horizon * self.step_index / self.config.n_steps

    # ----------------------------------------------------------------- helpers
    def _env_seeds(self, seed: SeedArg) -> list[int | None]:
        if seed is None:
            return [None] * self.num_envs
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, (bool, np.bool_)):
            first = check_seed(seed)
            return [first + i for i in range(self.num_envs)]
        if not isinstance(seed, (list, tuple, np.ndarray)):
            raise TypeError(
                f"seed must be None, an integer >= 0 or a list of {self.num_envs} of them (one "
                f"per env), got {type(seed).__name__}"
            )
        seeds = [check_seed(s) for s in seed]
        if len(seeds) != self.num_envs:
            raise ValueError(
                f"seed as a list must have one entry per env (num_envs={self.num_envs}), "
                f"got {len(seeds)}"
            )
        return seeds

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
            self.step_index / self.config.n_steps,
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

    def _views_of(self, positions: Any) -> list[Any]:
        """The block views of `positions`: the ones the block models cached, if current."""
        if self._block_views_of is positions:
            return self._block_views
        return [positions[block] for block in self._blocks]

    def _mean_drift_of(self, positions: Any) -> Any:
        """E interaction drift (B, N, d) of `positions` (B, P, N, d), block by block; the block
        models keep L(x) of their views for the next step."""
        if len(self._blocks) == 1:
            return mean_interaction_drift(self.model, positions)
        positions.flags.writeable = False
        views = self._views_of(positions)
        drifts = [
            mean_interaction_drift(m, v) for m, v in zip(self._block_models, views, strict=True)
        ]
        self._block_views, self._block_views_of = views, positions
        return np.concatenate(drifts)

    def _advance(self, x: Any, controls: Any, times: Any, dw: Any) -> tuple[Any, Any, Any]:
        """`advance_paths` of the whole batch, one block of envs at a time (see BLOCK_BYTES):
        every env's arithmetic is the same as in one call (the core works member by member)."""
        threshold = self.config.divergence_threshold
        if len(self._blocks) == 1:
            return advance_paths(
                self.integrator, self.model, x, controls, times, self.dt, dw, threshold
            )
        parts = [
            advance_paths(
                self.integrator,
                model,
                view,
                controls[block],
                times[block],
                self.dt,
                dw[block],
                threshold,
            )
            for model, view, block in zip(
                self._block_models, self._views_of(x), self._blocks, strict=True
            )
        ]
        x_next = np.concatenate([part[0] for part in parts])
        x_next.flags.writeable = False
        self._block_views, self._block_views_of = [part[0] for part in parts], x_next
        drift = np.concatenate([part[1] for part in parts])
        diverged = np.concatenate([part[2] for part in parts])
        return x_next, drift, diverged

    def _step_compiled(self, actions: Any) -> tuple[Any, ...] | None:
        """`step` for the common case, where every env steps (no autoreset in this call) and
        the actions are a float32 or float64 numpy array of shape (B, R d) or (B, R, d) (R = N,
        or 1 for the "common" basis), from
        the state whose L(x) the model keeps: the controls, running costs and right-hand sides
        in one compiled call (`native.step.prologue`), the draws, the integrator's fused
        step (or Euler-Maruyama's update and the kernel pass), and the divergence flags, path
        means and observation in another compiled call (`native.step.epilogue`), the same
        values bit for bit as the numpy step, which is about 30 numpy calls over the batch
        (tests/test_fast_step.py). None, before any draw, where it does not apply (the numpy
        step then runs, and raises for bad actions); a fused step that gives up or does not
        apply takes the numpy step's `_advance` with the same draws (counted in
        `plan_fallbacks`). Runs where the plan's envelope is the compiled step (`StepPlan`:
        numpy, one block, every pass member by member, SERB or ERB on the fused step or
        Euler-Maruyama, the "agents" or "common" action basis, the path "step" available)."""
        b = self.num_envs
        n, d = self.config.params.n_agents, self.config.params.dim
        rows = action_rows(self.config.action_basis, n)
        if (
            type(actions) is not np.ndarray
            or actions.dtype not in (np.float32, np.float64)
            or actions.shape not in ((b, rows * d), (b, rows, d))
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
        controls, costs, rhs = np.empty((b, n, d)), np.empty(b), np.empty(x.shape)
        a = np.ascontiguousarray(actions).reshape(b, rows, d)
        params = self.config.params
        if not module.prologue(
            a, self.config.max_control, x, drift, self._targets, params.gamma, controls, costs, rhs
        ):
            return None  # (non-finite actions: the numpy step raises)
        dw = fill_brownian_increments(
            self.np_randoms, self._all_rows, np.empty(x.shape), self.dt, self._generator_handles()
        )
        noise = model.sigma * dw
        if self.plan.fused:  # (compiled: no numpy warnings to silence)
            x_next = self.integrator.fused_step(model, operator, rhs, x, self.dt, noise)
        else:  # Euler-Maruyama's x + dt F + sigma dW, then the kernel pass at x_next
            with np.errstate(over="ignore", invalid="ignore"):
                x_next = x + self.dt * rhs + noise
                x_next.flags.writeable = False
                model.interaction_drift(x_next)
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
        low, high = self._observation_bounds
        mean_positions, mean_drift = np.empty((b, n, d)), np.empty((b, n, d))
        observations = np.empty((b, low.shape[0]), dtype=np.float32)
        diverged = np.empty(b, dtype=np.bool_)
        module.epilogue(
            x_next, drift_next, self.config.divergence_threshold, self._targets,
            (self.step_index + 1) / self.config.n_steps, low, high, absolute, mean_positions,
            mean_drift, observations, diverged,
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
        truncated = self.step_index >= self.config.n_steps
        info = self._state_info(controls, costs)
        self._autoreset = truncated.copy()
        return observations, -self.dt * costs, diverged, truncated, info

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

        `actions` may be a numpy array (or nested sequence) or a torch tensor; `stepping` is
        the (B,) mask on the env's device, `every` whether it is all True (then no row is
        masked: the same controls with two passes over the batch fewer).
        """
        b, xp = self.num_envs, self._xp
        n, d = self.config.params.n_agents, self.config.params.dim
        if arrays.is_torch(actions):
            # torch dtypes are floating, integer, complex or bool: the last two are not real
            if actions.is_complex() or str(actions.dtype) == "torch.bool":
                raise TypeError(f"actions must hold real numbers, got a tensor of {actions.dtype}")
            if self._device is not None:
                arr = actions.to(device=self._device, dtype=self._positions.dtype)
            else:
                arr = real_array("actions", arrays.to_numpy(actions.detach()), finite=False)
        else:
            # the dtype is checked for every row; finiteness below only for the rows that step
            # (an autoresetting env ignores its action, as SyncVectorEnv does)
            arr = self._on_device(real_array("actions", actions, finite=False))
        rows = action_rows(self.config.action_basis, n)
        if tuple(arr.shape) not in ((b, rows * d), (b, rows, d)):
            raise ValueError(
                f"actions must have shape ({b}, {rows * d}) or ({b}, {rows}, {d}), got "
                f"{tuple(arr.shape)}"
            )
        arr = xp.reshape(arr, (b, rows, d))
        if not bool(xp.all(xp.isfinite(arr if every else arr[stepping]))):
            raise ValueError("actions must be finite, got NaN or inf entries")
        if not every:
            # rows that do not step get no control at all, so a NaN there never reaches the
            # batch
            arr = xp.where(stepping[:, None, None], arr, 0.0)
        return controls_from_actions(arr, self.config.action_basis, self.config.max_control, n)

    # ------------------------------------------------------------------ API
    def reset(
        self, *, seed: SeedArg = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset every env (or those of ``options["reset_mask"]``); see the class docstring."""
        seeds = self._env_seeds(seed)
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
        b, p = self.num_envs, self.config.n_paths
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
        truncated = stepping & (elapsed >= self.config.n_steps)
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
