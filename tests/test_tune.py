"""`agent-envs tune`: the search spaces give valid training configs, bad options are one-line
errors, and (slow) a tiny search on a local Ray instance writes its summary."""

from __future__ import annotations

import importlib.util

import pytest

from agent_envs.training.commands.presets import PRESETS
from agent_envs.training.commands.tune import (
    TuneConfig,
    agents_per_copy,
    search_space,
    trial_train_config,
)


@pytest.mark.parametrize("learner", ["ppo", "ppo-modes", "sac", "td3", "ppo-shared"])
def test_every_sampled_point_is_a_valid_training_config(learner):
    """20 random points of each learner's space (paper preset) validate as `agent-envs train`
    configs: SB3 accepts every keyword, the ranges hold, a rollout fits (PPO)."""
    optuna = pytest.importorskip("optuna")
    config = TuneConfig(preset="paper", learner=learner, out="unused")
    base = config.base_config()
    agents = agents_per_copy(base.to_dict())
    assert agents == (100 if learner == "ppo-shared" else 1)
    sample = search_space(base.algo, base.timesteps, agents)
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=0))
    for _ in range(20):
        trial = study.ask()
        sampled = sample(trial)
        tuned = trial_train_config(base, sampled, "t").validate()
        assert tuned.timesteps == base.timesteps and tuned.env_kwargs == base.env_kwargs
        assert tuned.eval_seed == base.eval_seed  # validation seeds only; test seeds unseen
        assert 0.8 <= tuned.hyperparams["gamma"] < 1.0
        if base.algo == "ppo":
            rollout = tuned.hyperparams["n_steps"] * tuned.n_envs * agents
            assert tuned.hyperparams["batch_size"] <= rollout
            assert agents == 1 or 8 * rollout <= tuned.timesteps  # >= 8 rollouts per budget
        else:
            assert tuned.hyperparams["buffer_size"] == base.timesteps
        study.tell(trial, 1.0)


def test_the_base_config_is_the_presets_learner():
    config = TuneConfig(preset="paper", learner="ppo-modes", out="x", timesteps_scale=0.5)
    base = config.base_config()
    learner = PRESETS["paper"].learners[1]
    assert learner.name == "ppo-modes"
    assert base.timesteps == learner.timesteps // 2
    assert base.env_kwargs["max_control"] == 25.0 and base.hyperparams == learner.hyperparams
    assert base.env_kwargs["observation"] == "modes"  # the learner's env options are tuned on
    assert not base.progress_bar
    assert TuneConfig(preset="smoke", out="x").learner_entry().name == "ppo"


@pytest.mark.parametrize(
    ("kwargs", "flag"),
    [
        ({"learner": "dqn"}, "--learner"),
        ({"num_samples": 0}, "--num-samples"),
        ({"pruner": "hyperband"}, "--pruner"),
        ({"seed": -1}, "--seed"),
        ({"sampler_seed": 2**40}, "--sampler-seed"),
        ({"setting": "eps1", "learner": "td3"}, "--setting"),
        ({"preset": "nope"}, "--preset"),
        ({"cpus_per_trial": 0.0}, "--cpus-per-trial"),
    ],
)
def test_bad_tune_options_name_the_option(kwargs, flag):
    with pytest.raises((ValueError, TypeError), match=flag):
        TuneConfig(**{"out": "x", **kwargs})


@pytest.mark.slow
def test_tiny_search_writes_the_summary_and_a_usable_yaml(tmp_path):
    pytest.importorskip("ray")
    if importlib.util.find_spec("optuna") is None:
        pytest.skip("optuna comes with the zoo extra")
    import yaml

    from agent_envs.training.commands.cli import main
    from agent_envs.training.config import TrainConfig

    out = tmp_path / "tune"
    argv = ["tune", "--preset", "smoke", "--out", str(out), "--num-samples", "2"]
    assert main([*argv, "--num-cpus", "2", "--pruner", "none"]) == 0
    summary = (out / "tune_summary.md").read_text()
    assert "Best trials" in summary and "Parameter importances" in summary
    best = yaml.safe_load((out / "best_hyperparams.yml").read_text())
    entry = best["agent_envs/Swarm-v0"]
    n_envs, normalize = entry.pop("n_envs"), entry.pop("normalize")
    TrainConfig(
        env_kwargs={"n_agents": 5, "n_steps": 5},
        hyperparams=entry,
        n_envs=n_envs,
        normalize=normalize,
    ).validate()
    runs = sorted(p.name for p in (out / "runs").iterdir())
    assert len(runs) == 2 and all(r.startswith("trial_") for r in runs)
    # a second start into the same OUT needs --resume
    assert main(argv) == 2
