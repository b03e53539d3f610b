"""Swarm dynamics: interaction kernels, drift, Jacobian and frozen linearization."""

from agent_envs.dynamics.kernels import CuckerSmaleKernel, InteractionKernel
from agent_envs.dynamics.swarm import Linearization, SwarmModel, kernel_from_params

__all__ = [
    "CuckerSmaleKernel",
    "InteractionKernel",
    "Linearization",
    "SwarmModel",
    "kernel_from_params",
]
