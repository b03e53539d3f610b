"""The step plan: which code one env step runs, resolved once where the env is made.

Every choice of path that an env step makes from facts fixed when the env is made (its
arguments, its model, the compiled paths switched on in this process) is taken here, once, into
a frozen `StepPlan` that each env exposes as ``env.plan`` (``env.unwrapped.plan`` through
`gym.make`) and shows in its ``repr``; a training run records ``plan.describe()`` in its
``env.json``. The hot code reads the plan instead of deciding again: every env (the single
envs' `SwarmEpisode`, the native vector env) makes its model, plan and integrator together in
`planned_step`, which builds the integrator with the plan's `phi_method` ("auto" resolved for
the env's `n_paths`, the one place where `n_paths` reaches the integrator's choice), and the
native vector env takes its blocks and its compiled envelope from it.

What cannot be known before a step (a Lanczos that does not converge, a state whose actions or
cached linearization the compiled step does not take) still falls back mid-step, with the same
numbers; each env counts those fallbacks in its public ``env.plan_fallbacks``
(`collections.Counter`, keys in `FALLBACKS`).

Place: this module sits in `agent_envs.envs` and not under `integrators/` because the plan
combines the integrator's choices with the env's own (the native vector env's compiled envelope
and blocks, its backend and device) and needs what only an env fixes at construction (the
shape of its state: `n_paths` paths, `num_envs` envs); the integrators and the model keep
answering per call, for `simulate` and the controllers, which have no fixed shape.
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from agent_envs import native
from agent_envs.dynamics.kernels import CuckerSmaleKernel
from agent_envs.dynamics.linearization_cache import LinearizationCache
from agent_envs.dynamics.operators import GRID_MIN_AGENTS, grid_applies
from agent_envs.integrators import INTEGRATORS, EulerMaruyama, Integrator, make_integrator
from agent_envs.integrators.exponential import RosenbrockEuler
from agent_envs.integrators.phi_functions import auto_phi_method

if TYPE_CHECKING:
    from agent_envs.dynamics.swarm import SwarmModel
    from agent_envs.envs.episode_config import EpisodeConfig

#: the mid-step fallbacks an env counts in ``env.plan_fallbacks``: what happened instead
FALLBACKS = {
    "fused-gave-up": "a member's Lanczos in the fused step did not converge; the model's "
    "workspace was discarded and the general step (L(x) again, the phi-action) ran",
    "fused-declined": "the plan's fused step did not apply to this state (say the path 'fused' "
    "was switched off after the env was made); the general step ran (in the native vector "
    "env's compiled step: the numpy step's advance, with the same draws)",
    "compiled-step-declined": "the compiled step (the native vector env's, or a single env's) "
    "did not take this call (actions not a float32/float64 array of the batch's or the "
    "action's shape, non-finite actions, no cached L(x) of the state, or no state to step); "
    "the numpy step ran",
    "numpy-tail": "the compiled step on the envelope 'compiled-step': an env diverged, so the "
    "step ended in the numpy step's tail (the native vector env's `_finish_step`; a single "
    "env's observation of the state it keeps)",
}

#: `StepPlan.envelope` values: the compiled prologue and epilogue around the integrator's step
#: (the native vector env's `CompiledVectorStep`, the single envs' `compiled_episode_step`);
#: the same with the numpy tail (observation layout other than "absolute", SAME_STEP
#: autoresets, the PettingZoo env's per-agent observations and rewards); numpy calls only
ENVELOPES = ("compiled-step", "compiled-step+numpy-tail", "numpy")


@dataclass(frozen=True)
class StepPlan:
    """Which code one step of an env runs, resolved once when the env is made.

    Attributes:
        env: "gymnasium" (`SwarmEnv`), "pettingzoo" (`SwarmParallelEnv`) or "vector"
            (`SwarmVectorEnv`).
        integrator: em | ee | heun | erb | serb.
        jacobian: "frozen" or "exact" for erb/serb; "none" for the explicit schemes.
        phi_method: the strategy the integrator is built with: "auto" resolved for the env's
            `n_paths` ("expm" | "eigh" | "krylov"; "krylov" on a matrix-free operator), or the
            one asked for; for the explicit schemes the argument as given (unused).
        phi: the phi-action's code: "fused-lanczos" (the compiled step and next kernel pass in
            one call, `phi_functions.frozen_advance`), "compiled-lanczos" (`native.lanczos` on
            the frozen L(x)), "lanczos" (numpy, or the Array-API one on torch), "arnoldi"
            (a non-symmetric matrix), "expm", "eigh", "krylov-matrix-free" (the Krylov action
            on `LinearizationOperator`, in substeps where it does not converge), "none" (em,
            ee, heun).
        linear_operator: "dense" (N x N matrices) or "matrix_free" (kernel sums).
        kernel_pass: the pass that gives P(x) and L(x) x: "compiled" (`native.kernel`),
            "numpy", "torch", "grid" or "chunked" (the matrix-free kernel sums; a swarm too
            wide for the grid takes the chunked sum in that step).
        envelope: `ENVELOPES`: the compiled step (the native vector env's, or the single
            envs' as a batch of one) or numpy.
        num_envs: B (1 for the single envs).
        blocks: how many blocks of envs a numpy pass over the batch goes through.
        envs_per_block: envs per block (the last may hold fewer).
        n_paths: Brownian paths per env.
        backend: "numpy" or "torch".
        device: "cpu", "cuda:0", ...
        threads: numba's threads for the compiled passes.
    """

    env: str
    integrator: str
    jacobian: str
    phi_method: str
    phi: str
    linear_operator: str
    kernel_pass: str
    envelope: str
    num_envs: int
    blocks: int
    envs_per_block: int
    n_paths: int
    backend: str
    device: str
    threads: int

    @property
    def compiled_step(self) -> bool:
        """Whether steps take the compiled prologue and epilogue (`ENVELOPES`)."""
        return self.envelope != "numpy"

    @property
    def fused(self) -> bool:
        """Whether the integrator's step is the compiled fused step."""
        return self.phi == "fused-lanczos"

    def as_dict(self) -> dict[str, Any]:
        """The fields as a dict (JSON-ready)."""
        return dataclasses.asdict(self)

    def describe(self) -> str:
        """One line: integrator, phi-action, kernel pass, operator, envelope, batch, arrays."""
        scheme = self.integrator
        if self.jacobian != "none":
            scheme = f"{scheme}/{self.jacobian}"
        batch = f"paths={self.n_paths}"
        if self.env == "vector":
            batch = f"envs={self.num_envs} blocks={self.blocks}x{self.envs_per_block} {batch}"
        return (
            f"{scheme} phi={self.phi} kernel={self.kernel_pass} operator={self.linear_operator} "
            f"envelope={self.envelope} {batch} {self.backend}:{self.device} "
            f"threads={self.threads}"
        )


def planned_integrator(config: EpisodeConfig, plan: StepPlan) -> Integrator:
    """The env's integrator as its plan says: built with the plan's `phi_method` (so the
    env's `n_paths` reaches the integrator's choice here), and for ERB/SERB taking the fused
    step exactly where the plan has it (`RosenbrockEuler.fused`)."""
    spec = config.simulation
    integrator = make_integrator(
        spec.integrator, jacobian=spec.jacobian, phi_method=plan.phi_method
    )
    if isinstance(integrator, RosenbrockEuler):
        integrator.fused = plan.fused
    return integrator


def _like(*shape: int) -> np.ndarray:
    """A float64 numpy array of `shape` without memory: what the model's per-state answers
    read (type, dtype, shape)."""
    return np.broadcast_to(np.empty(()), shape)


def _symmetric(config: EpisodeConfig, model: SwarmModel) -> bool:
    """Whether the step's linearization is symmetric (as `SwarmModel.drift_and_linearization`
    says): L(x) for a symmetric kernel; the exact Jacobian only for a radial one too."""
    symmetric = bool(model.kernel.symmetric)
    if config.simulation.jacobian == "exact":
        symmetric = symmetric and bool(getattr(model.kernel, "radial", False))
    return symmetric


def resolve_phi_method(config: EpisodeConfig, model: SwarmModel, matrix_free: bool) -> str:
    """The phi strategy of an env's integrator: the simulation's `phi_method`, with "auto"
    resolved as `phi_functions.phi_action` resolves it for the env's n_paths matrices (frozen:
    N x N; exact: Nd x Nd), or "krylov" on a matrix-free operator (its only method)."""
    spec = config.simulation
    if spec.phi_method != "auto" or not INTEGRATORS[spec.integrator].needs_jacobian:
        return spec.phi_method
    if matrix_free:
        return "krylov"
    size = config.params.n_agents
    if spec.jacobian == "exact":
        size *= config.params.dim
    return auto_phi_method(size, spec.n_paths, _symmetric(config, model))


def member_by_member(config: EpisodeConfig, model: SwarmModel, num_envs: int) -> bool:
    """Whether every pass of a native vector env's step over the kernel matrices runs one system
    at a time: numba's kernel pass (the symmetric Cucker-Smale kernel on the dense workspace,
    the whole batch within the dense budget), and for an exponential integrator the compiled
    Lanczos on the frozen L(x). The env then takes one block (`SwarmVectorEnv`, BLOCK_BYTES)."""
    p, n, d = config.simulation.n_paths, config.params.n_agents, config.params.dim
    # the whole batch as one block (shape only): it must stay on the dense workspace path, as
    # each env does alone (beyond DENSE_MEMORY_BUDGET_BYTES the model goes matrix-free)
    like = _like(num_envs, p, n, d)
    if model.compiled_pass_parameters(like) is None or not model._uses_workspace(like):
        return False
    if INTEGRATORS[config.simulation.integrator].needs_jacobian:  # ERB, SERB
        return config.simulation.jacobian == "frozen" and native.available("lanczos")
    return True


def _linear_operator(config: EpisodeConfig, model: SwarmModel, numpy: bool, kind: str) -> str:
    if not numpy:  # ("matrix_free" on torch: the env's first kernel pass raises)
        return "matrix_free" if config.linear_operator == "matrix_free" else "dense"
    p, n, d = config.simulation.n_paths, config.params.n_agents, config.params.dim
    try:
        return "matrix_free" if model.matrix_free(_like(p, n, d), kind) else "dense"
    except ValueError:  # (a matrix-free path that does not exist: the step raises)
        return "matrix_free"


def _kernel_pass(config: EpisodeConfig, model: SwarmModel, numpy: bool, operator: str) -> str:
    if not numpy:
        return "torch"
    n, d = config.params.n_agents, config.params.dim
    if operator == "matrix_free":
        grid = grid_applies(model.kernel, d) and n >= GRID_MIN_AGENTS[d]
        return "grid" if grid else "chunked"
    if model.compiled_pass_parameters(_like(config.simulation.n_paths, n, d)) is not None:
        return "compiled"
    return "numpy"


def _phi(
    config: EpisodeConfig, model: SwarmModel, numpy: bool, operator: str, phi_method: str
) -> str:
    """The phi-action's code, as `RosenbrockEuler.step` and `phi_functions.phi_action` pick it
    for the env's states (float64, n_paths x N x d)."""
    if not INTEGRATORS[config.simulation.integrator].needs_jacobian:
        return "none"
    if operator == "matrix_free":
        return "krylov-matrix-free"
    if phi_method in ("expm", "eigh"):
        return phi_method
    if not _symmetric(config, model):
        return "arnoldi"
    workspace = (
        numpy
        and config.simulation.jacobian == "frozen"
        and isinstance(model.kernel, CuckerSmaleKernel)
    )  # the frozen L(x) as a `FrozenLaplacian` over the model's workspace
    if not workspace or not native.available("lanczos"):
        return "lanczos"
    like = _like(config.simulation.n_paths, config.params.n_agents, config.params.dim)
    if (  # `RosenbrockEuler.fused_step`'s conditions (`frozen_advance_applies`)
        model._peak is not None
        and hasattr(model, "fused_relinearization")
        and model.compiled_pass_parameters(like) is not None
        and native.available("fused")
    ):
        return "fused-lanczos"
    return "compiled-lanczos"


def _envelope(
    config: EpisodeConfig,
    numpy: bool,
    phi: str,
    blocks: int,
    numpy_tail: bool,
    one_at_a_time: bool,
) -> str:
    """The native vector env's envelope (`SwarmVectorEnv._step_compiled`): numpy, one block,
    every pass member by member, SERB or ERB on the fused step or Euler-Maruyama, the
    "agents" or "common" action basis ("modes" transforms its actions by numpy), and the path
    "step" available (checked by `fast_step.same_as_numpy`); with the numpy tail for a layout
    other than "absolute" or `numpy_tail` (SAME_STEP autoresets)."""
    if not numpy or blocks != 1 or config.action_basis not in ("agents", "common"):
        return "numpy"
    if not one_at_a_time:
        return "numpy"
    cls = INTEGRATORS[config.simulation.integrator]
    if not (cls is EulerMaruyama or (cls.needs_jacobian and phi == "fused-lanczos")):
        return "numpy"
    if not native.available("step"):
        return "numpy"
    if config.observation != "absolute" or numpy_tail:
        return "compiled-step+numpy-tail"
    return "compiled-step"


def _single_envelope(config: EpisodeConfig, model: SwarmModel, env: str) -> str:
    """A single env's envelope (`compiled_episode.compiled_episode_step`): the compiled
    prologue and epilogue around the integrator's step (fused, or its own: any scheme) where
    the kernel pass is the compiled one on the dense workspace (the model then keeps L(x) of
    every state the step starts from), the action basis "agents" or "common" and the path
    "step" available; with the numpy tail for a layout other than "absolute" and for the
    PettingZoo env (its per-agent observations: compiled rows for "absolute" and "relative",
    numpy's for "swarm" and for "local", whose neighbour search stays in numpy/scipy)."""
    p, n, d = config.simulation.n_paths, config.params.n_agents, config.params.dim
    like = _like(p, n, d)
    if (
        config.action_basis not in ("agents", "common")
        or model.compiled_pass_parameters(like) is None
        or not model._uses_workspace(like)
        or not native.available("step")
    ):
        return "numpy"
    if config.observation != "absolute" or env == "pettingzoo":
        return "compiled-step+numpy-tail"
    return "compiled-step"


def resolve_step_plan(
    config: EpisodeConfig,
    model: SwarmModel,
    *,
    env: str = "gymnasium",
    backend: str = "numpy",
    device: str = "cpu",
    threads: int = 1,
    num_envs: int = 1,
    block_bytes: int | None = None,
    same_step_autoreset: bool = False,
) -> StepPlan:
    """The `StepPlan` of an env with this config and model (the env's own, made first), from
    the functions the hot code asks: `auto_phi_method`, the model's `matrix_free` and
    `compiled_pass_parameters`, `native.available`. For the native vector env (``env=
    "vector"``) also its blocks (`block_bytes` of kernel matrices at most, unless every pass
    runs member by member or the backend is torch: one block); the envelope of every env
    (a single env's as a batch of one: `compiled_episode.compiled_episode_step`)."""
    cls = INTEGRATORS[config.simulation.integrator]
    numpy = backend == "numpy"
    kind = config.simulation.jacobian if cls.needs_jacobian else "frozen"
    operator = _linear_operator(config, model, numpy, kind)
    phi_method = resolve_phi_method(config, model, operator == "matrix_free")
    phi = _phi(config, model, numpy, operator, phi_method)
    blocks, per_block, envelope = 1, num_envs, "numpy"
    if env == "vector":
        n = config.params.n_agents
        if block_bytes is None:
            raise ValueError("the vector env's plan needs block_bytes")
        one_at_a_time = numpy and member_by_member(config, model, num_envs)
        wanted = -(-num_envs * 8 * config.simulation.n_paths * n * n // block_bytes)
        if not numpy or one_at_a_time:
            wanted = 1
        wanted = max(1, min(num_envs, wanted))
        per_block = -(-num_envs // wanted)  # balanced: blocks differ by <= 1 env
        blocks = -(-num_envs // per_block)
        envelope = _envelope(config, numpy, phi, blocks, same_step_autoreset, one_at_a_time)
    else:
        envelope = _single_envelope(config, model, env)
    return StepPlan(
        env=env,
        integrator=config.simulation.integrator,
        jacobian=config.simulation.jacobian if cls.needs_jacobian else "none",
        phi_method=phi_method,
        phi=phi,
        linear_operator=operator,
        kernel_pass=_kernel_pass(config, model, numpy, operator),
        envelope=envelope,
        num_envs=num_envs,
        blocks=blocks,
        envs_per_block=per_block,
        n_paths=config.simulation.n_paths,
        backend=backend,
        device=device,
        threads=threads,
    )


def planned_step(
    config: EpisodeConfig,
    fallbacks: Counter[str],
    *,
    cache_tensors: bool = False,
    threads: int = 1,
    **plan_options: Any,
) -> tuple[LinearizationCache, StepPlan, Integrator]:
    """What an env steps with, made once when the env is made: its model (a
    `LinearizationCache` of the config's params counting its fallbacks in `fallbacks`, torch
    states cached with `cache_tensors`), the `StepPlan` resolved for that model
    (`resolve_step_plan` with `threads` and `plan_options`: env, backend, device, num_envs,
    block_bytes, same_step_autoreset) and the integrator the plan names
    (`planned_integrator`). The single envs' episode and the native vector env both call it,
    so `n_paths` goes from the env's kwargs to the integrator through one plan."""
    model = LinearizationCache(
        config.params,
        config.linear_operator,
        cache_tensors=cache_tensors,
        fallbacks=fallbacks,
        threads=threads,
    )
    plan = resolve_step_plan(config, model, threads=threads, **plan_options)
    return model, plan, planned_integrator(config, plan)
