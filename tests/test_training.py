"""Training and comparison: CLI, configuration errors, smoke runs, resume, determinism, rl-zoo3.

The smoke runs train for a few hundred timesteps on a tiny swarm (N = 5, m = 10) and are marked
slow; together they take well under a minute on 2 CPU cores.
"""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from agent_envs.training.config import (
    ZOO_KEYS,
    TrainConfig,
    default_hyperparams,
    hyperparams_file,
)
from agent_envs.training.defaults import ALGORITHMS, GYM_ENV_ID, PETTINGZOO_ENV_ID

TINY_ENV = {"n_agents": 5, "n_steps": 10}
#: rollouts / learning starts small enough for a few hundred timesteps
TINY_HYPERPARAMS = {
    "ppo": {"n_steps": 16, "batch_size": 32, "n_epochs": 2},
    "a2c": {"n_steps": 5},
    "sac": {"learning_starts": 50, "batch_size": 32},
    "td3": {"learning_starts": 50, "batch_size": 32},
}
REPO = Path(__file__).resolve().parents[1]


def tiny_config(tmp_path: Path, algo: str = "ppo", env_id: str = GYM_ENV_ID, **overrides):
    """A config that trains in a few seconds: N = 5, m = 10, evaluations on 3 seeds."""
    values = {
        "algo": algo,
        "env_id": env_id,
        "env_kwargs": dict(TINY_ENV),
        "timesteps": 200,
        "seed": 0,
        "out": str(tmp_path / "runs"),
        "hyperparams": dict(TINY_HYPERPARAMS[algo]),
        "eval_freq": 100,
        "eval_episodes": 3,
        "checkpoint_freq": 100,
        "progress_bar": False,
        "tensorboard": False,
    }
    values.update(overrides)
    return TrainConfig(**values)


# ---------------------------------------------------------------------------------------- CLI


def _subcommands():
    from agent_envs.training.commands.cli import SUBCOMMANDS

    return sorted(SUBCOMMANDS)


@pytest.mark.parametrize("name", _subcommands())
def test_every_subcommand_help_exits_zero(name, capsys):
    from agent_envs.training.commands.cli import main

    with pytest.raises(SystemExit) as exc:
        main([name, "--help"])
    assert exc.value.code == 0
    assert "usage: agent-envs" in capsys.readouterr().out


def test_top_level_help_and_reproduce_alias_help():
    from agent_envs.training.commands.cli import main

    for argv in (["--help"], ["reproduce", "turnpike", "--help"]):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 0


def test_train_help_documents_every_config_field(capsys):
    from dataclasses import fields

    from agent_envs.training.commands.cli import main

    with pytest.raises(SystemExit):
        main(["train", "--help"])
    text = capsys.readouterr().out
    for f in fields(TrainConfig):
        assert "--" + f.name.replace("_", "-") in text
    assert "turnpike" in text


# ------------------------------------------------------------------------------------- errors


def test_unknown_algorithm_names_the_option():
    with pytest.raises(ValueError, match="--algo"):
        TrainConfig(algo="dqn").validate()


def test_unknown_env_id_names_the_option_and_suggests():
    with pytest.raises(ValueError, match=r"--env-id.*Did you mean agent_envs/Swarm-v0"):
        TrainConfig(env_id="agent_envs/Swarm-v1").validate()


@pytest.mark.parametrize("text", ["{n_agents: 5}", "[1, 2]", "'x'"])
def test_malformed_env_kwargs_names_the_option(text):
    with pytest.raises(ValueError, match="--env-kwargs"):
        TrainConfig(env_kwargs=text)


def test_malformed_hyperparams_names_the_option():
    with pytest.raises(ValueError, match="--hyperparams"):
        TrainConfig(hyperparams="{learning_rate=1}")
    with pytest.raises(ValueError, match=r"--hyperparams.*n_envs"):
        TrainConfig(hyperparams={"n_envs": 2}).validate()


def test_bad_env_kwarg_value_fails_before_training(tmp_path):
    from agent_envs.training.commands.train import train

    for bad in ({"n_agents": 1}, {"n_agent": 5}, {"n_agents": "five"}):
        with pytest.raises(ValueError, match="n_agent"):
            train(tiny_config(tmp_path, env_kwargs=bad))
    assert not (tmp_path / "runs").exists()  # nothing created for a rejected run


def test_cli_env_kwargs_typo_is_a_clean_error(tmp_path, capsys):
    from agent_envs.training.commands.cli import main

    out = str(tmp_path / "runs")
    assert main(["train", "--env-kwargs", '{"n_agent": 5}', "--out", out]) == 2
    assert "--env-kwargs" in capsys.readouterr().err


def test_horizon_end_is_terminal_for_the_learner():
    import gymnasium as gym

    import agent_envs  # noqa: F401
    from agent_envs.training.learners.wrappers import HorizonAsTermination

    env = HorizonAsTermination(gym.make(GYM_ENV_ID, **TINY_ENV))
    env.reset(seed=0)
    flags = [env.step(env.action_space.sample() * 0)[2:4] for _ in range(TINY_ENV["n_steps"])]
    assert flags[-1] == (True, False)  # terminated, not truncated, at t = T
    assert all(f == (False, False) for f in flags[:-1])


def test_cli_reports_bad_options_with_exit_code_2(capsys):
    from agent_envs.training.commands.cli import main

    assert main(["train", "--algo", "ppo", "--env-kwargs", "{oops"]) == 2
    assert "--env-kwargs" in capsys.readouterr().err
    assert main(["train", "--env-id", "CartPole-v2"]) == 2
    assert "--env-id" in capsys.readouterr().err
    assert main(["train", "--algo", "dqn"]) == 2  # argparse's choices check, one line too
    assert "--algo" in capsys.readouterr().err
    assert main(["compare", "--learners", "ppo,dqn", "--out", "unused"]) == 2
    assert "--learners" in capsys.readouterr().err


def test_cli_resume_refuses_to_change_the_run(tmp_path, capsys):
    from agent_envs.training.commands.cli import main

    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "config.json").write_text(json.dumps(TrainConfig().to_dict()))
    assert main(["train", "--resume", str(run_dir), "--algo", "sac"]) == 2
    assert "--algo" in capsys.readouterr().err


# ------------------------------------------------------------------------------ hyperparameters


@pytest.mark.parametrize("algo", ALGORITHMS)
def test_shipped_yaml_is_what_train_uses(algo):
    """The YAML file rl-zoo3 is pointed at is the one source of `agent-envs train`'s defaults:
    an entry for both swarm envs, valid SB3 keyword arguments, and the measured choices
    (gamma 0.9 for 20-50 step episodes, the horizon wrapper, normalization)."""
    from agent_envs.training.sb3_arguments import check_hyperparams

    yaml = pytest.importorskip("yaml")
    with open(hyperparams_file(algo)) as handle:
        raw = yaml.safe_load(handle)
    assert set(raw) == {GYM_ENV_ID, PETTINGZOO_ENV_ID}
    for env_id, entry in raw.items():
        assert default_hyperparams(algo, env_id) == entry
        assert entry["gamma"] == 0.9 and entry["normalize"] is True
        assert entry["env_wrapper"] == "agent_envs.training.learners.wrappers.HorizonAsTermination"
        kwargs = {k: v for k, v in entry.items() if k not in ZOO_KEYS}
        check_hyperparams(algo, kwargs, entry["policy"])
    if algo in ("ppo", "a2c"):
        assert raw[GYM_ENV_ID]["policy_kwargs"]["log_std_init"] == -3.0
    with pytest.raises(ValueError, match="--env-id"):
        default_hyperparams(algo, "Pendulum-v1")


def test_run_name_follows_cleanrl_pattern():
    from agent_envs.training.commands.train import default_run_name

    name = default_run_name(TrainConfig(algo="sac", seed=3))
    env, algo, seed, stamp = name.split("__")
    assert (env, algo, seed) == ("agent_envs_Swarm-v0", "sac", "3")
    assert stamp.isdigit()


# ------------------------------------------------------------------------------- determinism


def test_seeded_evaluation_is_deterministic():
    """The same policy on the same validation seeds gives the same costs, seed by seed."""
    from agent_envs.baselines import TurnpikeController
    from agent_envs.training.learners.callbacks import run_seeded_episodes
    from agent_envs.training.learners.environments import make_eval_vec_env

    venv = make_eval_vec_env(GYM_ENV_ID, TINY_ENV, 4)
    policy = TurnpikeController(venv.envs[0])
    first, diverged = run_seeded_episodes(policy, venv, 1000)
    second, _ = run_seeded_episodes(policy, venv, 1000)
    other, _ = run_seeded_episodes(policy, venv, 2000)
    np.testing.assert_array_equal(first, second)
    assert not np.allclose(first, other)
    assert first.shape == (4,) and not diverged.any() and np.all(first > 0)


def test_seeded_evaluation_matches_training_evaluate():
    """Sub-env i with seed s + i runs the episode `evaluate_policies` runs with seed s + i."""
    from agent_envs.training.commands.evaluate import evaluate_policies
    from agent_envs.training.learners.callbacks import run_seeded_episodes
    from agent_envs.training.learners.environments import make_eval_vec_env

    venv = make_eval_vec_env(GYM_ENV_ID, TINY_ENV, 3)
    from agent_envs.baselines import ProportionalController

    costs, _ = run_seeded_episodes(ProportionalController(venv.envs[0]), venv, 1000)
    results = evaluate_policies(
        ["proportional"], env_kwargs=TINY_ENV, seeds=[1000, 1001, 1002], progress=False
    )
    # SB3's DummyVecEnv hands rewards over as float32
    np.testing.assert_allclose(costs, results.episodes["total_cost"].to_numpy(), rtol=1e-6)


# ------------------------------------------------------------------------------ smoke (slow)


def _check_run(run_dir: Path, timesteps: int) -> dict:
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["timesteps"] >= timesteps
    for name in ("config.json", "env.json", "hyperparams.json", "final_model.zip"):
        assert (run_dir / name).is_file(), name
    # the step plans: the Gymnasium env's, and the native training env's where it is one
    description = json.loads((run_dir / "env.json").read_text())
    assert description["step_plan"].startswith(description["integrator"] + "/")
    training_plan = summary["training_step_plan"]
    assert training_plan is None or " envs=" in training_plan
    assert (run_dir / "final_model_vecnormalize.pkl").is_file()
    assert list((run_dir / "checkpoints").glob("rl_model_*_steps.zip"))
    from agent_envs.training.learners.callbacks import read_learning_curve

    curve = read_learning_curve(run_dir / "learning_curve.csv")
    assert curve and curve[-1]["timesteps"] == summary["timesteps"]
    for row in curve:
        assert np.isfinite(row["cost_mean"]) and row["turnpike_cost"] > 0
        assert np.isfinite(row["proportional_cost"]) and np.isfinite(row["zero_cost"])
    return summary


@pytest.mark.slow
@pytest.mark.parametrize("algo", ALGORITHMS)
def test_smoke_single_controller(algo, tmp_path):
    from agent_envs.training.commands.evaluate import evaluate_policies
    from agent_envs.training.commands.train import train

    run_dir = train(tiny_config(tmp_path, algo))
    assert run_dir.name.startswith(f"agent_envs_Swarm-v0__{algo}__0__")
    _check_run(run_dir, 200)
    if algo in ("sac", "td3"):  # the newest replay buffer only (they are large)
        buffers = list((run_dir / "checkpoints").glob("rl_model_replay_buffer_*_steps.pkl"))
        assert [p.name for p in buffers] == ["rl_model_replay_buffer_200_steps.pkl"]
    # the saved model is a policy `agent_envs.training.commands.evaluate` loads (VecNormalize found
    # next to it)
    results = evaluate_policies(
        {"learned": str(run_dir / "final_model.zip"), "zero": "zero"},
        env_kwargs=TINY_ENV,
        seeds=[10_000, 10_001],
        progress=False,
    )
    learned = results.meta["policies"]["learned"]
    assert learned["algo"] == algo and learned["vecnormalize"].endswith(
        "final_model_vecnormalize.pkl"
    )
    assert np.all(np.isfinite(results.episodes["total_cost"]))


@pytest.mark.slow
def test_smoke_parameter_shared_ppo(tmp_path):
    """PettingZoo + SuperSuit training; the shared policy scores the same on both envs."""
    import gymnasium as gym

    from agent_envs.training.commands.evaluate import evaluate_policies
    from agent_envs.training.commands.train import train
    from agent_envs.training.learners.multiagent import evaluate_per_agent
    from agent_envs.training.learners.policies import load_sb3_policy

    config = tiny_config(tmp_path, "ppo", PETTINGZOO_ENV_ID, timesteps=500, eval_freq=250)
    config.hyperparams["batch_size"] = 40  # a rollout holds n_steps * N = 80 agent-steps
    run_dir = train(config)
    summary = _check_run(run_dir, 500)
    assert summary["swarm_steps"] == summary["timesteps"] // TINY_ENV["n_agents"]
    seeds = [10_000, 10_001]
    results = evaluate_policies(
        {"shared": str(run_dir / "final_model.zip")},
        env_kwargs=TINY_ENV,
        seeds=seeds,
        progress=False,
    )
    assert results.meta["policies"]["shared"]["per_agent"] is True
    env = gym.make(GYM_ENV_ID, **TINY_ENV)
    policy, _ = load_sb3_policy(run_dir / "final_model.zip", env)
    per_agent = evaluate_per_agent(policy.policy, TINY_ENV, seeds)
    assert per_agent.shape == (2, TINY_ENV["n_agents"])
    # the agents' costs add up to the swarm's cost on the Gymnasium env, seed by seed
    np.testing.assert_allclose(
        per_agent.sum(axis=1), results.episodes["total_cost"].to_numpy(), rtol=1e-5
    )


@pytest.mark.slow
def test_training_is_reproducible_with_a_fixed_seed(tmp_path):
    from agent_envs.training.commands.train import train
    from agent_envs.training.learners.callbacks import read_learning_curve

    curves = []
    for i in range(2):
        run_dir = train(tiny_config(tmp_path / str(i), "ppo", checkpoint_freq=0))
        curves.append([r["cost_mean"] for r in read_learning_curve(run_dir / "learning_curve.csv")])
    assert curves[0] == curves[1]


def _two_threads_allowed() -> bool:
    from agent_envs.dynamics.laplacian import max_compiled_threads

    return max_compiled_threads() >= 2


def test_env_threads_reach_the_native_training_env(tmp_path):
    """--env-threads builds the native training env on that many threads."""
    if not _two_threads_allowed():
        pytest.skip("numba allows one thread here")
    from agent_envs.training.learners.environments import make_training_env

    venv = make_training_env(tiny_config(tmp_path, env_threads=2).validate(), 3)
    assert venv.venv.num_threads == 2
    assert all(model.threads == 2 for model in venv.venv._blocks.models)
    venv.close()


@pytest.mark.slow
def test_training_on_env_threads_learns_the_same(tmp_path):
    """The same seed on 1 and 2 env threads: the same learning curve (the envs' results are the
    same bit for bit on any number of threads)."""
    if not _two_threads_allowed():
        pytest.skip("numba allows one thread here")
    from agent_envs.training.commands.train import train
    from agent_envs.training.learners.callbacks import read_learning_curve

    curves = []
    for threads in (1, 2):
        config = tiny_config(tmp_path / str(threads), "ppo", checkpoint_freq=0)
        config.env_threads = threads
        run_dir = train(config)
        curves.append([r["cost_mean"] for r in read_learning_curve(run_dir / "learning_curve.csv")])
    assert curves[0] == curves[1]


class _InterruptAt:
    """An SB3 callback that raises KeyboardInterrupt (a Ctrl-C) at a given timestep."""

    def __new__(cls, timesteps: int):
        from stable_baselines3.common.callbacks import BaseCallback

        class Interrupt(BaseCallback):
            def _on_step(self) -> bool:
                if self.num_timesteps >= timesteps:
                    raise KeyboardInterrupt
                return True

        return Interrupt()


def _capture_start_parameters():
    from stable_baselines3.common.callbacks import BaseCallback

    class Capture(BaseCallback):
        start = None
        start_timesteps = None
        buffer_size = None
        obs_rms_count = None

        def _on_training_start(self) -> None:
            stats = self.model.get_vec_normalize_env()
            Capture.obs_rms_count = None if stats is None else float(stats.obs_rms.count)
            Capture.start = {
                k: v.detach().clone() for k, v in self.model.policy.state_dict().items()
            }
            Capture.start_timesteps = self.model.num_timesteps
            buffer = getattr(self.model, "replay_buffer", None)
            Capture.buffer_size = None if buffer is None else buffer.size()

        def _on_step(self) -> bool:
            return True

    return Capture


@pytest.mark.slow
@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_interrupted_run_resumes_from_its_last_checkpoint(algo, tmp_path):
    import torch

    from agent_envs.training.commands.train import train
    from agent_envs.training.defaults import algorithm_class
    from agent_envs.training.learners.callbacks import read_learning_curve
    from agent_envs.training.learners.checkpoints import latest_checkpoint

    config = tiny_config(tmp_path, algo, timesteps=400, eval_freq=100, checkpoint_freq=100)
    with pytest.raises(KeyboardInterrupt):
        train(config, callbacks=[_InterruptAt(250)])
    (run_dir,) = (tmp_path / "runs").iterdir()
    assert not (run_dir / "summary.json").exists()
    steps, model_path = latest_checkpoint(run_dir, algo == "sac", normalize=True)
    assert steps >= 250  # the interrupt saved a checkpoint at the current timestep
    saved = algorithm_class(algo).load(model_path, device="cpu").policy.state_dict()

    capture = _capture_start_parameters()
    resumed = train(
        TrainConfig(resume=str(run_dir), timesteps=400, progress_bar=False, tensorboard=False),
        callbacks=[capture()],
    )
    assert resumed == run_dir
    assert capture.start_timesteps == steps  # timesteps done are kept
    # the VecNormalize statistics come back with the checkpoint (not rebuilt from scratch)
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from agent_envs.training.learners.checkpoints import checkpoint_file

    saved_stats = VecNormalize.load(
        str(checkpoint_file(run_dir, "vecnormalize", steps)),
        DummyVecEnv([lambda: __import__("gymnasium").make(GYM_ENV_ID, **TINY_ENV)]),
    )
    saved_count = float(saved_stats.obs_rms.count)
    assert saved_count > 100
    # learn() resets the envs first, which adds one observation per env to the statistics
    assert saved_count <= capture.obs_rms_count <= saved_count + 8
    for key, value in saved.items():  # the trained weights are kept
        assert torch.equal(capture.start[key], value), key
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["timesteps"] >= 400
    timesteps = [r["timesteps"] for r in read_learning_curve(run_dir / "learning_curve.csv")]
    assert timesteps == sorted(timesteps) and timesteps[0] <= 100  # history kept, in order
    if algo == "sac":
        # the replay buffer came back with the checkpoint (all but the transition of the
        # interrupted step, which SB3 stores after the callbacks ran)
        assert capture.buffer_size >= steps - 1
    assert len(set(timesteps)) == len(timesteps)  # no evaluation counted twice

    # a finished run continues from its final state, not from an older checkpoint
    final_steps = summary["timesteps"]
    assert latest_checkpoint(run_dir, algo == "sac", normalize=True)[0] == final_steps
    capture = _capture_start_parameters()
    train(
        TrainConfig(
            resume=str(run_dir), timesteps=final_steps + 100, progress_bar=False, tensorboard=False
        ),
        callbacks=[capture()],
    )
    assert capture.start_timesteps == final_steps

    # asking for no more than what is done trains nothing and keeps the run as it is
    before = (run_dir / "summary.json").read_text()
    done = json.loads(before)["timesteps"]
    assert (
        train(
            TrainConfig(
                resume=str(run_dir), timesteps=done - 50, progress_bar=False, tensorboard=False
            )
        )
        == run_dir
    )
    assert (run_dir / "summary.json").read_text() == before


@pytest.mark.slow
def test_compare_quick_preset_smoke(tmp_path):
    """The main job end to end on a tiny budget: trains, evaluates on shared seeds, reports."""
    from agent_envs.training.commands.cli import main

    out = tmp_path / "cmp"
    argv = [
        "compare",
        "--preset",
        "quick",
        "--out",
        str(out),
        "--timesteps-scale",
        "0.01",
        "--test-episodes",
        "2",
        "--eval-env-kwargs",
        '{"integrator": "em"}',
        "--optimum",
        "optimal,mpc",  # the preset's optimum, and MPC, which the quick preset leaves out
        "--no-progress-bar",
    ]
    assert main(argv) == 0
    report = (out / "report" / "report.md").read_text()
    names = ("turnpike", "proportional", "zero", "optimal", "mpc", "ppo", "sac", "ppo-shared")
    for name in (*names, "apg", "proportional-common"):
        assert f"| {name} |" in report
    assert "Against each learner's fair baseline" in report
    assert "gap to optimal" in report
    assert "Learning curves" in report and "learning_curves.png" in report
    assert "Per-agent costs of ppo-shared" in report
    assert "Evaluated on another env" in report
    record = json.loads((out / "comparison.json").read_text())
    assert record["seeds"] == [10_000, 10_001]
    # a second invocation reuses the finished runs instead of training again
    runs = sorted(p.name for p in (out / "runs").iterdir())
    assert main(argv) == 0
    assert sorted(p.name for p in (out / "runs").iterdir()) == runs


@pytest.mark.slow
def test_rl_zoo3_trains_with_the_shipped_yaml(tmp_path):
    # not importorskip: importing rl_zoo3 patches gymnasium's TimeLimit for the whole process
    # (rl_zoo3.gym_patches adds "TimeLimit.truncated" to every info), which changed the infos
    # of every later test; the run itself happens in a subprocess
    if importlib.util.find_spec("rl_zoo3") is None:
        pytest.skip("rl_zoo3 is the optional 'zoo' extra")
    command = [
        sys.executable,
        "-m",
        "rl_zoo3.train",
        "--algo",
        "ppo",
        "--env",
        GYM_ENV_ID,
        "--gym-packages",
        "agent_envs",
        "--conf-file",
        str(hyperparams_file("ppo")),
        "--env-kwargs",
        "n_agents:5",
        "n_steps:10",
        "-n",
        "256",
        "--eval-freq",
        "128",
        "--eval-episodes",
        "2",
        "-f",
        str(tmp_path),
        "--seed",
        "0",
        "--num-threads",
        "1",
        "--hyperparams",
        "n_steps:32",
        "batch_size:64",
        "--verbose",
        "0",
    ]
    done = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    (run,) = (tmp_path / "ppo").iterdir()
    assert (run / "agent_envs-Swarm-v0.zip").is_file()
    assert (run / "agent_envs-Swarm-v0" / "vecnormalize.pkl").is_file()


# ------------------------------------------------------------------------ env options (issue 20)


def _episode_cost(policy, env, seed: int = 3) -> float:
    from episodes import episode_cost

    return episode_cost(policy, env, seed)


def test_a_policy_trained_with_env_options_acts_alike_on_the_default_env(tmp_path):
    """A run trained with observation="summary", action_basis="common" is evaluated on the
    default interface through InterfacePolicy with the cost it has on its own env; on an env
    with another N it is refused (its shapes do not fit its recorded interface)."""
    import gymnasium as gym

    from agent_envs.training.commands.train import train
    from agent_envs.training.learners.policies import InterfacePolicy, resolve_policy

    options = {"observation": "summary", "action_basis": "common"}
    config = tiny_config(
        tmp_path, env_kwargs={**TINY_ENV, **options}, timesteps=128, run_name="summary"
    )
    run_dir = train(config)
    model = run_dir / "final_model.zip"
    default = gym.make(GYM_ENV_ID, **TINY_ENV)
    own = gym.make(GYM_ENV_ID, **TINY_ENV, **options)
    wrapped, info = resolve_policy(str(model), default)
    assert isinstance(getattr(wrapped, "policy", None), object) and info["interface"] == options
    direct, _ = resolve_policy(str(model), own)
    assert _episode_cost(wrapped, default) == pytest.approx(_episode_cost(direct, own), rel=1e-5)
    assert isinstance(wrapped, InterfacePolicy)
    # the summary observation has 3d + 1 entries at any N, but the action is one control
    # here too, so the model fits at another N; a "modes" model does not
    modes = {"observation": "modes", "action_basis": "modes"}
    config = tiny_config(
        tmp_path, env_kwargs={**TINY_ENV, **modes}, timesteps=128, run_name="modes"
    )
    modes_model = train(config) / "final_model.zip"
    other_n = gym.make(GYM_ENV_ID, **{**TINY_ENV, "n_agents": TINY_ENV["n_agents"] + 1})
    with pytest.raises(ValueError, match="needs"):
        resolve_policy(str(modes_model), other_n)


def test_a_shared_policy_with_the_swarm_layout_is_evaluated_in_its_layout(tmp_path):
    """The parameter-shared learner with observation="swarm", agent_reward="team": validated
    and evaluated on the Gymnasium env through PerAgentPolicy in its layout, compare's
    per-agent table runs it in its layout with own rewards, and a run whose env.json has the
    Gymnasium twin's id (earlier versions wrote that) still loads as per-agent."""
    import json

    import gymnasium as gym

    from agent_envs.training.commands.compare import per_agent_table
    from agent_envs.training.commands.train import train
    from agent_envs.training.learners.checkpoints import best_model_path
    from agent_envs.training.learners.policies import PerAgentPolicy, resolve_policy

    options = {"observation": "swarm", "agent_reward": "team"}
    config = tiny_config(
        tmp_path, "ppo", PETTINGZOO_ENV_ID, env_kwargs={**TINY_ENV, **options}, timesteps=500
    )
    run_dir = train(config)
    curve = (run_dir / "learning_curve.csv").read_text().splitlines()
    assert len(curve) >= 2  # validated on the Gymnasium twin
    env = gym.make(GYM_ENV_ID, **TINY_ENV)
    policy, info = resolve_policy(str(best_model_path(run_dir)), env)  # compare's model
    assert isinstance(policy, PerAgentPolicy) and policy.layout == "swarm" and info["per_agent"]
    cost = _episode_cost(policy, env)
    row = per_agent_table(run_dir, dict(TINY_ENV), [3])[0].iloc[0]
    # each agent's own cost adds up to the swarm's cost of the same episode
    assert row["swarm cost (sum over agents), mean"] == pytest.approx(cost, rel=1e-5)
    description = json.loads((run_dir / "env.json").read_text())
    (run_dir / "env.json").write_text(json.dumps({**description, "env_id": GYM_ENV_ID}))
    again, _ = resolve_policy(str(run_dir / "final_model.zip"), env)
    assert isinstance(again, PerAgentPolicy) and again.layout == "swarm"
