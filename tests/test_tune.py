"""`agent-envs tune`: the search spaces give valid training configs, bad options are one-line
errors, the multi-seed objective aggregates and reports as documented, and (slow) a tiny search
on a local Ray instance writes its summary, with one or two training seeds per trial."""

from __future__ import annotations

import importlib.util
import math

import pytest

from agent_envs.training.commands.presets import PRESETS
from agent_envs.training.commands.seed_objective import SeedReports, aggregate_seeds
from agent_envs.training.commands.tune import (
    TuneConfig,
    agents_per_copy,
    search_space,
    trial_train_config,
    trials_table,
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
        ({"seeds": (-1,)}, "--seeds"),
        ({"seeds": (3, 1, 3)}, "--seeds"),
        ({"seeds": ("0-2", "2")}, "--seeds"),
        ({"seeds": (2**40,)}, "--seeds"),
        ({"seeds": ()}, "--seeds"),
        ({"seed_objective": "best"}, "--seed-objective"),
        ({"sampler_seed": 2**40}, "--sampler-seed"),
        ({"setting": "eps1", "learner": "td3"}, "--setting"),
        ({"preset": "nope"}, "--preset"),
        ({"cpus_per_trial": 0.0}, "--cpus-per-trial"),
    ],
)
def test_bad_tune_options_name_the_option(kwargs, flag):
    with pytest.raises((ValueError, TypeError), match=flag):
        TuneConfig(**{"out": "x", **kwargs})


@pytest.mark.parametrize(
    ("objective", "expected"),
    [("worst", 0.336), ("median", 0.0795), ("mean", (0.047 + 0.064 + 0.336 + 0.095) / 4)],
)
def test_the_seed_objective_of_hand_costs(objective, expected):
    """Four seeds' costs 0.047, 0.336, 0.064, 0.095: worst 0.336, median (0.064 + 0.095) / 2,
    mean their sum / 4; one seed is its own cost under every objective."""
    costs = [0.047, 0.336, 0.064, 0.095]
    assert aggregate_seeds(costs, objective) == pytest.approx(expected, rel=1e-12)
    assert aggregate_seeds([0.0708], objective) == 0.0708
    assert aggregate_seeds(costs[:3], "median") == 0.064


def test_the_seed_objective_refuses_no_cost_and_unknown_names():
    with pytest.raises(ValueError, match="--seed-objective"):
        aggregate_seeds([1.0], "best")
    with pytest.raises(ValueError, match="no per-seed cost"):
        aggregate_seeds([], "mean")


def test_seeds_report_end_to_end_on_one_time_axis():
    """Seeds 4 then 7 of budget 100: seed 4's evaluations report its best so far at its own
    timesteps; seed 7's report at 100 + t the worst of seed 4's final best and seed 7's best
    so far; the last report is the objective over both seeds' final bests."""
    reports = SeedReports((4, 7), budget=100, objective="worst")
    first = reports.evaluation({"cost_mean": 0.5, "timesteps": 50})
    assert first == {
        "validation_cost": 0.5,
        "last_cost": 0.5,
        "timesteps": 50,
        "seed": 4,
        "cost_seed_4": 0.5,
    }
    assert reports.evaluation({"cost_mean": 0.6, "timesteps": 100})["validation_cost"] == 0.5
    # a run past its budget (PPO's last rollout) stays on its own seed's part of the axis
    assert reports.evaluation({"cost_mean": 0.7, "timesteps": 128})["timesteps"] == 100
    reports.next_seed()
    second = reports.evaluation({"cost_mean": 0.9, "timesteps": 50})
    assert (second["timesteps"], second["seed"], second["validation_cost"]) == (150, 7, 0.9)
    last = reports.evaluation({"cost_mean": 0.2, "timesteps": 128})  # past the budget
    assert last["timesteps"] == 228 and last["validation_cost"] == 0.5
    assert (last["cost_seed_4"], last["cost_seed_7"], last["last_cost"]) == (0.5, 0.2, 0.2)
    mean = SeedReports((4, 7), 100, "mean", costs={4: 0.5}, running=1)
    assert mean.evaluation({"cost_mean": 0.2, "timesteps": 100})[
        "validation_cost"
    ] == pytest.approx(0.35, rel=1e-15)


def test_trials_that_reached_every_seed_rank_first():
    """A trial stopped after seed 0 with a low partial objective ranks after the trials that
    ran both seeds; a seed a trial never reached is NaN."""
    from types import SimpleNamespace

    def result(trial, costs):
        metrics = {"trial_id": trial, "timesteps": 100 * len(costs)}
        metrics |= {f"cost_seed_{s}": c for s, c in costs.items()}
        if costs:
            metrics["validation_cost"] = max(costs.values())
        config = {"base": {}, "sampled": {}, "seeds": [0, 1], "objective": "worst", "lr": 0.1}
        return SimpleNamespace(config=config, metrics=metrics, error=None)

    grid = [
        result("stopped", {0: 0.1}),
        result("worse", {0: 0.3, 1: 0.5}),
        result("none", {}),
        result("better", {0: 0.4, 1: 0.2}),
    ]
    table = trials_table(grid, (0, 1))
    assert list(table["trial"]) == ["better", "worse", "stopped", "none"]
    assert list(table.columns) == [
        "trial",
        "validation_cost",
        "cost_seed_0",
        "cost_seed_1",
        "timesteps",
        "error",
        "lr",
    ]
    assert math.isnan(table["cost_seed_1"][2]) and table["validation_cost"][0] == 0.4


def test_several_seeds_set_the_base_and_the_command():
    config = TuneConfig(preset="smoke", out="x", seeds=("3-4",), seed_objective="mean")
    assert config.seeds == (3, 4) and config.base_config().seed == 3
    assert config.command().endswith("--seeds 3 4 --seed-objective mean")
    assert config.objective_text() == "the mean over training seeds 3,4"
    assert TuneConfig(preset="smoke", out="x").seeds == (0,)  # the single seed of before


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


@pytest.mark.slow
def test_tiny_search_on_two_seeds_writes_the_per_seed_costs(tmp_path):
    """Two trials of two training seeds each (the worst objective): the table has both seeds'
    costs and their maximum as the objective, each seed its run folder, the YAML comment names
    the objective and seeds."""
    pytest.importorskip("ray")
    if importlib.util.find_spec("optuna") is None:
        pytest.skip("optuna comes with the zoo extra")
    import pandas as pd

    from agent_envs.training.commands.cli import main

    out = tmp_path / "tune"
    argv = ["tune", "--preset", "smoke", "--out", str(out), "--num-samples", "2"]
    argv += ["--seeds", "0", "1", "--num-cpus", "2", "--pruner", "none"]
    assert main(argv) == 0
    table = pd.read_csv(out / "trials.csv")
    assert list(table.columns[:4]) == ["trial", "validation_cost", "cost_seed_0", "cost_seed_1"]
    for _, row in table.iterrows():
        worst = max(row["cost_seed_0"], row["cost_seed_1"])
        assert math.isfinite(worst) and row["validation_cost"] == worst
    assert "cost_seed_1" in (out / "tune_summary.md").read_text()
    assert "the worst over training seeds 0,1: " in (out / "best_hyperparams.yml").read_text()
    runs = sorted(p.name for p in (out / "runs").iterdir())
    assert len(runs) == 4 and {r.rsplit("__", 1)[1] for r in runs} == {"0", "1"}
