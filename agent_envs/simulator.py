"""Batches of Brownian paths: initial states, noise, stepping, divergence detection.

All randomness comes from a `numpy.random.Generator` passed in (the env's `self.np_random`) or
built from a seed; integrators never draw. `simulate` spawns two independent child generators
from the seed, one for the initial positions and one for the Brownian increments, so giving
`initial_positions` does not change the noise, and every integrator sees the same increments
for the same seed.

Arrays: numpy by default; torch (CPU or CUDA) when torch tensors are passed in
(`initial_positions`, `control`, `control_rate`) or `backend="torch"`/`device=` asks for it
(`agent_envs.arrays.resolve`). The Brownian increments are always drawn by numpy from the seed
and then moved to the device, so a torch run sees exactly the increments of the numpy run with
the same seed. On torch the trajectory is differentiable with respect to the initial positions
and the control (the stepping is functional: no in-place writes).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from agent_envs import arrays
from agent_envs.draws import brownian_increments, uniform_positions
from agent_envs.dynamics.kernels import check_kernel_library
from agent_envs.dynamics.operators import check_linear_operator
from agent_envs.dynamics.swarm import SwarmModel, kernel_from_params
from agent_envs.integrators import (
    DEFAULT_INTEGRATOR,
    DEFAULT_JACOBIAN,
    Integrator,
    make_integrator,
)
from agent_envs.integrators.base import DriftModel
from agent_envs.params import SwarmParams
from agent_envs.validation import (
    DIVERGENCE_THRESHOLD_RANGE,
    MAX_BATCH_SIZE,
    MAX_CONTROL_RANGE,
    MAX_PATHS,
    MAX_STEPS,
    check_int,
    check_positive,
    check_seed,
    check_size,
    real_array,
)

#: A state is flagged as diverged when it is non-finite or max |x| exceeds this.
DEFAULT_DIVERGENCE_THRESHOLD = 1e4
#: Default number of time steps m (the paper's turnpike experiments; tau = T / m).
DEFAULT_N_STEPS = 50
#: Default bound on each coordinate of u_k: an env action a in [-1, 1] is the control
#: u = 150 a. It leaves the turnpike cheap control (eq:cheap_ctr, beta = 12) unclipped in the
#: paper's settings: benchmarks/max_control.py measures its largest |u|, docs/envs/gymnasium.md
#: ("Why max_control = 150") has the figures.
DEFAULT_MAX_CONTROL = 150.0
#: Default phi-function strategy of the exponential integrators (`phi_functions`).
DEFAULT_PHI_METHOD = "auto"
#: Brownian paths of an env episode: one path, one sample of the SDE per step, by default.
ENV_N_PATHS = 1
#: Brownian paths of a sample average (the paper's K = 20): `simulate`, the optimal-control
#: solver and its controllers estimate the expectation in eq:discrete_cost_functional over this
#: many paths by default. It differs from `ENV_N_PATHS` on purpose: an env gives a learner one
#: sample per step, a solver needs the average.
SAMPLE_AVERAGE_PATHS = 20

ControlSpec = Any  # None | array | Callable[[float, array], array]


def check_steps_and_paths(params: SwarmParams, n_steps: Any, n_paths: Any) -> tuple[int, int]:
    """(m, K) checked: 1 <= m <= 1e9, 1 <= K <= 1e6 with K N d <= 1e8; errors name them."""
    n_steps = check_int("n_steps", n_steps, 1, MAX_STEPS)
    n_paths = check_int("n_paths", n_paths, 1, MAX_PATHS)
    state_size = params.n_agents * params.dim
    check_size("n_paths", n_paths, n_paths * state_size, MAX_BATCH_SIZE, "n_paths * N * d")
    return n_steps, n_paths


@dataclass(frozen=True)
class SimulationSpec:
    """How a swarm simulation is discretized, sampled and controlled: the one spec shared by
    `simulate`, `baselines.solve_optimal_control`, the controllers and the envs'
    `EpisodeConfig` (each default defined once, above).

    Fields: `integrator` ("em", "ee", "heun", "erb", "serb"), `jacobian` ("frozen" | "exact",
    for erb/serb), `phi_method` (`phi_functions`), `n_steps` m (tau = T / m), `n_paths` K
    (Brownian paths; an env's default is `ENV_N_PATHS`, a sample average's
    `SAMPLE_AVERAGE_PATHS`), `max_control` (the bound on every coordinate of u), `seed` (None
    or an int >= 0: the start and the noise of `simulate`, the paths of a solve). A bad value
    raises `ValueError`/`TypeError` naming the field; `for_params` adds the checks that need
    the model (K N d <= 1e8, "eigh" only on a symmetric kernel).
    """

    integrator: str = DEFAULT_INTEGRATOR
    jacobian: str = DEFAULT_JACOBIAN
    phi_method: str = DEFAULT_PHI_METHOD
    n_steps: int = DEFAULT_N_STEPS
    n_paths: int = ENV_N_PATHS
    max_control: float = DEFAULT_MAX_CONTROL
    seed: int | None = None

    def __post_init__(self) -> None:
        make_integrator(self.integrator, jacobian=self.jacobian, phi_method=self.phi_method)
        set_ = object.__setattr__
        set_(self, "n_steps", check_int("n_steps", self.n_steps, 1, MAX_STEPS))
        set_(self, "n_paths", check_int("n_paths", self.n_paths, 1, MAX_PATHS))
        set_(
            self, "max_control", check_positive("max_control", self.max_control, MAX_CONTROL_RANGE)
        )
        set_(self, "seed", check_seed(self.seed))

    def for_params(self, params: SwarmParams) -> SimulationSpec:
        """This spec after the checks that need the model; returns self."""
        check_steps_and_paths(params, self.n_steps, self.n_paths)
        check_phi_method_fits_kernel(params, self.integrator, self.jacobian, self.phi_method)
        return self

    def time_step(self, params: SwarmParams) -> float:
        """tau = T / m."""
        return params.horizon / self.n_steps


def real_input(name: str, value: Any) -> Any:
    """A torch tensor of a real floating dtype as is (autograd kept), else `real_array`.

    Strings, bools and complex numbers raise `TypeError` naming `name` on either path.
    """
    if arrays.is_torch(value):
        if value.is_complex() or not value.is_floating_point():
            raise TypeError(f"{name} must be a real floating-point tensor, got {value.dtype}")
        return value
    return real_array(name, value)


def as_positions(positions: Any, n_agents: int, dim: int, name: str = "initial_positions"):
    """Validate positions of shape (N,) (only for d = 1) or (N, d); return (N, d) floats.

    Entries must be finite real numbers (`agent_envs.validation.real_array`: strings, bools and
    complex numbers raise `TypeError` naming `name`). A torch tensor stays a tensor (same
    device, autograd kept); anything else becomes a float64 numpy array.
    """
    arr = real_input(name, positions)
    xp = arrays.namespace(arr)
    if arr.ndim == 1 and dim == 1:
        arr = arr[:, None]
    if tuple(arr.shape) != (n_agents, dim):
        allowed = f"({n_agents},) or ({n_agents}, 1)" if dim == 1 else f"({n_agents}, {dim})"
        got = tuple(getattr(positions, "shape", np.shape(positions)))
        raise ValueError(f"{name} must have shape {allowed}, got {got}")
    if not bool(xp.all(xp.isfinite(arr))):
        raise ValueError(f"{name} must be finite")
    return arr


def check_phi_method_fits_kernel(
    params: SwarmParams, integrator: str, jacobian: str, phi_method: str
) -> None:
    """Raise `ValueError` naming `phi_method` when "eigh" is forced on a non-symmetric matrix.

    "eigh" needs a symmetric kernel for `jacobian="frozen"`, and a symmetric radial kernel
    (attribute `radial`) for `jacobian="exact"`; it matters only for "erb"/"serb".
    """
    if phi_method != "eigh" or integrator not in ("erb", "serb"):
        return
    kernel = kernel_from_params(params)
    symmetric = bool(kernel.symmetric)
    if jacobian == "exact":
        symmetric = symmetric and bool(getattr(kernel, "radial", False))
    if not symmetric:
        raise ValueError(
            f"phi_method='eigh' needs a symmetric matrix, but jacobian={jacobian!r} with this "
            "kernel is not symmetric; use phi_method='auto', 'expm' or 'krylov'"
        )


def diverged_paths(x: Any, threshold: float = DEFAULT_DIVERGENCE_THRESHOLD) -> Any:
    """Per path (leading axes of x (..., N, d)): True if non-finite or max |x| > threshold.

    In the library of x (a bool array of the leading shape).
    """
    xp = arrays.namespace(x)
    if math.isfinite(threshold):
        # |x| <= threshold is False for NaN and inf (and beyond the threshold): one comparison
        # for both checks, three passes over x fewer than isfinite and >, the same flags
        return ~xp.all(xp.abs(x) <= threshold, axis=(-2, -1))
    bad = ~xp.isfinite(x) | (xp.abs(x) > threshold)
    return xp.any(bad, axis=(-2, -1))


def _control_at(control: ControlSpec, n: int, t: float, x: Any, name: str) -> Any:
    if control is None:
        return None
    u = control(t, x) if callable(control) else control[n]
    if callable(control):
        u = real_input(f"{name} at step {n}", u)
    u = arrays.asarray(u, like=x)
    xp = arrays.namespace(x)
    try:
        u = xp.broadcast_to(u, tuple(x.shape))
    except (ValueError, RuntimeError):
        raise ValueError(
            f"{name} at step {n} has shape {tuple(u.shape)}, which does not broadcast to the "
            f"state shape {tuple(x.shape)}"
        ) from None
    if not bool(xp.all(xp.isfinite(u))):
        raise ValueError(f"{name} at step {n} is not finite")
    return u


def _validate_control_array(control: Any, n_steps: int, n_agents: int, dim: int, name: str):
    if control is None or callable(control):
        return control
    arr = real_input(name, control)
    if dim == 1 and arr.ndim == 2:
        arr = arr[..., None]
    shape = tuple(arr.shape)
    if arr.ndim not in (3, 4) or shape[0] != n_steps or shape[-2:] != (n_agents, dim):
        raise ValueError(
            f"{name} must be None, a callable(t, x) -> u, or an array of shape "
            f"(n_steps, N, d) = ({n_steps}, {n_agents}, {dim}) or (n_steps, n_paths, N, d); "
            f"got shape {tuple(np.shape(control)) if not arrays.is_torch(control) else shape}"
        )
    return arr


@dataclass
class Trajectory:
    """The result of `simulate`.

    Attributes:
        times: (m + 1,) the time grid t_n = n tau (numpy).
        positions: (m + 1, n_paths, N, d), numpy or a torch tensor (the simulation's library;
            differentiable on torch). When a path diverges, integration stops and the rows
            after `divergence_step` are NaN (flagged by `diverged`, never silent).
        controls: (m, n_paths, N, d) the control applied on each step (zeros for no control),
            in the simulation's library.
        diverged: True if any path became non-finite or exceeded `divergence_threshold`.
        divergence_step: the first step index n at which a path diverged, else None.
        diverged_paths: (n_paths,) which paths diverged (numpy bool).
        wall_time: seconds spent integrating.
    """

    times: np.ndarray
    positions: Any
    controls: Any
    diverged: bool
    divergence_step: int | None
    diverged_paths: np.ndarray
    wall_time: float
    integrator: str
    jacobian: str | None
    params: SwarmParams = field(repr=False)

    @property
    def mean_positions(self) -> Any:
        """Positions averaged over the Brownian paths: (m + 1, N, d)."""
        return arrays.namespace(self.positions).mean(self.positions, axis=1)


def _generators(seed: int | np.random.Generator | None):
    if isinstance(seed, np.random.Generator):
        init_rng, noise_rng = seed.spawn(2)
    else:
        seed = check_seed(seed)  # or a numpy Generator, handled above
        init_ss, noise_ss = np.random.SeedSequence(seed).spawn(2)
        init_rng, noise_rng = np.random.default_rng(init_ss), np.random.default_rng(noise_ss)
    return init_rng, noise_rng


def simulate(
    params: SwarmParams,
    integrator: str | Integrator = DEFAULT_INTEGRATOR,
    *,
    jacobian: str | None = None,
    n_steps: int = DEFAULT_N_STEPS,
    n_paths: int = SAMPLE_AVERAGE_PATHS,
    seed: int | np.random.Generator | None = None,
    initial_positions: Any = None,
    control: ControlSpec = None,
    control_rate: ControlSpec = None,
    phi_method: str | None = None,
    divergence_threshold: float = DEFAULT_DIVERGENCE_THRESHOLD,
    model: DriftModel | None = None,
    increments: Any = None,
    backend: str | None = None,
    device: Any = None,
    linear_operator: str | None = None,
) -> Trajectory:
    """Integrate the swarm SDE on [0, T] with m = `n_steps` steps for `n_paths` Brownian paths.

    Args:
        params: the model (N, d, horizon T; the dynamics unless `model` is given).
        integrator: a registry name ("em", "ee", "heun", "erb", "serb") or an Integrator.
        jacobian: "frozen" (default, L(x)) or "exact" (dF/dx), for "erb"/"serb"; with an
            integrator instance, leave it None (the instance's own choice is used).
        n_steps: 1 <= m <= 1e9; tau = T / m.
        n_paths: 1 <= n_paths <= 1e6 (n_paths N d <= 1e8), the number of Brownian paths
            simulated together (all from the same start).
        seed: int, `numpy.random.Generator` or None.
        initial_positions: (N,) or (N, d), finite, inside `divergence_threshold`; default
            uniform on [-1, 1]^d drawn from the seed.
        control: None, an array (n_steps, N, d) or (n_steps, n_paths, N, d), or a callable
            ``control(t, x) -> u`` with x of shape (n_paths, N, d) and u broadcastable to it.
        control_rate: du/dt in the same forms, for the phi2 term of `eq:serbaut` (optional).
        phi_method: "auto" (default), "expm", "eigh" or "krylov" (see `phi_action`).
        divergence_threshold: R in [1, 1e6], max |x| beyond which a path counts as diverged.
        model: a drift model following `agent_envs.integrators.base.DriftModel`
            (``drift(t, x, u)``, ``drift_and_linearization(t, x, u, kind)``, ``sigma``), e.g. a
            closed loop whose drift contains a feedback law; default `SwarmModel(params)`.
        increments: the Brownian increments dW, shape (n_steps, n_paths, N, d), variance tau;
            default drawn from the seed (then `seed` only draws the initial positions).
        backend: "numpy", "torch" or None (torch when a torch tensor is passed in or `device`
            is given, numpy otherwise).
        device: a torch device ("cpu", "cuda", ...) for the torch backend.
        linear_operator: "auto" (default), "dense" or "matrix_free": how the drift and the
            frozen linearization are evaluated (see `SwarmModel`; matrix-free = kernel sums
            without the N x N matrix, numpy only, the choice for large N). Only with the
            default model.

    Bad arguments raise `TypeError`/`ValueError` naming them and their accepted ranges (see
    `agent_envs.validation`). Controls are checked for a real dtype and finiteness; a control
    so large that the state leaves R is reported by `diverged`, not rejected.
    """
    if not isinstance(params, SwarmParams):
        raise TypeError(f"params must be a SwarmParams, got {type(params).__name__}")
    n_steps, n_paths = check_steps_and_paths(params, n_steps, n_paths)
    divergence_threshold = check_positive(
        "divergence_threshold", divergence_threshold, DIVERGENCE_THRESHOLD_RANGE
    )
    scheme = _scheme(params, integrator, jacobian, phi_method, model is None)
    xp, dev, dtype = arrays.resolve(backend, device, initial_positions, control, control_rate)
    n, d = params.n_agents, params.dim
    control = _validate_control_array(control, n_steps, n, d, "control")
    control_rate = _validate_control_array(control_rate, n_steps, n, d, "control_rate")
    model = _model(params, model, linear_operator)
    if not arrays.is_numpy_namespace(xp) and not isinstance(params.kernel, str):
        # a user kernel on a torch path: probe it once (one clear error, not one deep inside)
        probe = arrays.asarray(np.zeros(1), xp=xp, device=dev, dtype=dtype)
        check_kernel_library(getattr(model, "kernel", params.kernel), probe, params.dim)
    x0, increments = _start_and_increments(
        params, seed, initial_positions, increments, (n_steps, n_paths), divergence_threshold
    )
    x0 = arrays.asarray(x0, xp=xp, device=dev, dtype=dtype)
    increments = arrays.asarray(increments, xp=xp, device=dev, dtype=dtype)
    times = np.linspace(0.0, params.horizon, n_steps + 1)
    x = xp.broadcast_to(x0, (n_paths, n, d))
    if arrays.is_numpy_namespace(xp):
        x = x.copy()
    loop = (xp, times, params.horizon / n_steps, divergence_threshold)
    start = time.perf_counter()
    states, applied, bad, divergence_step = _integrate(
        scheme, model, x, increments, control, control_rate, loop
    )
    wall = time.perf_counter() - start
    return _trajectory(params, scheme, xp, times, states, applied, bad, divergence_step, wall)


def _scheme(
    params: SwarmParams,
    integrator: str | Integrator,
    jacobian: str | None,
    phi_method: str | None,
    default_model: bool,
) -> Integrator:
    """`simulate`'s integrator: the instance given (a `jacobian` or `phi_method` that differs
    from its own raises), or the registry's scheme with the defaults (and, for the default
    model, "eigh" checked against the kernel)."""
    if isinstance(integrator, Integrator):
        for name, given in (("jacobian", jacobian), ("phi_method", phi_method)):
            own = getattr(integrator, name, None)
            if given is not None and given != own:
                raise ValueError(
                    f"{name}={given!r} conflicts with the integrator instance's {name}={own!r}; "
                    f"set it when building the integrator (make_integrator(..., {name}=...))"
                )
        return integrator
    jacobian = DEFAULT_JACOBIAN if jacobian is None else jacobian
    phi_method = DEFAULT_PHI_METHOD if phi_method is None else phi_method
    scheme = make_integrator(integrator, jacobian=jacobian, phi_method=phi_method)
    if default_model:
        check_phi_method_fits_kernel(params, integrator, jacobian, phi_method)
    return scheme


def _model(params: SwarmParams, model: DriftModel | None, linear_operator: str | None) -> Any:
    """`simulate`'s drift model: `model`, or `SwarmModel(params, linear_operator or "auto")`
    (`linear_operator` only with the default model)."""
    if linear_operator is not None:
        check_linear_operator(linear_operator)
        if model is not None:
            raise ValueError(
                "linear_operator applies to the default SwarmModel; with model= given, build "
                "the model with its own linear_operator"
            )
    if model is None:
        model = SwarmModel(params, "auto" if linear_operator is None else linear_operator)
    return model


def _start_and_increments(
    params: SwarmParams,
    seed: int | np.random.Generator | None,
    initial_positions: Any,
    increments: Any,
    steps_and_paths: tuple[int, int],
    divergence_threshold: float,
) -> tuple[Any, Any]:
    """x^0 (N, d) and the increments (m, K, N, d) of `simulate`: given (checked) or drawn from
    the seed's two child generators (start, noise)."""
    n_steps, n_paths = steps_and_paths
    n, d = params.n_agents, params.dim
    init_rng, noise_rng = _generators(seed)
    if initial_positions is None:
        x0 = uniform_positions(init_rng, n, d)
    else:
        x0 = as_positions(initial_positions, n, d)
    if bool(np.any(arrays.to_numpy(diverged_paths(x0, divergence_threshold)))):
        raise ValueError(
            "initial_positions must lie inside the divergence threshold "
            f"(|x| <= {divergence_threshold:g})"
        )
    shape = (n_paths, n, d)
    if increments is None:
        increments = brownian_increments(noise_rng, (n_steps, *shape), params.horizon / n_steps)
    elif tuple(getattr(increments, "shape", np.shape(increments))) != (n_steps, *shape):
        raise ValueError(
            f"increments must have shape (n_steps, n_paths, N, d) = {(n_steps, *shape)}, "
            f"got {tuple(getattr(increments, 'shape', np.shape(increments)))}"
        )
    return x0, increments


def _integrate(
    scheme: Integrator,
    model: Any,
    x: Any,
    increments: Any,
    control: ControlSpec,
    control_rate: ControlSpec,
    loop: tuple[Any, np.ndarray, float, float],
) -> tuple[list[Any], list[Any], np.ndarray, int | None]:
    """The time loop of `simulate` from x^0 = x (K, N, d) with `loop` = (the array namespace,
    the time grid t_0 .. t_m, tau, the divergence threshold): (the states x^0 .. x^n up to the
    first divergence, the controls applied, the (K,) flags of the diverged paths, the step n
    at which some path diverged or None)."""
    xp, times, dt, divergence_threshold = loop
    n_steps = len(times) - 1
    states = [x]
    applied = []
    bad = np.zeros(x.shape[0], dtype=bool)
    divergence_step = None
    with arrays.hot_path_threads(), np.errstate(over="ignore", invalid="ignore"):
        for step in range(n_steps):
            t = float(times[step])
            u = _control_at(control, step, t, x, "control")
            du = _control_at(control_rate, step, t, x, "control_rate")
            applied.append(u)
            x = scheme.step(model, x, u, t, dt, increments[step], du_dt=du)
            flags = diverged_paths(x, divergence_threshold)
            if bool(xp.any(flags)):
                bad = arrays.to_numpy(flags)
                divergence_step = step + 1
                break
            states.append(x)
    return states, applied, bad, divergence_step


def _trajectory(
    params: SwarmParams,
    scheme: Integrator,
    xp: Any,
    times: np.ndarray,
    states: list[Any],
    applied: list[Any],
    bad: np.ndarray,
    divergence_step: int | None,
    wall: float,
) -> Trajectory:
    """The `Trajectory` of the loop's states and controls, padded to m + 1 states (NaN after
    a divergence) and m controls (zeros for no control)."""
    n_steps = len(times) - 1
    nan_state = arrays.asarray(np.full(tuple(states[0].shape), np.nan), like=states[0])
    zero_control = arrays.zeros(tuple(states[0].shape), like=states[0])
    states = states + [nan_state] * (n_steps + 1 - len(states))
    controls = [zero_control if u is None else u for u in applied]
    controls += [zero_control] * (n_steps - len(controls))
    return Trajectory(
        times=times,
        positions=xp.stack(states, axis=0),
        controls=xp.stack(controls, axis=0),
        diverged=divergence_step is not None,
        divergence_step=divergence_step,
        diverged_paths=bad,
        wall_time=wall,
        integrator=scheme.name,
        jacobian=getattr(scheme, "jacobian", None),
        params=params,
    )
