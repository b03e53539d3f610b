"""agent-envs: a stochastic, possibly stiff swarm as Gymnasium/PettingZoo environments.

from agent_envs import SwarmParams, simulate
traj = simulate(SwarmParams(n_agents=100, epsilon=0.05, sigma=0.01), integrator="serb",
                jacobian="frozen", n_steps=25, n_paths=20, seed=0)
"""

from agent_envs.dynamics import CuckerSmaleKernel, InteractionKernel, SwarmModel
from agent_envs.integrators import INTEGRATORS, make_integrator, phi_action
from agent_envs.params import SwarmParams
from agent_envs.simulator import Trajectory, simulate

__version__ = "0.1.0"

__all__ = [
    "INTEGRATORS",
    "CuckerSmaleKernel",
    "InteractionKernel",
    "SwarmModel",
    "SwarmParams",
    "Trajectory",
    "__version__",
    "make_integrator",
    "phi_action",
    "simulate",
]
