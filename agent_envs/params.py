"""Validated parameters of the swarm model.

`SwarmParams` holds everything that defines the controlled SDE (paper `eq:dynamics`) and its
running cost (paper `eq:running_cost`): the number of agents N, the dimension d, the
interaction kernel, the noise level, the horizon T, the target xbar and the control weight
gamma. It is a frozen dataclass; every field is checked in `__post_init__` and a bad value
raises `ValueError` (or `TypeError`) naming the field and its allowed range.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from agent_envs.validation import (
    ALPHA_RANGE,
    EPSILON_RANGE,
    GAMMA_RANGE,
    HORIZON_RANGE,
    MAX_AGENTS,
    MAX_STATE_SIZE,
    SIGMA_RANGE,
    TARGET_RANGE,
    check_int,
    check_positive,
    check_real,
    real_array,
)

# check_int, check_positive and check_real live in agent_envs.validation; they stay importable
# from here for the modules that import them from params.
__all__ = [
    "KERNEL_NAMES",
    "SwarmParams",
    "check_int",
    "check_positive",
    "check_real",
    "target_as_vector",
]

KERNEL_NAMES = ("symmetric", "nonsymmetric")


def target_as_vector(target: float | Sequence[float] | np.ndarray, dim: int) -> np.ndarray:
    """Return the target xbar as a float array of shape (dim,).

    A scalar is broadcast to every coordinate; a sequence must have length `dim`. Entries must
    be real numbers (`agent_envs.validation.real_array`: no bools, strings or complex numbers)
    in `TARGET_RANGE`. Raises `TypeError`/`ValueError` naming `target` otherwise.
    """
    arr = real_array("target", target)
    if arr.ndim == 0:
        arr = np.full(dim, float(arr))
    if arr.shape != (dim,):
        raise ValueError(f"target must be a scalar or have shape ({dim},), got shape {arr.shape}")
    if not np.all((arr >= TARGET_RANGE.low) & (arr <= TARGET_RANGE.high)):
        raise ValueError(f"target entries must lie in {TARGET_RANGE}, got {arr}")
    return arr


@dataclass(frozen=True)
class SwarmParams:
    """Parameters of the controlled swarm SDE and its cost.

    The accepted ranges come from `agent_envs.validation`, which derives them.

    Attributes:
        n_agents: 2 <= N <= 1e7, the number of agents.
        dim: d >= 1 with N d <= 1e7, the dimension of each agent's position (the paper uses
            d = 1).
        kernel: ``"symmetric"`` for ``p(x, y) = 1/(eps (alpha^2 + |x-y|^2))`` (`eq:symmker`),
            ``"nonsymmetric"`` for ``p(x_k, x_l) = 1/(eps_l (alpha^2 + |x_k-x_l|^2))`` with
            ``eps_l = eps_min + (eps_max - eps_min)(l-1)/(N-1)`` (`eq:nonsymmker`), or an object
            following `agent_envs.dynamics.kernels.InteractionKernel`.
        alpha: alpha in [1e-6, 1e6], the kernel's length scale.
        epsilon: eps in [1e-12, 1e12], the symmetric kernel's stiffness (small eps = stiff).
        epsilon_min: eps_min in [1e-12, 1e12], the smallest eps_l of the non-symmetric
            kernel (eps_min <= eps_max).
        epsilon_max: eps_max in [1e-12, 1e12], the largest eps_l of the non-symmetric kernel.
        sigma: sigma in [0, 1e6], the additive noise level.
        horizon: T in [1e-6, 1e6], the final time (the start time is t0 = 0).
        target: xbar, a scalar (broadcast to all d coordinates) or a length-d sequence, entries
            in [-1e6, 1e6] (the envs also need |xbar| < divergence_threshold).
        gamma: gamma in [0, 1e6], the control weight of the running cost (the paper gives no
            value; 0.01 is our default).
    """

    n_agents: int = 100
    dim: int = 1
    kernel: Any = "symmetric"
    alpha: float = 0.1
    epsilon: float = 0.05
    epsilon_min: float = 1e-2
    epsilon_max: float = 1e-1
    sigma: float = 0.01
    horizon: float = 1.0
    target: Any = 0.7
    gamma: float = 0.01

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        n_agents = check_int("n_agents", self.n_agents, 2, MAX_AGENTS)
        set_(self, "n_agents", n_agents)
        try:
            dim = check_int("dim", self.dim, 1, MAX_STATE_SIZE // n_agents)
        except ValueError as exc:
            raise ValueError(f"{exc} (n_agents * dim must be <= {MAX_STATE_SIZE:.0e})") from None
        set_(self, "dim", dim)
        if isinstance(self.kernel, str):
            if self.kernel not in KERNEL_NAMES:
                raise ValueError(
                    f"kernel must be one of {KERNEL_NAMES} or an InteractionKernel object, "
                    f"got {self.kernel!r}"
                )
        else:
            needed = ("value", "grad_x", "grad_y", "symmetric")
            missing = [m for m in needed if not hasattr(self.kernel, m)]
            if missing:
                raise TypeError(
                    "kernel must be 'symmetric', 'nonsymmetric' or an object with methods "
                    "value, grad_x, grad_y and a bool attribute symmetric (InteractionKernel); "
                    f"missing {missing}"
                )
        set_(self, "alpha", check_positive("alpha", self.alpha, ALPHA_RANGE))
        for name in ("epsilon", "epsilon_min", "epsilon_max"):
            set_(self, name, check_positive(name, getattr(self, name), EPSILON_RANGE))
        if self.epsilon_max < self.epsilon_min:
            raise ValueError(
                f"epsilon_max must be >= epsilon_min, got epsilon_min={self.epsilon_min}, "
                f"epsilon_max={self.epsilon_max}"
            )
        set_(self, "sigma", check_real("sigma", self.sigma, SIGMA_RANGE))
        set_(self, "horizon", check_positive("horizon", self.horizon, HORIZON_RANGE))
        tgt = target_as_vector(self.target, self.dim)
        set_(self, "target", float(tgt[0]) if self.dim == 1 else tuple(float(v) for v in tgt))
        set_(self, "gamma", check_real("gamma", self.gamma, GAMMA_RANGE))

    @property
    def target_vector(self) -> np.ndarray:
        """The target xbar as an array of shape (d,)."""
        return target_as_vector(self.target, self.dim)

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        """Names of all fields, in order (the env keyword arguments that map to params)."""
        return tuple(f.name for f in fields(cls))
