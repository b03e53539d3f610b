"""Validated parameters of the swarm model.

`SwarmParams` holds everything that defines the controlled SDE (paper `eq:dynamics`) and its
running cost (paper `eq:running_cost`): the number of agents N, the dimension d, the
interaction kernel, the noise level, the horizon T, the target xbar and the control weight
gamma. It is a frozen dataclass; every field is checked in `__post_init__` and a bad value
raises `ValueError` (or `TypeError`) naming the field and its allowed range.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

KERNEL_NAMES = ("symmetric", "nonsymmetric")


def check_real(name: str, value: Any) -> float:
    """`value` as a finite float; TypeError/ValueError naming `name` otherwise."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value}")
    return value


def check_positive(name: str, value: Any) -> float:
    """`value` as a finite float > 0; TypeError/ValueError naming `name` otherwise."""
    value = check_real(name, value)
    if value <= 0.0:
        raise ValueError(f"{name} must be > 0, got {value}")
    return value


def check_int(name: str, value: Any, minimum: int) -> int:
    """`value` as an int >= minimum (bools rejected); TypeError/ValueError naming `name`."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be an integer, got {type(value).__name__}")
    if value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value}")
    return int(value)


def target_as_vector(target: float | Sequence[float] | np.ndarray, dim: int) -> np.ndarray:
    """Return the target xbar as a float array of shape (dim,).

    A scalar is broadcast to every coordinate; a sequence must have length `dim` and finite
    entries. Raises `ValueError` naming `target` otherwise.
    """
    arr = np.asarray(target, dtype=float)
    if arr.ndim == 0:
        arr = np.full(dim, float(arr))
    if arr.shape != (dim,):
        raise ValueError(f"target must be a scalar or have shape ({dim},), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"target must be finite, got {arr}")
    return arr


@dataclass(frozen=True)
class SwarmParams:
    """Parameters of the controlled swarm SDE and its cost.

    Attributes:
        n_agents: N >= 2, the number of agents.
        dim: d >= 1, the dimension of each agent's position (the paper uses d = 1).
        kernel: ``"symmetric"`` for ``p(x, y) = 1/(eps (alpha^2 + |x-y|^2))`` (`eq:symmker`),
            ``"nonsymmetric"`` for ``p(x_k, x_l) = 1/(eps_l (alpha^2 + |x_k-x_l|^2))`` with
            ``eps_l = eps_min + (eps_max - eps_min)(l-1)/(N-1)`` (`eq:nonsymmker`), or an object
            following `agent_envs.dynamics.kernels.InteractionKernel`.
        alpha: alpha > 0, the kernel's length scale.
        epsilon: eps > 0, the symmetric kernel's stiffness (small eps = stiff).
        epsilon_min, epsilon_max: 0 < eps_min <= eps_max, range of the non-symmetric kernel.
        sigma: sigma >= 0, the additive noise level.
        horizon: T > 0, the final time (the start time is t0 = 0).
        target: xbar, a scalar (broadcast to all d coordinates) or a length-d sequence.
        gamma: gamma >= 0, the control weight of the running cost (the paper gives no value;
            0.01 is our default).
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
        set_(self, "n_agents", check_int("n_agents", self.n_agents, 2))
        set_(self, "dim", check_int("dim", self.dim, 1))
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
        set_(self, "alpha", check_positive("alpha", self.alpha))
        set_(self, "epsilon", check_positive("epsilon", self.epsilon))
        set_(self, "epsilon_min", check_positive("epsilon_min", self.epsilon_min))
        set_(self, "epsilon_max", check_positive("epsilon_max", self.epsilon_max))
        if self.epsilon_max < self.epsilon_min:
            raise ValueError(
                f"epsilon_max must be >= epsilon_min, got epsilon_min={self.epsilon_min}, "
                f"epsilon_max={self.epsilon_max}"
            )
        sigma = check_real("sigma", self.sigma)
        if sigma < 0.0:
            raise ValueError(f"sigma must be >= 0, got {sigma}")
        set_(self, "sigma", sigma)
        set_(self, "horizon", check_positive("horizon", self.horizon))
        tgt = target_as_vector(self.target, self.dim)
        set_(self, "target", float(tgt[0]) if self.dim == 1 else tuple(float(v) for v in tgt))
        gamma = check_real("gamma", self.gamma)
        if gamma < 0.0:
            raise ValueError(f"gamma must be >= 0, got {gamma}")
        set_(self, "gamma", gamma)

    @property
    def target_vector(self) -> np.ndarray:
        """The target xbar as an array of shape (d,)."""
        return target_as_vector(self.target, self.dim)

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        """Names of all fields, in order (the env keyword arguments that map to params)."""
        return tuple(f.name for f in fields(cls))
