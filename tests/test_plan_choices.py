"""The step plan's phi strategy for the exact Jacobian: the matrix's size and symmetry.

`resolve_phi_method` resolves "auto" as `phi_functions.phi_action` does for the env's states:
the exact Jacobian is an Nd x Nd matrix (the frozen L(x) N x N), symmetric only for a
symmetric *radial* kernel. Sizes are chosen where these facts change the answer.
"""

from __future__ import annotations

import types

from agent_envs.envs.episode_config import EpisodeConfig
from agent_envs.envs.step_plan import resolve_phi_method
from agent_envs.integrators.phi_functions import auto_phi_method


def _model(**kernel: bool) -> types.SimpleNamespace:
    return types.SimpleNamespace(kernel=types.SimpleNamespace(**kernel))


def test_the_exact_jacobian_is_sized_n_times_d():
    config = EpisodeConfig.from_kwargs(n_agents=50, dim=2, jacobian="exact", target=[0.1, 0.2])
    radial = _model(symmetric=True, radial=True)
    assert auto_phi_method(100, 1, True) != auto_phi_method(50, 1, True)  # (the sizes matter)
    assert resolve_phi_method(config, radial, False) == auto_phi_method(100, 1, True)
    frozen = EpisodeConfig.from_kwargs(n_agents=50, dim=2, target=[0.1, 0.2])
    assert resolve_phi_method(frozen, radial, False) == auto_phi_method(50, 1, True)


def test_the_exact_jacobian_of_a_non_radial_kernel_is_not_symmetric():
    config = EpisodeConfig.from_kwargs(n_agents=50, dim=2, jacobian="exact", target=[0.1, 0.2])
    assert auto_phi_method(100, 1, True) != auto_phi_method(100, 1, False)
    non_radial = _model(symmetric=True)  # (symmetric in (x, y), its Jacobian's blocks are not)
    assert resolve_phi_method(config, non_radial, False) == auto_phi_method(100, 1, False)
    frozen = EpisodeConfig.from_kwargs(n_agents=100, target=0.3)  # L(x) stays symmetric
    assert resolve_phi_method(frozen, non_radial, False) == auto_phi_method(100, 1, True)


def test_explicit_methods_and_matrix_free_states_pass_through():
    config = EpisodeConfig.from_kwargs(n_agents=50, phi_method="eigh")
    assert resolve_phi_method(config, _model(symmetric=True, radial=True), False) == "eigh"
    auto = EpisodeConfig.from_kwargs(n_agents=50)
    assert resolve_phi_method(auto, _model(symmetric=True, radial=True), True) == "krylov"
    em = EpisodeConfig.from_kwargs(n_agents=50, integrator="em")
    assert resolve_phi_method(em, _model(symmetric=True), False) == "auto"
