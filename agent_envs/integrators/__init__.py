"""Time-stepping schemes behind one interface, and the registry of their names.

    make_integrator("serb", jacobian="frozen")  ->  an Integrator with .step(...)

Names: "em" (Euler-Maruyama), "ee" (explicit Euler), "heun" (RK2), "erb" (exponential
Rosenbrock-Euler), "serb" (stochastic exponential Rosenbrock-Euler).
"""

from __future__ import annotations

from agent_envs.integrators.base import Integrator
from agent_envs.integrators.explicit import EulerMaruyama, ExplicitEuler, Heun
from agent_envs.integrators.exponential import (
    JACOBIAN_CHOICES,
    ExponentialRosenbrockEuler,
    StochasticExponentialRosenbrockEuler,
)
from agent_envs.integrators.phi_functions import PHI_METHODS, phi_action

INTEGRATORS: dict[str, type[Integrator]] = {
    cls.name: cls
    for cls in (
        EulerMaruyama,
        ExplicitEuler,
        Heun,
        ExponentialRosenbrockEuler,
        StochasticExponentialRosenbrockEuler,
    )
}

#: The Jacobian choice we recommend for ERB/SERB, from our measurements (docs/paper.md).
DEFAULT_JACOBIAN = "frozen"
#: The integrator we recommend for stiff settings.
DEFAULT_INTEGRATOR = "serb"


def make_integrator(
    name: str, jacobian: str = DEFAULT_JACOBIAN, phi_method: str = "auto"
) -> Integrator:
    """Build the integrator registered under `name`.

    `jacobian` ("exact" | "frozen") and `phi_method` apply to "erb"/"serb" only and are still
    validated for the others so that a typo never passes silently.
    """
    if not isinstance(name, str) or name not in INTEGRATORS:
        raise ValueError(f"integrator must be one of {sorted(INTEGRATORS)}, got {name!r}")
    if jacobian not in JACOBIAN_CHOICES:
        raise ValueError(f"jacobian must be one of {JACOBIAN_CHOICES}, got {jacobian!r}")
    if phi_method not in PHI_METHODS:
        raise ValueError(f"phi_method must be one of {PHI_METHODS}, got {phi_method!r}")
    cls = INTEGRATORS[name]
    if cls.needs_jacobian:
        return cls(jacobian=jacobian, phi_method=phi_method)  # type: ignore[call-arg]
    return cls()


__all__ = [
    "DEFAULT_INTEGRATOR",
    "DEFAULT_JACOBIAN",
    "INTEGRATORS",
    "JACOBIAN_CHOICES",
    "PHI_METHODS",
    "Integrator",
    "make_integrator",
    "phi_action",
]
