"""Which saved run a trial reuses: `find_run` matches env kwargs by the env they name."""

from __future__ import annotations

import json

from agent_envs.training.commands.learner_runs import find_run, same_env_kwargs
from agent_envs.training.config import TrainConfig
from agent_envs.training.defaults import GYM_ENV_ID

OVERRIDES = {"n_agents": 8, "epsilon": 0.05, "observation": "summary", "action_basis": "common"}


def test_same_env_kwargs_matches_defaults_spelt_out_or_left_out():
    full = {**OVERRIDES, "dim": 1, "kernel": "symmetric", "gamma": 0.01, "jacobian": "frozen"}
    assert same_env_kwargs(full, OVERRIDES)
    # the same env whichever of its defaults each side spells out
    assert same_env_kwargs({**OVERRIDES, "gamma": 0.01}, {**OVERRIDES, "dim": 1})
    assert not same_env_kwargs({**full, "epsilon": 1.0}, OVERRIDES)
    assert not same_env_kwargs({**full, "gamma": 0.1}, OVERRIDES)  # a non-default value
    assert not same_env_kwargs({**OVERRIDES, "max_control": 25.0}, OVERRIDES)
    assert not same_env_kwargs({**OVERRIDES, "observation": "swarm"}, OVERRIDES)
    assert not same_env_kwargs({**OVERRIDES, "no_such_option": 1}, OVERRIDES)  # invalid
    assert not same_env_kwargs(None, OVERRIDES)


def _saved_run(tmp_path, env_kwargs: dict, timesteps: int = 100) -> TrainConfig:
    wanted = TrainConfig(
        algo="ppo",
        env_id=GYM_ENV_ID,
        env_kwargs=OVERRIDES,
        timesteps=timesteps,
        seed=3,
        out=str(tmp_path),
        run_name="run",
    )
    run = tmp_path / "run"
    run.mkdir()
    saved = {**wanted.to_dict(), "env_kwargs": env_kwargs}
    (run / "config.json").write_text(json.dumps(saved))
    (run / "summary.json").write_text(json.dumps({"timesteps": timesteps}))
    return wanted


def test_find_run_reuses_a_run_saved_with_defaults_spelt_out(tmp_path):
    full = {**OVERRIDES, "dim": 1, "kernel": "symmetric", "n_paths": 1, "max_control": 150.0}
    wanted = _saved_run(tmp_path, full)
    assert find_run(wanted) == (tmp_path / "run", True)


def test_find_run_ignores_a_run_of_another_env(tmp_path):
    wanted = _saved_run(tmp_path, {**OVERRIDES, "sigma": 0.02})
    assert find_run(wanted) is None


def test_apg_run_reuses_a_run_saved_with_defaults_spelt_out(tmp_path):
    """The apg path of the reuse (`_apg_run`): the same law and training, the env spelt out."""
    from agent_envs.training.commands.learner_runs import _apg_run
    from agent_envs.training.learners.apg_config import APGConfig
    from agent_envs.training.learners.apg_policy import LAW_DESCRIPTION

    wanted = APGConfig(env_kwargs={"n_agents": 8, "epsilon": 0.05}, iterations=20, progress=False)
    run = tmp_path / "run"
    run.mkdir()
    (run / LAW_DESCRIPTION).write_text("{}")
    saved = wanted.to_dict()
    saved["env_kwargs"] = {"n_agents": 8, "epsilon": 0.05, "dim": 1, "gamma": 0.01}
    (run / "config.json").write_text(json.dumps(saved))
    (run / "summary.json").write_text(json.dumps({"iterations": 20}))
    assert _apg_run(wanted, tmp_path, "run") == (run, True)
    saved["env_kwargs"]["sigma"] = 0.5  # another env
    (run / "config.json").write_text(json.dumps(saved))
    assert _apg_run(wanted, tmp_path, "run") is None
