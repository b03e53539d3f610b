"""The command line's one error path: a battery of bad invocations, one per option and more.

Every invocation runs in process (`cli.main`) and must return 2 with exactly one non-empty line
on stderr and no traceback, without creating its output folder: each subcommand checks all its
inputs before it trains, simulates or writes anything. The battery covers every option of every
subcommand (a test below checks that against the parsers) and the failures listed in issue 11.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import pickle
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import pytest

from agent_envs.training.commands.cli import SUBCOMMANDS, build_parser, main
from agent_envs.training.config import TrainConfig

SMALL = {"n_agents": 4, "n_steps": 4}


class _Planted:
    """Unpickling this creates a marker file: the stand-in for arbitrary code in a pickle."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (pathlib.Path.touch, (self.marker,))


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    """The files the battery refers to: a plain file, models, damaged models, results."""
    from stable_baselines3 import PPO

    from agent_envs.training.commands.evaluate import evaluate_policies

    root = tmp_path_factory.mktemp("battery")
    paths = {"root": root, "file": root / "a_file.txt"}
    paths["file"].write_text("not a folder\n")
    ppo = PPO("MlpPolicy", gym.make("agent_envs/Swarm-v0", **SMALL), n_steps=8, batch_size=8)
    ppo.save(root / "ppo.zip")
    paths["ppo"] = root / "ppo.zip"
    data = paths["ppo"].read_bytes()
    paths["truncated"] = root / "truncated.zip"
    paths["truncated"].write_bytes(data[: len(data) // 2])
    paths["corrupt"] = root / "corrupt.zip"
    paths["corrupt"].write_bytes(b"not a zip at all")
    planted = root / "planted"
    planted.mkdir()
    (planted / "final_model.zip").write_bytes(data)
    paths["marker"] = root / "pickle_ran"
    (planted / "final_model_vecnormalize.pkl").write_bytes(pickle.dumps(_Planted(paths["marker"])))
    paths["planted"] = planted / "final_model.zip"
    paths["results"] = root / "results"
    evaluate_policies(
        ["zero", "turnpike"],
        env_kwargs=SMALL,
        seeds=[0, 1],
        progress=False,
        out_dir=root / "results",
    )
    paths["empty"] = root / "empty"
    paths["empty"].mkdir()
    paths["damaged"] = root / "damaged"
    paths["damaged"].mkdir()
    (paths["damaged"] / "episodes.csv").write_text("policy,seed\nzero,oops\n")
    run = root / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps(TrainConfig().to_dict()))
    paths["run"] = run
    paths["badrun"] = root / "badrun"
    paths["badrun"].mkdir()
    (paths["badrun"] / "config.json").write_text("{not json")
    return paths


#: (argv, what the message must mention). {out}: a fresh folder that must not be created;
#: {file}, {ppo}, ...: the paths of the `files` fixture.
BATTERY: list[tuple[list[str], str]] = [
    # the top level and the reproduce alias
    (["bogus"], "invalid choice"),
    (["reproduce"], "reproduce"),
    (["reproduce", "bogus"], "reproduce"),
    # reproduce uncontrolled: --out --n-agents --n-paths --seed
    (["reproduce", "uncontrolled", "--out", "{out}", "--n-agents", "0"], "--n-agents"),
    (["reproduce", "uncontrolled", "--out", "{out}", "--n-agents", "x"], "--n-agents"),
    (["reproduce", "uncontrolled", "--out", "{out}", "--n-paths", "0"], "--n-paths"),
    (["reproduce", "uncontrolled", "--out", "{out}", "--n-paths", "10000000"], "--n-paths"),
    (
        [
            "reproduce",
            "uncontrolled",
            "--out",
            "{out}",
            "--n-agents",
            "10000000",
            "--n-paths",
            "99",
        ],
        "--n-paths",
    ),
    (["reproduce", "uncontrolled", "--out", "{out}", "--seed", "-1"], "--seed"),
    (["reproduce", "uncontrolled", "--out", "{out}", "--seed", str(2**32)], "--seed"),
    (["reproduce", "uncontrolled", "--out", "{file}"], "--out"),
    (["reproduce", "uncontrolled", "--out", "{file}/sub"], "--out"),
    (["reproduce", "uncontrolled", "--out", "{out}", "--bogus"], "--bogus"),
    # reproduce turnpike: --out --seeds --modes --n-agents --n-paths --n-steps --no-progress
    (["reproduce", "turnpike", "--out", "{out}", "--seeds", "-1"], "--seeds"),
    (["reproduce", "turnpike", "--out", "{out}", "--seeds", "x"], "--seeds"),
    (["reproduce", "turnpike", "--out", "{out}", "--seeds", "0", "0"], "--seeds"),
    # the one seed-list syntax (defaults.parse_seeds): N, A-B, A:B, comma- or space-separated
    (["reproduce", "turnpike", "--out", "{out}", "--seeds", "0-2,1"], "twice"),
    (["reproduce", "turnpike", "--out", "{out}", "--seeds", "3-1"], "empty"),
    (["reproduce", "turnpike", "--out", "{out}", "--seeds", "0,4294967296"], "largest seed"),
    (["reproduce", "turnpike", "--out", "{out}", "--seeds", "1.5"], "--seeds"),
    (["reproduce", "turnpike", "--out", "{out}", "--seeds", ","], "no seed"),
    (["reproduce", "turnpike", "--out", "{out}", "--modes", "bogus"], "--modes"),
    (["reproduce", "turnpike", "--out", "{out}", "--n-agents", "0"], "--n-agents"),
    (["reproduce", "turnpike", "--out", "{out}", "--n-paths", "0"], "--n-paths"),
    (["reproduce", "turnpike", "--out", "{out}", "--n-steps", "0"], "--n-steps"),
    (["reproduce", "turnpike", "--out", "{file}"], "--out"),
    (["reproduce", "turnpike", "--out", "{out}", "--no-progress=yes"], "--no-progress"),
    # reproduce turnpike-property: --out --n-agents --n-paths --tau --horizons --sigmas --epsilons
    # --kernels --delta --seed --max-control --gtol --max-iterations --no-progress
    (["reproduce", "turnpike-property", "--out", "{file}"], "--out"),
    (["reproduce", "turnpike-property", "--out", "{out}", "--n-agents", "1"], "--n-agents"),
    (["reproduce", "turnpike-property", "--out", "{out}", "--n-paths", "0"], "--n-paths"),
    (["reproduce", "turnpike-property", "--out", "{out}", "--tau", "0"], "--tau"),
    (["reproduce", "turnpike-property", "--out", "{out}", "--tau", "0.3"], "tau"),
    (["reproduce", "turnpike-property", "--out", "{out}", "--horizons", "-1"], "--horizons"),
    (["reproduce", "turnpike-property", "--out", "{out}", "--sigmas", "nan"], "--sigmas"),
    (["reproduce", "turnpike-property", "--out", "{out}", "--epsilons", "0"], "--epsilons"),
    (["reproduce", "turnpike-property", "--out", "{out}", "--kernels", "bogus"], "--kernels"),
    (["reproduce", "turnpike-property", "--out", "{out}", "--delta", "-1"], "--delta"),
    (["reproduce", "turnpike-property", "--out", "{out}", "--seed", "-1"], "--seed"),
    (["reproduce", "turnpike-property", "--out", "{out}", "--seed", str(2**32)], "--seed"),
    (["reproduce", "turnpike-property", "--out", "{out}", "--max-control", "0"], "--max-control"),
    (["reproduce", "turnpike-property", "--out", "{out}", "--gtol", "inf"], "--gtol"),
    (["reproduce", "turnpike-property", "--out", "{out}", "--max-iterations", "0"], "iterations"),
    (["reproduce", "turnpike-property", "--out", "{out}", "--no-progress=1"], "--no-progress"),
    (["reproduce", "turnpike-property", "--out", "{out}", "--n-seeds", "0"], "--n-seeds"),
    (["reproduce", "turnpike-property", "--out", "{out}", "--starts", "bogus"], "--starts"),
    # reproduce cheap-control-bound: --out --n-agents --n-paths --eval-paths --tau --horizons
    # --sigma --epsilon --beta --scaling-agents --scaling-horizon --scaling-epsilons --seed
    # --max-control --gtol --max-iterations --no-progress
    (["reproduce", "cheap-control-bound", "--out", "{file}"], "--out"),
    (["reproduce", "cheap-control-bound", "--out", "{out}", "--n-agents", "1"], "--n-agents"),
    (["reproduce", "cheap-control-bound", "--out", "{out}", "--n-paths", "0"], "--n-paths"),
    (["reproduce", "cheap-control-bound", "--out", "{out}", "--eval-paths", "1"], "--eval-paths"),
    (["reproduce", "cheap-control-bound", "--out", "{out}", "--tau", "0"], "--tau"),
    (["reproduce", "cheap-control-bound", "--out", "{out}", "--horizons", "0.33"], "--horizons"),
    (["reproduce", "cheap-control-bound", "--out", "{out}", "--sigma", "0"], "--sigma"),
    (["reproduce", "cheap-control-bound", "--out", "{out}", "--epsilon", "-1"], "--epsilon"),
    (["reproduce", "cheap-control-bound", "--out", "{out}", "--beta", "0"], "--beta"),
    (["reproduce", "cheap-control-bound", "--out", "{out}", "--scaling-agents", "1"], "agents"),
    (
        ["reproduce", "cheap-control-bound", "--out", "{out}", "--scaling-horizon", "0.07"],
        "horizon",
    ),
    (["reproduce", "cheap-control-bound", "--out", "{out}", "--scaling-epsilons", "0"], "epsilons"),
    (["reproduce", "cheap-control-bound", "--out", "{out}", "--seed", "-1"], "--seed"),
    (["reproduce", "cheap-control-bound", "--out", "{out}", "--max-control", "0"], "--max-control"),
    (["reproduce", "cheap-control-bound", "--out", "{out}", "--gtol", "0"], "--gtol"),
    (["reproduce", "cheap-control-bound", "--out", "{out}", "--max-iterations", "0"], "iterations"),
    (["reproduce", "cheap-control-bound", "--out", "{out}", "--no-progress=1"], "--no-progress"),
    # evaluate: --policy --env-id --env-kwargs --seeds --target --beta --delta --out --report
    # --no-progress
    (["evaluate"], "--out"),
    (["evaluate", "--out", "{out}", "-p", "nothing"], "nothing"),
    (["evaluate", "--out", "{out}", "-p", "{corrupt}"], "corrupt.zip"),
    (["evaluate", "--out", "{out}", "-p", "{truncated}"], "truncated.zip"),
    (["evaluate", "--out", "{out}", "-p", "sac:{ppo}"], "PPO"),
    (["evaluate", "--out", "{out}", "-p", "a=turnpike", "-p", "a=zero"], "twice"),
    (["evaluate", "--out", "{out}", "-p", "=zero"], "--policy"),
    (["evaluate", "--out", "{out}", "-p", "{planted}"], "refusing to load"),
    (["evaluate", "--out", "{out}", "-p", "{ppo}:{root}/missing.pkl"], "missing.pkl"),
    (["evaluate", "--out", "{out}", "-p", "{ppo}"], "expects observations"),
    (["evaluate", "--out", "{out}", "--env-id", "Bogus-v0"], "--env-id"),
    (["evaluate", "--out", "{out}", "--env-id", "CartPole-v1"], "not a swarm env"),
    (["evaluate", "--out", "{out}", "--env-id", "agent_envs.swarm_v0"], "PettingZoo"),
    (["evaluate", "--out", "{out}", "--env-kwargs", '{"bogus": 1}'], "bogus"),
    (["evaluate", "--out", "{out}", "--env-kwargs", '{"n_agents": -1}'], "n_agents"),
    (["evaluate", "--out", "{out}", "--env-kwargs", '{"neighbours": 0}'], "neighbours"),
    (["evaluate", "--out", "{out}", "--env-kwargs", '{"neighbours": 3}'], "observation='local'"),
    (["evaluate", "--out", "{out}", "--env-kwargs", "[1]"], "--env-kwargs"),
    (["evaluate", "--out", "{out}", "--env-kwargs", "{oops"], "--env-kwargs"),
    (["evaluate", "--out", "{out}", "--seeds", "x"], "--seeds"),
    (["evaluate", "--out", "{out}", "--seeds", "-1"], "--seeds"),
    (["evaluate", "--out", "{out}", "--seeds", "5:5"], "--seeds"),
    (["evaluate", "--out", "{out}", "--seeds", "0:1000000"], "--seeds"),
    (["evaluate", "--out", "{out}", "--seeds", "1", "1"], "--seeds"),
    (["evaluate", "--out", "{out}", "--seeds"], "--seeds"),
    (["evaluate", "--out", "{out}", "--seeds", "0:2", "1"], "twice"),
    (["evaluate", "--out", "{out}", "--seeds", "4294967290:4294967297"], "largest seed"),
    (["evaluate", "--out", "{out}", "--seeds", "0..3"], "A-B"),
    (["evaluate", "--out", "{out}", "--target", "nan"], "--target"),
    (["evaluate", "--out", "{out}", "--target", "inf"], "--target"),
    (["evaluate", "--out", "{out}", "--target", "x"], "--target"),
    (["evaluate", "--out", "{out}", "--target", "1e300"], "target"),
    (["evaluate", "--out", "{out}", "--beta", "-1"], "--beta"),
    (["evaluate", "--out", "{out}", "--beta", "nan"], "--beta"),
    (["evaluate", "--out", "{out}", "--delta", "0"], "--delta"),
    (["evaluate", "--out", "{file}"], "--out"),
    (["evaluate", "--out", "{file}/sub"], "--out"),
    (["evaluate", "--out", "{out}", "--report=yes"], "--report"),
    (["evaluate", "--out", "{out}", "--no-progress=yes"], "--no-progress"),
    # report: RESULTS --out --title --reference --seed-index
    (["report", "{root}/missing", "--out", "{out}"], "missing"),
    (["report", "{results}"], "--out"),
    (["report", "--out", "{out}"], "results"),
    (["report", "{empty}", "--out", "{out}"], "episodes.csv"),
    (["report", "{damaged}", "--out", "{out}"], "damaged"),
    (["report", "{results}", "--out", "{file}"], "--out"),
    (["report", "{results}", "--out", "{out}", "--reference", "bogus"], "--reference"),
    (["report", "{results}", "--out", "{out}", "--seed-index", "999"], "--seed-index"),
    (["report", "{results}", "--out", "{out}", "--seed-index", "-1"], "--seed-index"),
    (["report", "{results}", "--out", "{out}", "--seed-index", "x"], "--seed-index"),
    (["report", "{results}", "--out", "{out}", "--title"], "--title"),
    # train: one bad value per option
    (["train", "--out", "{out}", "--algo", "dqn"], "--algo"),
    (["train", "--out", "{out}", "--env-id", "CartPole-v1"], "not a swarm env"),
    (["train", "--out", "{out}", "--env-id", "Bogus-v0"], "--env-id"),
    (["train", "--out", "{out}", "--env-kwargs", '{"bogus": 1}'], "bogus"),
    (["train", "--out", "{out}", "--env-kwargs", "{oops"], "--env-kwargs"),
    (["train", "--out", "{out}", "--timesteps", "0"], "--timesteps"),
    (["train", "--out", "{out}", "--timesteps", "x"], "--timesteps"),
    (["train", "--out", "{out}", "--seed", "-1"], "--seed"),
    (["train", "--out", "{out}", "--seed", str(2**32)], "--seed"),
    (["train", "--out", "{file}"], "--out"),
    (["train", "--out", "{file}/sub"], "--out"),
    (["train", "--out", "{out}", "--run-name", "a/b"], "--run-name"),
    (["train", "--out", "{out}", "--run-name", ".."], "--run-name"),
    (["train", "--out", "{out}", "--n-envs", "0"], "--n-envs"),
    (["train", "--out", "{out}", "--hyperparams", '{"learning_rate": "fast"}'], "learning_rate"),
    (["train", "--out", "{out}", "--hyperparams", '{"bogus": 1}'], "bogus"),
    (["train", "--out", "{out}", "--hyperparams", '{"n_steps": 0}'], "n_steps"),
    (["train", "--out", "{out}", "--hyperparams", '{"batch_size": -1}'], "batch_size"),
    (["train", "--out", "{out}", "--hyperparams", '{"gamma": 2}'], "gamma"),
    (["train", "--out", "{out}", "--hyperparams", '{"seed": 3}'], "--seed"),
    (["train", "--out", "{out}", "--hyperparams", '{"n_envs": 2}'], "--n-envs"),
    (
        ["train", "--out", "{out}", "--hyperparams", '{"policy_kwargs": {"net_arch": "big"}}'],
        "net_arch",
    ),
    (
        ["train", "--out", "{out}", "--hyperparams", '{"policy_kwargs": {"bogus": 1}}'],
        "policy_kwargs",
    ),
    (["train", "--out", "{out}", "--hyperparams", "[1]"], "--hyperparams"),
    (
        ["train", "--out", "{out}", "--algo", "sac", "--hyperparams", '{"train_freq": 0}'],
        "train_freq",
    ),
    (["train", "--out", "{out}", "--normalize=maybe"], "--normalize"),
    (["train", "--out", "{out}", "--eval-freq", "-1"], "--eval-freq"),
    (["train", "--out", "{out}", "--eval-episodes", "0"], "--eval-episodes"),
    (["train", "--out", "{out}", "--eval-seed", "-1"], "--eval-seed"),
    (["train", "--out", "{out}", "--checkpoint-freq", "-1"], "--checkpoint-freq"),
    (["train", "--out", "{out}", "--turnpike-beta", "0"], "--turnpike-beta"),
    (["train", "--out", "{out}", "--turnpike-delta", "nan"], "--turnpike-delta"),
    (["train", "--out", "{out}", "--vec-env", "threads"], "--vec-env"),
    (["train", "--out", "{out}", "--device", "foo"], "--device"),
    (["train", "--out", "{out}", "--device", "cuda:99"], "--device"),
    (["train", "--out", "{out}", "--torch-threads", "-1"], "--torch-threads"),
    (["train", "--out", "{out}", "--env-threads", "0"], "--env-threads"),
    (["train", "--out", "{out}", "--env-threads", "100000"], "--env-threads"),
    (
        ["train", "--out", "{out}", "--env-id", "agent_envs.swarm_v0", "--env-threads", "2"],
        "--env-threads",
    ),
    (["train", "--out", "{out}", "--verbose", "3"], "--verbose"),
    (["train", "--out", "{out}", "--progress-bar=x"], "--progress-bar"),
    (["train", "--out", "{out}", "--tensorboard=x"], "--tensorboard"),
    (["train", "--resume", "{root}/no_run"], "--resume"),
    (["train", "--resume", "{run}", "--algo", "sac"], "--algo"),
    (["train", "--resume", "{badrun}"], "config.json"),
    # compare: one bad value per option
    # sweep: --preset --out --num-cpus --address --cpus-per-trial --resume --seeds --learners
    # --settings --timesteps-scale --test-episodes --vec-env --dry-run --bootstrap-seed
    (["sweep", "--out", "{out}", "--preset", "bogus"], "--preset"),
    (["tune", "--out", "{out}", "--preset", "bogus"], "--preset"),
    (["train", "--algo", "apg", "--timesteps", "10", "--out", "{out}"], "--timesteps"),
    (["train", "--algo", "apg", "--hyperparams", '{"iters": 1}', "--out", "{out}"], "iters"),
    (["train", "--algo", "apg", "--hyperparams", '{"hidden": -1}', "--out", "{out}"], "hidden"),
    (["train", "--algo", "apg", "--env-kwargs", '{"n_agents": 0}', "--out", "{out}"], "n_agents"),
    (["tune", "--out", "{out}", "--preset", "paper", "--learner", "apg"], "--learner"),
    (["tune", "--out", "{out}", "--learner", "dqn"], "--learner"),
    (["tune", "--out", "{out}", "--setting", "eps1"], "--setting"),
    (["tune", "--out", "{file}", "--dry-run"], "--out"),
    (["tune", "--out", "{out}", "--num-samples", "0"], "--num-samples"),
    (["tune", "--out", "{out}", "--seeds", "-1"], "--seeds"),
    (["tune", "--out", "{out}", "--seeds", "0", "1", "0"], "--seeds"),
    (["tune", "--out", "{out}", "--seed-objective", "best"], "--seed-objective"),
    (["tune", "--out", "{out}", "--sampler-seed", "-3"], "--sampler-seed"),
    (["tune", "--out", "{out}", "--pruner", "hyperband"], "--pruner"),
    (["tune", "--out", "{out}", "--num-cpus", "0"], "--num-cpus"),
    (["tune", "--out", "{out}", "--address", ""], "--address"),
    (["tune", "--out", "{out}", "--cpus-per-trial", "nan"], "--cpus-per-trial"),
    (["tune", "--out", "{out}", "--timesteps-scale", "0"], "--timesteps-scale"),
    (["tune", "--out", "{out}", "--vec-env", "threads"], "--vec-env"),
    (["tune", "--out", "{out}", "--env-kwargs", '{"n_agents": -1}'], "n_agents"),
    (["tune", "--out", "{out}", "--resume=x"], "--resume"),
    (["tune", "--out", "{out}", "--dry-run=x"], "--dry-run"),
    (["sweep", "--out", "{out}", "--env-kwargs", '{"n_agents": 0}'], "n_agents"),
    (["sweep", "--out", "{out}", "--env-kwargs", "[1]"], "--env-kwargs"),
    (["sweep", "--out", "{file}"], "--out"),
    (["sweep", "--out", "{out}", "--num-cpus", "0"], "--num-cpus"),
    (["sweep", "--out", "{out}", "--address", ""], "--address"),
    (["sweep", "--out", "{out}", "--cpus-per-trial", "-1"], "--cpus-per-trial"),
    (["sweep", "--out", "{out}", "--resume"], "--resume"),
    (["sweep", "--out", "{out}", "--seeds", "0,x"], "--seeds"),
    (["sweep", "--out", "{out}", "--learners", "dqn"], "--learners"),
    (["sweep", "--out", "{out}", "--settings", "bogus"], "--settings"),
    (["sweep", "--out", "{out}", "--timesteps-scale", "0"], "--timesteps-scale"),
    (["sweep", "--out", "{out}", "--test-episodes", "1"], "--test-episodes"),
    (["sweep", "--out", "{out}", "--vec-env", "threads"], "--vec-env"),
    (["sweep", "--out", "{out}", "--dry-run=1"], "--dry-run"),
    (["sweep", "--out", "{out}", "--bootstrap-seed", "-1"], "--bootstrap-seed"),
    (["compare", "--out", "{out}", "--preset", "bogus"], "--preset"),
    (["compare", "--out", "{out}", "--setting", "eps1"], "--setting"),  # quick has only main
    (["compare", "--out", "{out}", "--vec-env", "threads"], "--vec-env"),
    (["compare", "--out", "{out}", "--preset", "paper", "--setting", "bogus"], "--setting"),
    (["compare", "--out", "{out}", "--optimum", "optimal,bogus"], "--optimum"),
    (["compare", "--out", "{out}", "--optimum", "mpc,mpc"], "--optimum"),
    (["compare", "--out", "{file}"], "--out"),
    (["compare", "--out", "{out}", "--learners", "ppo,dqn"], "--learners"),
    (["compare", "--out", "{out}", "--learners", ","], "--learners"),
    (["compare", "--out", "{out}", "--seed", "-1"], "--seed"),
    (["compare", "--out", "{out}", "--env-kwargs", '{"bogus": 1}'], "bogus"),
    (["compare", "--out", "{out}", "--eval-env-kwargs", '{"bogus": 1}'], "--eval-env-kwargs"),
    (["compare", "--out", "{out}", "--eval-env-kwargs", '{"n_agents": 0}'], "--eval-env-kwargs"),
    (["compare", "--out", "{out}", "--timesteps-scale", "0"], "--timesteps-scale"),
    (["compare", "--out", "{out}", "--timesteps-scale", "inf"], "--timesteps-scale"),
    (["compare", "--out", "{out}", "--test-episodes", "1"], "--test-episodes"),
    (["compare", "--out", "{out}", "--retrain=x"], "--retrain"),
    (["compare", "--out", "{out}", "--progress-bar=x"], "--progress-bar"),
    (["compare", "--out", "{out}", "--verbose", "7"], "--verbose"),
    (["compare", "--out", "{out}", "--torch-threads", "-1"], "--torch-threads"),
    # the benchmark: tasks, evaluate --task, leaderboard
    (["tasks", "--regenerate", "agent_envs/Nope-v0"], "the tasks are"),
    (["tasks", "--verify", "agent_envs/StiffSwarm-v9"], "has no version v9"),
    (["tasks", "--verify", "all", "--verify-seeds", "0"], "--verify-seeds"),
    (["tasks", "--regenerate", "all", "--workers", "0"], "--workers"),
    (["tasks", "--regenerate", "all", "--work-dir", "{file}"], "--work-dir"),
    (["tasks", "--regenerate", "all", "--data-dir", "{file}"], "--data-dir"),
    (["tasks", "--json=yes"], "--json"),
    (["evaluate", "--out", "{out}", "--task", "agent_envs/Nope-v0"], "the tasks are"),
    (["evaluate", "--out", "{out}", "--task", "StiffSwarm-v0", "--target", "0.1"], "--target"),
    (["leaderboard", "--out", "{file}"], "--out"),
    (["leaderboard", "--out", "{out}", "--tasks", "Nope-v0"], "the tasks are"),
    (["leaderboard", "--out", "{out}", "--seeds", "x"], "--seeds"),
    (["leaderboard", "--out", "{out}", "--workers", "0"], "--workers"),
    (["leaderboard", "--out", "{out}", "--learners", "ppo-magic"], "--learners"),
    (["leaderboard", "--out", "{out}", "--timesteps-scale", "0"], "--timesteps-scale"),
    (["leaderboard", "--out", "{out}", "--table", "{file}/t.md"], "--table"),
    # the published tables
    (["tables", "--root", "{out}"], "--root"),
    (["tables", "--root", "{file}", "--check"], "--root"),
    (["tables", "--check=x"], "--check"),
    (["tables", "--figures=x"], "--figures"),
]


def _fill(argv: list[str], files: dict[str, Path], out: Path) -> list[str]:
    names = {"out": str(out), **{k: str(v) for k, v in files.items()}}
    filled = []
    for arg in argv:
        for key, value in names.items():
            arg = arg.replace("{" + key + "}", value)
        filled.append(arg)
    return filled


def test_battery_is_large_and_covers_every_option():
    assert len(BATTERY) >= 60
    used = {a.split("=")[0] for argv, _ in BATTERY for a in argv if a.startswith("-")}
    for name in SUBCOMMANDS:
        parser = build_parser(name)
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[
            name
        ]
        for action in sub._actions:
            if action.dest == "help":
                continue
            if action.option_strings:
                assert used & set(action.option_strings), (name, action.option_strings)


@pytest.mark.filterwarnings("error")  # a warning would be a second stderr line in a terminal
@pytest.mark.parametrize(("argv", "mentions"), BATTERY, ids=[" ".join(a)[:60] for a, _ in BATTERY])
def test_bad_invocation_is_one_line_and_exit_2(argv, mentions, files, tmp_path, capsys):
    out = tmp_path / "out"
    filled = _fill(argv, files, out)
    code = main(filled)
    err = capsys.readouterr().err
    assert code == 2, (filled, err)
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err
    assert err.startswith("agent-envs"), err
    assert _fill([mentions], files, out)[0] in err, err
    assert not out.exists(), f"{filled} created its output folder before failing"
    assert not files["marker"].exists(), "an untrusted pickle was loaded"


def test_untrusted_statistics_are_never_unpickled(files, tmp_path, capsys):
    """The planted pickle runs code when loaded; evaluate refuses it and says how to name it."""
    code = main(["evaluate", "-p", str(files["planted"]), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and not files["marker"].exists()
    assert f"{files['planted']}:{files['planted'].parent / 'final_model_vecnormalize.pkl'}" in err


def test_the_script_prints_one_line_too(tmp_path):
    """Out of process (imports of torch and SB3 included, no pytest capture): still one line."""
    argv = ["train", "--device", "foo", "--out", str(tmp_path / "o")]
    done = subprocess.run(
        [sys.executable, "-m", "agent_envs.training.commands.cli", *argv],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and done.stderr.startswith("agent-envs train: error:")


def test_help_still_exits_zero(capsys):
    for name in SUBCOMMANDS:
        with pytest.raises(SystemExit) as exc:
            main([name, "--help"])
        assert exc.value.code == 0
    capsys.readouterr()
