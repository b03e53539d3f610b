"""The optimal open-loop control of the fully discrete problem, by L-BFGS-B on autodiff gradients.

Problem (`eq:discrete_cost_functional`, with the expectation replaced by the sample mean over K
Brownian paths, as the paper's experiments do):

    V = min_{u^0..u^{m-1}}  (1/K) sum_{j=1}^K  tau sum_{n=0}^{m-1} c(x^{n,j}, u^n),
        c(x, u) = (1/N) sum_k (|x_k - xbar|^2 + gamma |u_k|^2)            (`eq:running_cost`)

subject to x^{n+1,j} = one step of the chosen integrator (SERB `eq:serb` with the frozen
linearization L(x) by default; EM, EE, Heun, ERB, exact Jacobian selectable) from x^{0,j} = x^0
with the Brownian increments `agent_envs.simulator.simulate` draws for `seed`, and the box
|u_k^n| <= max_control on every coordinate (the env's action bound). The control is open loop:
one deterministic sequence u^n of shape (N, d) for all K paths, as in the paper.

Gradient: reverse-mode automatic differentiation (torch, float64) through the core's own
integrator (`simulate` on torch tensors): one forward simulation plus its backward pass, no
second copy of the dynamics. Optimizer: `scipy.optimize.minimize(method="L-BFGS-B")`, the
standard quasi-Newton method for smooth problems with box bounds (Byrd, Lu, Nocedal, Zhu 1995),
started from `initial_controls` (a warm start) or u = 0.

Convergence: the projected gradient g (components that push against an active bound zeroed)
must satisfy max|g| <= gtol * max|g(u = 0)|, i.e. the gradient has been reduced by the factor
gtol relative to the uncontrolled start (`relative_gradient_norm`). Otherwise a RuntimeWarning
is issued and `converged` is False. A non-finite cost or gradient at u = 0 or at the returned
control is a failed solve, never a converged one (`converged=False`, the reason in `failure`):
the objective stands in a penalty with a zero gradient there, which would otherwise pass the
gradient test after 0 iterations (stiff EM, whose backward pass overflows).

torch is needed only here (the `train` extra) and is imported when solving. The solve runs
torch with `threads` intra-op threads (default 1, restored afterwards): these problems are many
small batched matrix operations, where extra threads mostly add synchronisation (measured in
docs/benchmarks.md, "The optimal-control solver").
"""

from __future__ import annotations

import contextlib
import time
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from agent_envs.costs import discrete_cost
from agent_envs.dynamics.swarm import kernel_from_params
from agent_envs.params import SwarmParams, check_int, check_positive
from agent_envs.simulator import (
    DEFAULT_INTEGRATOR,
    DEFAULT_JACOBIAN,
    DEFAULT_MAX_CONTROL,
    DEFAULT_N_STEPS,
    SAMPLE_AVERAGE_PATHS,
    simulate,
)

#: default tolerance on the relative projected gradient norm
DEFAULT_GTOL = 1e-6
#: default cap on L-BFGS-B iterations
DEFAULT_MAX_ITERATIONS = 500
#: L-BFGS-B memory (number of stored correction pairs)
DEFAULT_MEMORY = 20


def import_torch() -> Any:
    """torch, or an ImportError that names the `train` extra."""
    try:
        import torch
    except ImportError as exc:  # pragma: no cover - depends on the installation
        raise ImportError(
            "solve_optimal_control needs torch for its gradients; install the 'train' extra: "
            "pip install 'agent-envs[train]'"
        ) from exc
    return torch


@contextlib.contextmanager
def torch_threads(torch: Any, threads: int | None) -> Iterator[None]:
    """Run the block with `threads` torch intra-op threads (None: leave torch's setting)."""
    if threads is None:
        yield
        return
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


@dataclass(frozen=True)
class OptimalControlResult:
    """What `solve_optimal_control` found.

    Attributes:
        controls: (m, N, d) the open-loop control u^0..u^{m-1} (the same for every path).
        positions: (m + 1, K, N, d) the state under it, on the Brownian increments `simulate`
            draws for the seed (computed by the numpy `simulate`).
        cost: the discrete cost functional on those paths (`agent_envs.costs.discrete_cost`,
            mean over the K paths): the value V when converged.
        converged: whether the relative projected gradient norm reached `gtol`.
        iterations: L-BFGS-B iterations.
        evaluations: objective + gradient evaluations (forward + backward simulations).
        gradient_norm: max |projected gradient| of the cost at `controls`.
        relative_gradient_norm: `gradient_norm` / the same at u = 0.
        initial_cost: the cost at the start (`initial_controls` or 0).
        message: the optimizer's own stopping message.
        wall_time: seconds spent in the solve.
        times: (m + 1,) the time grid.
        failure: why the solve failed numerically (a non-finite cost or gradient at u = 0 or
            at `controls`, or a diverged final simulation), else None; a failed solve is
            never `converged`.
    """

    controls: np.ndarray
    positions: np.ndarray
    cost: float
    converged: bool
    iterations: int
    evaluations: int
    gradient_norm: float
    relative_gradient_norm: float
    initial_cost: float
    message: str
    wall_time: float
    times: np.ndarray
    failure: str | None = None

    @property
    def mean_positions(self) -> np.ndarray:
        """E x^n over the paths: (m + 1, N, d)."""
        return self.positions.mean(axis=1)


def projected_gradient(u: np.ndarray, grad: np.ndarray, bound: float) -> np.ndarray:
    """The gradient with the components that push against an active bound |u| = bound zeroed."""
    at_upper = (u >= bound) & (grad < 0.0)
    at_lower = (u <= -bound) & (grad > 0.0)
    return np.where(at_upper | at_lower, 0.0, grad)


class DiscreteCostObjective:
    """u (flat, m N d) -> (cost, d cost / d u) by autodiff through the core's torch `simulate`.

    Every call simulates the K paths from x^0 with the increments of `seed` (the same on every
    call: the sample-average problem is deterministic) and back-propagates the sample-mean
    discrete cost, on the torch `device` (default CPU). A diverged forward simulation
    (non-finite cost) or a non-finite gradient returns `penalty` and a zero gradient, so the
    line search backs off; `last_failure` says which (None after a finite evaluation).
    """

    def __init__(
        self,
        params: SwarmParams,
        integrator: str,
        jacobian: str,
        phi_method: str,
        n_steps: int,
        n_paths: int,
        seed: int,
        initial_positions: np.ndarray,
        penalty: float = 1e10,
        device: Any = None,
    ) -> None:
        self.torch = import_torch()
        self.params = params
        self.integrator = integrator
        self.jacobian = jacobian
        self.phi_method = phi_method
        self.n_steps = n_steps
        self.n_paths = n_paths
        self.seed = seed
        self.shape = (n_steps, params.n_agents, params.dim)
        self.device = self.torch.device("cpu" if device is None else device)
        f64 = self.torch.float64
        self.x0 = self.torch.as_tensor(initial_positions, dtype=f64, device=self.device)
        self.target = self.torch.as_tensor(params.target_vector, dtype=f64, device=self.device)
        self.dt = params.horizon / n_steps
        self.penalty = float(penalty)
        self.evaluations = 0
        self.last_failure: str | None = None
        self._warned_gradient = False

    def _gradient_hint(self) -> str:
        """What to try after a non-finite gradient: an exponential integrator for an explicit
        one (EM's gradient at a stiff eps overflows, 1e15-1e16 at eps = 0.05), else the other
        phi-methods."""
        if self.integrator not in ("erb", "serb"):
            return "try integrator='serb': an explicit scheme's gradient overflows when stiff"
        others = [m for m in ("eigh", "expm", "krylov") if m != self.phi_method]
        return "try phi_method=" + " or ".join(repr(m) for m in others)

    def cost(self, controls: Any) -> Any:
        """The sample-mean discrete cost as a torch scalar (differentiable in `controls`)."""
        torch = self.torch
        traj = simulate(
            self.params,
            self.integrator,
            jacobian=self.jacobian,
            phi_method=self.phi_method,
            n_steps=self.n_steps,
            n_paths=self.n_paths,
            seed=self.seed,
            initial_positions=self.x0,
            control=controls,
        )
        costs = discrete_cost(
            traj.positions, traj.controls, self.target, self.params.gamma, self.dt
        )
        return torch.mean(costs)

    def __call__(self, flat: np.ndarray) -> tuple[float, np.ndarray]:
        torch = self.torch
        self.evaluations += 1
        u = torch.tensor(
            flat.reshape(self.shape), dtype=torch.float64, device=self.device, requires_grad=True
        )
        value = self.cost(u)
        self.last_failure = None
        if not bool(torch.isfinite(value)):
            self.last_failure = "non-finite cost (the simulation diverged)"
            return self.penalty, np.zeros_like(flat)
        value.backward()
        grad = u.grad.detach().cpu().numpy().reshape(-1)
        if not np.all(np.isfinite(grad)):
            self.last_failure = (
                f"finite cost {float(value.detach()):.6g} but a non-finite gradient "
                "(the backward pass overflowed or failed)"
            )
            if not self._warned_gradient:
                self._warned_gradient = True
                warnings.warn(
                    f"finite cost {float(value.detach()):.6g} but a non-finite gradient with "
                    f"integrator={self.integrator!r}, phi_method={self.phi_method!r}: the "
                    f"backward pass failed; treated as a diverged step ({self._gradient_hint()})",
                    RuntimeWarning,
                    stacklevel=2,
                )
            return self.penalty, np.zeros_like(flat)
        return float(value.detach()), grad.astype(float)


@dataclass(frozen=True)
class BoxMinimization:
    """L-BFGS-B's result with our convergence measure (see `minimize_in_box`)."""

    result: Any
    gradient_norm: float
    relative: float
    f_start: float
    failure: str | None = None


def minimize_in_box(
    objective: Any,
    start: np.ndarray,
    bound: float,
    gtol: float,
    max_iterations: int,
    memory: int,
) -> BoxMinimization:
    """L-BFGS-B on |u_i| <= bound from `start`, stopped at the relative KKT residual `gtol`.

    `objective(flat) -> (value, gradient)`. The reference is max|projected gradient| at u = 0.
    When the objective has an attribute `last_failure` (a reason, or None after a finite
    evaluation), a failure at u = 0 or at the returned point is the result's `failure`.
    """
    import scipy.optimize

    def evaluate(flat: np.ndarray) -> tuple[tuple[float, np.ndarray], str | None]:
        value = objective(flat)
        return value, getattr(objective, "last_failure", None)

    (f_start, g_start), start_failure = evaluate(start)
    if np.any(start != 0.0):
        (_, g_zero), zero_failure = evaluate(np.zeros(start.size))
    else:
        g_zero, zero_failure = g_start, start_failure
    reference = float(np.max(np.abs(projected_gradient(np.zeros(start.size), g_zero, bound))))
    cache = {"x": start.copy(), "value": (f_start, g_start), "failure": start_failure}

    def fun(flat: np.ndarray) -> tuple[float, np.ndarray]:
        if not np.array_equal(flat, cache["x"]):
            cache["x"] = flat.copy()
            cache["value"], cache["failure"] = evaluate(flat)
        return cache["value"]

    def stop_when_converged(flat: np.ndarray) -> None:
        # L-BFGS-B's own test caps each projected component by the distance to its bound,
        # which is not scale-free; our test is the relative KKT residual (module docstring).
        grad = fun(flat)[1]
        if np.max(np.abs(projected_gradient(flat, grad, bound))) <= gtol * reference:
            raise StopIteration

    result = scipy.optimize.minimize(
        fun,
        start,
        jac=True,
        method="L-BFGS-B",
        bounds=scipy.optimize.Bounds(-bound, bound),
        callback=stop_when_converged,
        options={
            "maxiter": max_iterations,
            "maxfun": 10 * max_iterations,
            "maxcor": memory,
            "ftol": 0.0,
            "gtol": 0.0,
        },
    )
    grad = fun(result.x)[1]
    grad_norm = float(np.max(np.abs(projected_gradient(result.x, grad, bound))))
    relative = grad_norm / reference if reference > 0 else (0.0 if grad_norm == 0 else np.inf)
    failure = None
    if zero_failure is not None:
        failure = f"at u = 0: {zero_failure}"
    elif cache["failure"] is not None:
        failure = f"at the returned control: {cache['failure']}"
    return BoxMinimization(result, grad_norm, float(relative), float(f_start), failure)


def differentiated_phi_method(params: SwarmParams, jacobian: str, phi_method: str | None) -> str:
    """The phi strategy the differentiated simulations use.

    An explicit `phi_method` is kept. For None/"auto", the dense strategies whose gradients are
    tested against finite differences: "eigh" when the linearization is symmetric (symmetric
    kernel; with the exact Jacobian also radial), "expm" otherwise. "auto" would pick Krylov
    for large batched problems, whose torch backward gave non-finite gradients at N = 100 with
    20 paths (docs/benchmarks.md, "The optimal-control solver"). The final `simulate` that
    produces `positions` and `cost` uses the caller's `phi_method`, so the cost contract holds
    either way.
    """
    if phi_method not in (None, "auto"):
        return phi_method
    kernel = kernel_from_params(params)
    symmetric = bool(kernel.symmetric)
    if jacobian == "exact":
        symmetric = symmetric and bool(getattr(kernel, "radial", False))
    return "eigh" if symmetric else "expm"


def _initial_controls(initial_controls: Any, shape: tuple[int, ...], bound: float) -> np.ndarray:
    if initial_controls is None:
        return np.zeros(shape)
    arr = np.asarray(initial_controls, dtype=float)
    if arr.ndim == 2 and shape[-1] == 1:
        arr = arr[..., None]
    if arr.shape != shape:
        raise ValueError(
            f"initial_controls must have shape (n_steps, N, d) = {shape}, got {np.shape(arr)}"
        )
    if not np.all(np.isfinite(arr)):
        raise ValueError("initial_controls must be finite")
    return np.clip(arr, -bound, bound)


def _check_solver_options(
    seed: Any, max_control: float, gtol: float, max_iterations: int, memory: int, threads: Any
) -> tuple[float, float, int, int, int | None]:
    """The solver's own options checked: (bound, gtol, max_iterations, memory, threads).

    The seed must be an int (not a generator): every evaluation draws the same increments.
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise TypeError(
            f"seed must be an int (the same increments are drawn on every evaluation), got {seed!r}"
        )
    bound = check_positive("max_control", max_control)
    gtol = check_positive("gtol", gtol)
    max_iterations = check_int("max_iterations", max_iterations, 1)
    memory = check_int("memory", memory, 1)
    if threads is not None:
        threads = check_int("threads", threads, 1)
    return bound, gtol, max_iterations, memory, threads


def _start_positions(
    params: SwarmParams,
    integrator: str,
    jacobian: str,
    phi_method: str | None,
    n_steps: int,
    seed: int,
    initial_positions: Any,
) -> np.ndarray:
    """x^0 (N, d): `initial_positions`, or drawn uniform on [-1, 1]^d from the seed.

    The numpy simulate (one path) validates everything else with its own messages (params,
    integrator, jacobian, phi_method, n_steps, seed, initial_positions) and draws x^0 if needed.
    """
    probe = simulate(
        params,
        integrator,
        jacobian=jacobian,
        phi_method=phi_method,
        n_steps=n_steps,
        n_paths=1,
        seed=seed,
        initial_positions=initial_positions,
    )
    return probe.positions[0, 0]


def _evaluate_controls(
    params: SwarmParams,
    integrator: str,
    jacobian: str,
    phi_method: str | None,
    n_steps: int,
    n_paths: int,
    seed: int,
    x0: np.ndarray,
    controls: np.ndarray,
) -> tuple[Any, float]:
    """(trajectory, cost) of the controls u (m, N, d) on the solver's K paths, with numpy.

    The cost is the sample mean over the K paths of `eq:discrete_cost_functional` with
    tau = T / m, on the caller's `phi_method` (the returned trajectory's contract).
    """
    final = simulate(
        params,
        integrator,
        jacobian=jacobian,
        phi_method=phi_method,
        n_steps=n_steps,
        n_paths=n_paths,
        seed=seed,
        initial_positions=x0,
        control=controls,
    )
    cost = float(
        np.mean(
            discrete_cost(
                final.positions,
                final.controls,
                params.target_vector,
                params.gamma,
                params.horizon / n_steps,
            )
        )
    )
    return final, cost


def _warn_not_converged(relative: float, gtol: float, failure: str | None, result: Any) -> None:
    """A RuntimeWarning naming why the solve stopped (attributed to solve_optimal_control's
    caller, as before this was a function: stacklevel 3)."""
    why = (
        f"relative projected gradient norm {relative:.3g} > gtol = {gtol:g}"
        if failure is None
        else f"failed: {failure}"
    )
    warnings.warn(
        f"solve_optimal_control did not converge: {why} after {result.nit} iterations "
        f"({result.message})",
        RuntimeWarning,
        stacklevel=3,
    )


def solve_optimal_control(
    params: SwarmParams,
    integrator: str = DEFAULT_INTEGRATOR,
    *,
    jacobian: str = DEFAULT_JACOBIAN,
    phi_method: str | None = None,
    n_steps: int = DEFAULT_N_STEPS,
    n_paths: int = SAMPLE_AVERAGE_PATHS,
    seed: int = 0,
    initial_positions: Any = None,
    max_control: float = DEFAULT_MAX_CONTROL,
    initial_controls: Any = None,
    gtol: float = DEFAULT_GTOL,
    max_iterations: int = DEFAULT_MAX_ITERATIONS,
    memory: int = DEFAULT_MEMORY,
    threads: int | None = 1,
    device: Any = None,
    warn: bool = True,
) -> OptimalControlResult:
    """Minimize the sample-mean discrete cost over open-loop controls (module docstring).

    Args:
        params: the model (N, d, kernel, sigma, T, xbar, gamma).
        integrator: "serb" (default), "erb", "em", "ee" or "heun": the scheme of the dynamics.
        jacobian: "frozen" (default) or "exact", for "erb"/"serb".
        phi_method: as in `simulate` (default "auto" for the returned trajectory; the
            differentiated simulations use `differentiated_phi_method`).
        n_steps: m >= 1 (tau = T / m).
        n_paths: K >= 1 Brownian paths (sigma = 0 needs only 1).
        seed: int >= 0; the paths are `simulate(..., seed=seed)`'s.
        initial_positions: x^0, (N,) or (N, d); default uniform on [-1, 1]^d from the seed.
        max_control: the bound on every coordinate of u (> 0).
        initial_controls: warm start, (m, N, d) (clipped to the bound); default 0.
        gtol: stop when max|projected gradient| <= gtol * max|gradient at u = 0|.
        max_iterations: cap on L-BFGS-B iterations.
        memory: L-BFGS-B memory.
        threads: torch intra-op threads during the solve (None: torch's own setting).
        device: the torch device of the forward/backward simulations ("cpu" default, "cuda").
        warn: issue a RuntimeWarning when not converged (set False for capped MPC re-solves).

    Returns:
        an `OptimalControlResult`.
    """
    bound, gtol, max_iterations, memory, threads = _check_solver_options(
        seed, max_control, gtol, max_iterations, memory, threads
    )
    x0 = _start_positions(
        params, integrator, jacobian, phi_method, n_steps, seed, initial_positions
    )
    shape = (n_steps, params.n_agents, params.dim)
    start = _initial_controls(initial_controls, shape, bound)
    began = time.perf_counter()
    objective = DiscreteCostObjective(
        params,
        integrator,
        jacobian,
        differentiated_phi_method(params, jacobian, phi_method),
        n_steps,
        n_paths,
        int(seed),
        x0,
        device=device,
    )
    with torch_threads(objective.torch, threads):
        run = minimize_in_box(objective, start.reshape(-1), bound, gtol, max_iterations, memory)
    result, grad_norm, relative, f_start = run.result, run.gradient_norm, run.relative, run.f_start
    failure = run.failure
    controls = np.clip(result.x, -bound, bound).reshape(shape)
    wall = time.perf_counter() - began
    final, cost = _evaluate_controls(
        params, integrator, jacobian, phi_method, n_steps, n_paths, seed, x0, controls
    )
    # a diverged final state makes the objective return its penalty with a zero gradient
    if failure is None and (final.diverged or not np.isfinite(cost)):
        failure = "the final simulation diverged (non-finite or exploding state)"
    converged = bool(relative <= gtol) and failure is None
    if not converged and warn:
        _warn_not_converged(relative, gtol, failure, result)
    return OptimalControlResult(
        controls=controls,
        positions=final.positions,
        cost=cost,
        converged=converged,
        iterations=int(result.nit),
        evaluations=objective.evaluations,
        gradient_norm=grad_norm,
        relative_gradient_norm=float(relative),
        initial_cost=float(f_start),
        message=str(result.message),
        wall_time=wall,
        times=final.times,
        failure=failure,
    )
