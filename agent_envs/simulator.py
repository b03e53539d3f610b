"""Batches of Brownian paths: initial states, noise, stepping, divergence detection.

All randomness comes from a `numpy.random.Generator` passed in (the env's `self.np_random`) or
built from a seed; integrators never draw. `simulate` spawns two independent child generators
from the seed, one for the initial positions and one for the Brownian increments, so giving
`initial_positions` does not change the noise, and every integrator sees the same increments
for the same seed.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from agent_envs.dynamics.swarm import SwarmModel, kernel_from_params
from agent_envs.integrators import DEFAULT_JACOBIAN, Integrator, make_integrator
from agent_envs.params import SwarmParams
from agent_envs.validation import (
    DIVERGENCE_THRESHOLD_RANGE,
    MAX_BATCH_SIZE,
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

ControlSpec = None | np.ndarray | Callable[[float, np.ndarray], np.ndarray]


def as_positions(positions: Any, n_agents: int, dim: int, name: str = "initial_positions"):
    """Validate positions of shape (N,) (only for d = 1) or (N, d); return (N, d) floats.

    Entries must be finite real numbers (`agent_envs.validation.real_array`: strings, bools and
    complex numbers raise `TypeError` naming `name`).
    """
    arr = real_array(name, positions)
    if arr.ndim == 1 and dim == 1:
        arr = arr[:, None]
    if arr.shape != (n_agents, dim):
        allowed = f"({n_agents},) or ({n_agents}, 1)" if dim == 1 else f"({n_agents}, {dim})"
        raise ValueError(f"{name} must have shape {allowed}, got {arr.shape}")
    return arr


def uniform_positions(rng: np.random.Generator, n_agents: int, dim: int) -> np.ndarray:
    """N agents drawn uniform on [-1, 1]^d (the paper's start); shape (N, d)."""
    return rng.uniform(-1.0, 1.0, size=(n_agents, dim))


def brownian_increments(rng: np.random.Generator, shape: tuple[int, ...], dt: float):
    """Increments dW ~ N(0, dt I) of the given shape."""
    return np.sqrt(dt) * rng.standard_normal(shape)


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


def diverged_paths(x: np.ndarray, threshold: float = DEFAULT_DIVERGENCE_THRESHOLD) -> np.ndarray:
    """Per path (leading axes of x (..., N, d)): True if non-finite or max |x| > threshold."""
    bad = ~np.isfinite(x) | (np.abs(x) > threshold)
    return np.any(bad, axis=(-2, -1))


def _control_at(control: ControlSpec, n: int, t: float, x: np.ndarray, name: str) -> Any:
    if control is None:
        return None
    if callable(control):
        u = real_array(f"{name} at step {n}", control(t, x))
    else:
        u = control[n]
    try:
        u = np.broadcast_to(u, x.shape)
    except ValueError:
        raise ValueError(
            f"{name} at step {n} has shape {np.shape(u)}, which does not broadcast to the "
            f"state shape {x.shape}"
        ) from None
    if not np.all(np.isfinite(u)):
        raise ValueError(f"{name} at step {n} is not finite")
    return u


def _validate_control_array(control: Any, n_steps: int, n_agents: int, dim: int, name: str):
    if control is None or callable(control):
        return control
    arr = real_array(name, control)
    if dim == 1 and arr.ndim == 2:
        arr = arr[..., None]
    if arr.ndim not in (3, 4) or arr.shape[0] != n_steps or arr.shape[-2:] != (n_agents, dim):
        raise ValueError(
            f"{name} must be None, a callable(t, x) -> u, or an array of shape "
            f"(n_steps, N, d) = ({n_steps}, {n_agents}, {dim}) or (n_steps, n_paths, N, d); "
            f"got shape {np.shape(control)}"
        )
    return arr


@dataclass
class Trajectory:
    """The result of `simulate`.

    Attributes:
        times: (m + 1,) the time grid t_n = n tau.
        positions: (m + 1, n_paths, N, d). When a path diverges, integration stops and the rows
            after `divergence_step` are NaN (flagged by `diverged`, never silent).
        controls: (m, n_paths, N, d) the control applied on each step (zeros for no control).
        diverged: True if any path became non-finite or exceeded `divergence_threshold`.
        divergence_step: the first step index n at which a path diverged, else None.
        diverged_paths: (n_paths,) which paths diverged.
        wall_time: seconds spent integrating.
    """

    times: np.ndarray
    positions: np.ndarray
    controls: np.ndarray
    diverged: bool
    divergence_step: int | None
    diverged_paths: np.ndarray
    wall_time: float
    integrator: str
    jacobian: str | None
    params: SwarmParams = field(repr=False)

    @property
    def mean_positions(self) -> np.ndarray:
        """Positions averaged over the Brownian paths: (m + 1, N, d)."""
        return self.positions.mean(axis=1)


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
    integrator: str | Integrator = "serb",
    *,
    jacobian: str | None = None,
    n_steps: int = 50,
    n_paths: int = 20,
    seed: int | np.random.Generator | None = None,
    initial_positions: Any = None,
    control: ControlSpec = None,
    control_rate: ControlSpec = None,
    phi_method: str | None = None,
    divergence_threshold: float = DEFAULT_DIVERGENCE_THRESHOLD,
) -> Trajectory:
    """Integrate the swarm SDE on [0, T] with m = `n_steps` steps for `n_paths` Brownian paths.

    Args:
        params: the model.
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

    Bad arguments raise `TypeError`/`ValueError` naming them and their accepted ranges (see
    `agent_envs.validation`). Controls are checked for a real dtype and finiteness; a control
    so large that the state leaves R is reported by `diverged`, not rejected.
    """
    if not isinstance(params, SwarmParams):
        raise TypeError(f"params must be a SwarmParams, got {type(params).__name__}")
    n_steps = check_int("n_steps", n_steps, 1, MAX_STEPS)
    n_paths = check_int("n_paths", n_paths, 1, MAX_PATHS)
    state_size = params.n_agents * params.dim
    check_size("n_paths", n_paths, n_paths * state_size, MAX_BATCH_SIZE, "n_paths * N * d")
    divergence_threshold = check_positive(
        "divergence_threshold", divergence_threshold, DIVERGENCE_THRESHOLD_RANGE
    )
    if isinstance(integrator, Integrator):
        scheme = integrator
        for name, given in (("jacobian", jacobian), ("phi_method", phi_method)):
            own = getattr(scheme, name, None)
            if given is not None and given != own:
                raise ValueError(
                    f"{name}={given!r} conflicts with the integrator instance's {name}={own!r}; "
                    f"set it when building the integrator (make_integrator(..., {name}=...))"
                )
    else:
        jacobian = DEFAULT_JACOBIAN if jacobian is None else jacobian
        phi_method = "auto" if phi_method is None else phi_method
        scheme = make_integrator(integrator, jacobian=jacobian, phi_method=phi_method)
        check_phi_method_fits_kernel(params, integrator, jacobian, phi_method)
    n, d = params.n_agents, params.dim
    control = _validate_control_array(control, n_steps, n, d, "control")
    control_rate = _validate_control_array(control_rate, n_steps, n, d, "control_rate")
    model = SwarmModel(params)
    init_rng, noise_rng = _generators(seed)
    if initial_positions is None:
        x0 = uniform_positions(init_rng, n, d)
    else:
        x0 = as_positions(initial_positions, n, d)
        if np.any(diverged_paths(x0, divergence_threshold)):
            raise ValueError(
                "initial_positions must lie inside the divergence threshold "
                f"(|x| <= {divergence_threshold:g})"
            )

    dt = params.horizon / n_steps
    times = np.linspace(0.0, params.horizon, n_steps + 1)
    positions = np.full((n_steps + 1, n_paths, n, d), np.nan)
    controls = np.zeros((n_steps, n_paths, n, d))
    x = np.broadcast_to(x0, (n_paths, n, d)).copy()
    positions[0] = x
    bad = np.zeros(n_paths, dtype=bool)
    divergence_step = None
    start = time.perf_counter()
    for step in range(n_steps):
        t = times[step]
        u = _control_at(control, step, t, x, "control")
        du = _control_at(control_rate, step, t, x, "control_rate")
        if u is not None:
            controls[step] = u
        dw = brownian_increments(noise_rng, x.shape, dt)
        with np.errstate(over="ignore", invalid="ignore"):
            x = scheme.step(model, x, u, t, dt, dw, du_dt=du)
        bad = diverged_paths(x, divergence_threshold)
        if np.any(bad):
            divergence_step = step + 1
            break
        positions[step + 1] = x
    wall = time.perf_counter() - start
    return Trajectory(
        times=times,
        positions=positions,
        controls=controls,
        diverged=divergence_step is not None,
        divergence_step=divergence_step,
        diverged_paths=bad,
        wall_time=wall,
        integrator=scheme.name,
        jacobian=getattr(scheme, "jacobian", None),
        params=params,
    )
