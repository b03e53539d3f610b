"""`EpisodeConfig`'s own contracts: `replace` by env kwarg name, the simulation's fields read
through the config, and the env-specific option check only where an env is named."""

from __future__ import annotations

import pytest

from agent_envs.envs.episode_config import EpisodeConfig


def test_replace_changes_each_kind_of_kwarg_and_nothing_else():
    config = EpisodeConfig.from_kwargs(n_agents=12, n_steps=7, observation="relative")
    params = config.replace(epsilon=0.5)  # a SwarmParams field
    assert params.params.epsilon == 0.5 and params.params.n_agents == 12
    assert params.simulation == config.simulation and params.observation == "relative"
    spec = config.replace(n_paths=3, integrator="em")  # the simulation's fields
    assert (spec.simulation.n_paths, spec.simulation.integrator) == (3, "em")
    assert spec.params == config.params and spec.simulation.n_steps == 7
    option = config.replace(observation="absolute", divergence_threshold=50.0)  # the config's
    assert (option.observation, option.divergence_threshold) == ("absolute", 50.0)
    assert option.params == config.params and option.simulation == config.simulation
    both = config.replace(epsilon=2.0, n_paths=2, agent_reward="team")
    assert (both.params.epsilon, both.simulation.n_paths, both.agent_reward) == (2.0, 2, "team")
    assert config.replace() == config
    with pytest.raises(ValueError, match="n_paths"):
        config.replace(n_paths=0)  # validated again


def test_the_simulations_fields_read_through_the_config():
    config = EpisodeConfig.from_kwargs(
        n_agents=5, n_steps=8, n_paths=2, integrator="erb", jacobian="exact",
        phi_method="expm", max_control=30.0, horizon=2.0,
    )  # fmt: skip
    sim = config.simulation
    assert (config.integrator, config.jacobian, config.phi_method) == ("erb", "exact", "expm")
    assert (config.n_steps, config.n_paths, config.max_control) == (8, 2, 30.0)
    assert (sim.n_steps, sim.n_paths, sim.max_control) == (8, 2, 30.0)
    assert config.dt == 2.0 / 8


def test_an_env_only_option_is_refused_only_where_that_env_is_named():
    # "swarm" is the PettingZoo env's layout: the generic check accepts it, the Gymnasium
    # env's refuses it with its own values
    assert EpisodeConfig.from_kwargs(observation="swarm").observation == "swarm"
    assert (
        EpisodeConfig.from_kwargs(env_kind="pettingzoo", observation="swarm").observation == "swarm"
    )
    with pytest.raises(ValueError, match="observation"):
        EpisodeConfig.from_kwargs(env_kind="gymnasium", observation="swarm")
