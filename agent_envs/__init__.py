"""agent-envs: a stochastic, possibly stiff swarm as Gymnasium/PettingZoo environments.

import gymnasium as gym, agent_envs
env = gym.make("agent_envs/Swarm-v0", n_agents=100, n_steps=50)   # registered on import
from agent_envs import swarm_v0; par_env = swarm_v0.parallel_env()  # PettingZoo

from agent_envs import SwarmParams, simulate
traj = simulate(SwarmParams(n_agents=100, epsilon=0.05, sigma=0.01), integrator="serb",
                jacobian="frozen", n_steps=25, n_paths=20, seed=0)
"""

from agent_envs.dynamics import CuckerSmaleKernel, InteractionKernel, SwarmModel
from agent_envs.integrators import INTEGRATORS, make_integrator, phi_action
from agent_envs.params import SwarmParams
from agent_envs.simulator import Trajectory, simulate

# Registers the Gymnasium id "agent_envs/Swarm-v0" (also what rl-zoo3's --gym-packages does).
from agent_envs.envs import SwarmEnv, SwarmParallelEnv, register_envs  # isort: skip

register_envs()

from agent_envs.tasks import register_tasks  # noqa: E402  (the benchmark's task ids)

register_tasks()

__version__ = "0.1.0"

__all__ = [
    "INTEGRATORS",
    "CuckerSmaleKernel",
    "InteractionKernel",
    "SwarmEnv",
    "SwarmModel",
    "SwarmParallelEnv",
    "SwarmParams",
    "Trajectory",
    "__version__",
    "make_integrator",
    "phi_action",
    "simulate",
]
