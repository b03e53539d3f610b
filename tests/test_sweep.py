"""`agent-envs sweep`: the grid without Ray, and (slow) the smoke sweep on a local Ray
instance (skipped without the `sweep` extra)."""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from agent_envs.training.commands.experiment import (
    LEARNER,
    REFERENCE,
    ExperimentOptions,
    Trial,
    build_trials,
)
from agent_envs.training.commands.presets import PRESETS
from agent_envs.training.config import VEC_ENV_CHOICES, TrainConfig, read_hyperparams_file

# ------------------------------------------------------------------------------- the grid


def test_smoke_grid_is_two_learner_trials_and_the_three_references():
    trials = build_trials(PRESETS["smoke"], runs_dir="/x/runs")
    learners = [t for t in trials if t.kind == LEARNER]
    references = [t for t in trials if t.kind == REFERENCE]
    assert [(t.policy, t.seed) for t in learners] == [("ppo", 0), ("ppo", 1)]
    assert sorted(t.policy for t in references) == ["proportional", "turnpike", "zero"]
    assert {t.trial_id for t in trials} == {
        "main__ppo__0",
        "main__ppo__1",
        "main__turnpike",
        "main__proportional",
        "main__zero",
    }
    for t in learners:
        config = TrainConfig.from_dict(t.train).validate()
        assert config.run_name == t.trial_id and config.out == "/x/runs"
        assert config.env_kwargs == {"n_agents": 5, "n_steps": 5} == t.eval_env_kwargs
        assert config.timesteps == 256 and config.seed == t.seed
        assert not config.progress_bar
    assert all(t.test_seeds == (10000, 10001, 10002, 10003, 10004) for t in trials)


def test_trial_round_trips_through_json():
    for trial in build_trials(PRESETS["smoke"]):
        assert Trial.from_dict(json.loads(json.dumps(trial.to_dict()))) == trial


def test_grid_options_change_seeds_budget_and_test_episodes():
    options = ExperimentOptions(seeds=(3, 4, 5), timesteps_scale=0.5, test_episodes=3)
    trials = build_trials(PRESETS["smoke"], options)
    learners = [t for t in trials if t.kind == LEARNER]
    assert [t.seed for t in learners] == [3, 4, 5]
    assert {t.train["timesteps"] for t in learners} == {128}
    assert all(len(t.test_seeds) == 3 for t in trials)


@pytest.mark.parametrize(
    ("options", "flag"),
    [
        (ExperimentOptions(learners=("dqn",)), "--learners"),
        (ExperimentOptions(settings=("nope",)), "--settings"),
        (ExperimentOptions(seeds=(0, 0)), "--seeds"),
        (ExperimentOptions(seeds=(-1,)), "--seeds"),
        (ExperimentOptions(timesteps_scale=0.0), "--timesteps-scale"),
        (ExperimentOptions(test_episodes=1), "--test-episodes"),
        (ExperimentOptions(vec_env="threads"), "--vec-env"),
    ],
)
def test_bad_grid_options_name_the_option(options, flag):
    with pytest.raises(ValueError, match=flag):
        build_trials(PRESETS["smoke"], options)


def test_paper_preset_definition():
    preset = PRESETS["paper"]
    assert preset.env_kwargs == {
        "n_agents": 100,
        "n_steps": 50,
        "epsilon": 0.05,
        "alpha": 0.1,
        "sigma": 0.01,
        "horizon": 1.0,
        "target": 0.7,
        "integrator": "serb",
        "n_paths": 20,
        "max_control": 25.0,
    }
    assert preset.references == (
        "optimal",
        "mpc",
        "turnpike",
        "proportional",
        "zero",
        "proportional-common",
    )
    assert len(preset.seeds) >= 3
    assert preset.vec_env == "native" and preset.vec_env in VEC_ENV_CHOICES
    sb3 = [t for t in build_trials(preset) if t.kind == LEARNER and t.train["algo"] != "apg"]
    assert {t.train["vec_env"] for t in sb3} == {
        "native",
        "dummy",  # the PettingZoo learner trains on SuperSuit's vector env
    }
    trials = build_trials(preset, ExperimentOptions(vec_env="dummy"))
    learners = [t for t in trials if t.kind == LEARNER]
    main = {(t.policy, t.seed) for t in learners if t.setting == "main"}
    names = ("ppo", "ppo-modes", "sac", "td3", "ppo-shared", "ppo-local", "apg")
    assert main == {(a, s) for a in names for s in preset.seeds}
    eps1 = {t.policy for t in learners if t.setting == "eps1"}
    assert eps1 == {"ppo", "sac", "ppo-shared", "ppo-local", "apg"}
    em = {t.policy for t in learners if t.setting == "em-to-serb"}
    assert em == {"ppo", "sac", "apg"}
    # apg: APGConfig's defaults (what benchmarks/bench_apg.py measured) on the setting's env
    apg = next(t for t in learners if t.policy == "apg" and t.setting == "main")
    assert apg.train["iterations"] == 300 and apg.train["eval_freq"] == 25
    assert apg.train["env_kwargs"] == preset.env_kwargs and apg.train["train_paths"] == 4
    # each SB3 learner trains with its env options and the hyperparams/paper.yml entry; it is
    # evaluated on the setting's env (the default interface)
    options = {
        "ppo": {"observation": "summary", "action_basis": "common"},
        "ppo-modes": {"observation": "modes", "action_basis": "modes"},
        "sac": {"observation": "summary", "action_basis": "common"},
        "td3": {"observation": "summary", "action_basis": "common"},
        "ppo-shared": {"observation": "swarm", "agent_reward": "team"},
        "ppo-local": {"observation": "local", "neighbours": 6, "agent_reward": "team"},
    }
    entries = read_hyperparams_file("paper")
    for trial in (t for t in learners if t.setting == "main" and t.policy != "apg"):
        config = TrainConfig.from_dict(trial.train)
        assert config.env_kwargs == {**preset.env_kwargs, **options[trial.policy]}
        assert trial.eval_env_kwargs == preset.env_kwargs
        entry = dict(entries[trial.policy])
        assert config.n_envs == entry.pop("n_envs")
        assert config.normalize == entry.pop("normalize", None)  # rl-zoo3's key -> --normalize
        assert all(config.hyperparams[key] == value for key, value in entry.items())
    by_setting = {t.setting: t for t in learners if t.policy != "apg"}
    assert by_setting["eps1"].train["env_kwargs"]["epsilon"] == 1.0
    em = by_setting["em-to-serb"]
    assert em.train["env_kwargs"]["integrator"] == "em"
    assert em.eval_env_kwargs["integrator"] == "serb"
    shared = next(t for t in learners if t.policy == "ppo-shared")
    assert shared.train["env_id"] == "agent_envs.swarm_v0" and shared.train["algo"] == "ppo"
    # train-on-EM is evaluated on the main env: the main setting's reference trials serve both
    references = [t for t in trials if t.kind == REFERENCE]
    for ref in references:
        if ref.setting == "main":
            assert ref.settings == ("main", "em-to-serb")
    from agent_envs.training.commands.experiment import available_references

    wanted, lacking = available_references(preset)
    assert not lacking  # the centre law is an interface reference, not a BASELINES entry
    assert sorted(t.policy for t in references if t.setting == "main") == sorted(wanted)
    bound = [t for t in learners if t.setting == "bound150"]
    assert {t.policy for t in bound} == {"ppo"}
    assert all(t.train["env_kwargs"]["max_control"] == 150.0 for t in bound)
    eps1 = sorted(t.policy for t in references if t.setting == "eps1")
    assert eps1 == sorted(r for r in wanted if r != "mpc")  # MPC: the main setting only


@pytest.mark.parametrize("algo", ["ppo", "sac", "td3"])
def test_zoo_pendulum_file_holds_rl_zoo3_pendulum_entries(algo):
    """hyperparams/zoo_pendulum.yml (the first paper study's learners) holds every key of
    rl-zoo3's tuned Pendulum-v1 entry with the zoo's value (budget, buffer and policy apart)."""
    pytest.importorskip("yaml")
    # find_spec, not import: importing rl_zoo3 patches gymnasium's TimeLimit for the whole test
    # process (rl_zoo3.gym_patches), which breaks the vector env's equivalence tests
    spec = importlib.util.find_spec("rl_zoo3")
    if spec is None or spec.origin is None:
        pytest.skip("rl_zoo3 is the optional 'zoo' extra")
    import yaml

    path = Path(spec.origin).parent / "hyperparams" / f"{algo}.yml"
    zoo = yaml.safe_load(path.read_text())["Pendulum-v1"]
    shipped = read_hyperparams_file("zoo_pendulum")[algo]
    for key, value in zoo.items():
        if key in ("n_timesteps", "policy", "buffer_size"):
            continue  # the study sized the replay buffer to its budget (in the preset)
        if key == "policy_kwargs":
            value = eval(value, {"dict": dict})  # the zoo writes "dict(net_arch=[400, 300])"
        assert shipped[key] == value, key


# ------------------------------------------------------------------------------------ CLI


def test_sweep_dry_run_lists_the_trials(capsys):
    from agent_envs.training.commands.cli import main

    assert main(["sweep", "--preset", "smoke", "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "main__ppo__0: train ppo" in out and "main__zero: evaluate zero" in out


def test_sweep_bad_seeds_is_a_clean_error(capsys):
    from agent_envs.training.commands.cli import main

    assert main(["sweep", "--preset", "smoke", "--dry-run", "--seeds", "a,b"]) == 2
    assert "--seeds" in capsys.readouterr().err


def test_resume_needs_a_started_sweep_and_a_second_start_needs_resume(tmp_path):
    from agent_envs.training.commands.sweep import SweepConfig, _load_or_save_grid

    out = tmp_path / "sw"
    with pytest.raises(ValueError, match="--resume"):
        _load_or_save_grid(SweepConfig(preset="smoke", out=str(out), resume=True), out)
    _, trials, command = _load_or_save_grid(SweepConfig(preset="smoke", out=str(out)), out)
    assert command.startswith("agent-envs sweep --preset smoke --out")
    assert (out / "sweep.json").is_file() and len(trials) == 5
    with pytest.raises(ValueError, match="--resume"):
        _load_or_save_grid(SweepConfig(preset="smoke", out=str(out)), out)
    # the resumed grid is the saved one, whatever grid options come with --resume
    resumed, again, _ = _load_or_save_grid(
        SweepConfig(preset="smoke", out=str(out), resume=True, seeds="7"), out
    )
    assert again == trials and resumed.seeds is None


# ------------------------------------------------------------------------- smoke (slow)


@pytest.mark.slow
def test_smoke_sweep_writes_the_report_and_the_run_folders(tmp_path):
    pytest.importorskip("ray")
    pytest.importorskip("rliable")
    from agent_envs.training.commands.cli import main
    from agent_envs.training.results.seed_statistics import iqm
    from agent_envs.training.results.tables import EvaluationResults

    out = tmp_path / "sweep"
    args = ["sweep", "--preset", "smoke", "--out", str(out), "--num-cpus", "2"]
    assert main(args) == 0
    report = (out / "report" / "report.md").read_text()
    for heading in ("Results per policy", "Across training seeds", "Learning curves"):
        assert heading in report
    assert "ppo (seed 0)" in report and "ppo (seed 1)" in report
    assert (out / "report" / "learning_curves_main.png").stat().st_size > 0
    costs = []
    for seed in (0, 1):
        run = out / "runs" / f"main__ppo__{seed}"
        for name in ("config.json", "learning_curve.csv", "summary.json"):
            assert (run / name).is_file(), name
        assert (out / "runs" / f"main__ppo__{seed}.sweep_trial.log").is_file()
        assert any((run / "tb").rglob("events.out.tfevents.*"))
        assert json.loads((run / "summary.json").read_text())["timesteps"] >= 256
        episodes = EvaluationResults.load(run / "test_evaluation").episodes
        assert list(episodes["seed"]) == list(range(10000, 10005))
        costs.append(episodes["total_cost"].to_numpy())
    # the report's IQM is the IQM of the two runs' test costs
    stats = pd.read_csv(out / "report" / "across_seeds.csv").set_index("policy")
    assert stats.loc["ppo", "runs"] == 2 and stats.loc["ppo", "episodes"] == 10
    assert stats.loc["ppo", "iqm_cost"] == pytest.approx(-iqm(-np.stack(costs)))
    assert set(stats.index) == {"ppo", "turnpike", "proportional", "zero"}
    # docs/sweep.md's table renders from the episodes files alone as the report shows it
    from agent_envs.training.commands.sweep_report import across_seed_markdown

    files = [
        out / "runs" / f"main__ppo__{seed}" / "test_evaluation" / "episodes.csv" for seed in (0, 1)
    ]
    files += [
        out / "references" / "main" / r / "episodes.csv"
        for r in ("turnpike", "proportional", "zero")
    ]
    assert across_seed_markdown(*files) in report
    assert not any(Path.cwd().glob("ray_results"))
    # every trial's wall time, as Tune recorded it, in grid order
    times = pd.read_csv(out / "report" / "trial_wall_times.csv")
    assert list(times["trial"]) == [
        "main__ppo__0",
        "main__ppo__1",
        "main__turnpike",
        "main__proportional",
        "main__zero",
    ]
    assert "Wall time per trial" in report
    assert (times["wall time [s]"] >= 0).all()  # a reference at N = 5 can round to 0.0 s
    assert (times.loc[times["kind"] == "learner", "wall time [s]"] > 0).all()

    # resuming a finished sweep trains nothing again and rewrites the report
    before = json.loads((out / "runs" / "main__ppo__0" / "summary.json").read_text())
    assert main([*args, "--resume"]) == 0
    after = json.loads((out / "runs" / "main__ppo__0" / "summary.json").read_text())
    assert after == before
    assert "# resumed with --resume" in (out / "report" / "report.md").read_text()
    # the restored Tune results keep the first run's wall times
    assert pd.read_csv(out / "report" / "trial_wall_times.csv").equals(times)
    assert sorted(p.name for p in (out / "runs").iterdir() if p.is_dir()) == [
        "main__ppo__0",
        "main__ppo__1",
    ]


def _agent_envs() -> list[str]:
    """The installed `agent-envs` script of this interpreter's environment."""
    return [str(Path(sys.executable).parent / "agent-envs")]


@pytest.mark.slow
def test_resume_after_a_killed_driver_finishes_and_leaves_no_ray_process(tmp_path):
    """SIGKILL the sweep's driver (an OOM kill, a lost terminal) while its trials run: the
    local Ray instance's processes it leaves behind are ended by the next run in the same OUT,
    and `--resume` finishes the sweep."""
    pytest.importorskip("ray")
    pytest.importorskip("rliable")
    pytest.importorskip("psutil")
    from agent_envs.training.ray_session import RAY_SESSION_FILE, session_processes

    out = tmp_path / "sweep"
    command = [*_agent_envs(), "sweep", "--preset", "smoke", "--out", str(out), "--num-cpus", "2"]
    driver = subprocess.Popen(
        [*command, "--timesteps-scale", "40"],
        cwd=tmp_path,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    record = out / RAY_SESSION_FILE
    deadline = time.monotonic() + 120
    while not any((out / "runs").glob("*.sweep_trial.log")) and time.monotonic() < deadline:
        assert driver.poll() is None, "the sweep ended before it could be killed"
        time.sleep(0.5)
    assert record.is_file()
    session_dir = json.loads(record.read_text())["session_dir"]
    time.sleep(3)  # the trials are running
    driver.send_signal(signal.SIGKILL)
    driver.wait(timeout=30)
    resumed = subprocess.run(
        [*command, "--timesteps-scale", "40", "--resume"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert (out / "report" / "report.md").is_file()
    assert session_processes(session_dir) == []  # nothing of the killed run's Ray is left
    assert not record.exists()  # the resumed run shut its own Ray down


@pytest.mark.slow
def test_smoke_sweep_on_a_two_node_cluster_with_token_auth(tmp_path):
    """`sweep --address` on a two-node Ray cluster started on the loopback address (head + one
    worker node, token authentication as Ray 2.60 sets it up: the token in ~/.ray/auth_token of
    every node and the driver, RAY_AUTH_MODE=token); the trials run on both nodes."""
    pytest.importorskip("ray")
    pytest.importorskip("rliable")
    ray_cli = str(Path(sys.executable).parent / "ray")
    port = _free_port()
    env = {**os.environ, "HOME": str(tmp_path), "RAY_AUTH_MODE": "token"}
    env["RAY_USAGE_STATS_ENABLED"] = "0"

    def ray(*args: str) -> None:
        subprocess.run([ray_cli, *args], env=env, check=True, capture_output=True, timeout=120)

    ray("get-auth-token", "--generate")
    # a temp dir of its own (short: Ray's unix sockets live there), so that the cluster's
    # processes, and only they, are ended at the end (`ray stop` would end every Ray instance
    # on the machine, a sweep of the user's included)
    temp_dir = Path(tempfile.mkdtemp(prefix="rt", dir="/tmp"))
    try:
        ray(
            "start",
            "--head",
            "--node-ip-address=127.0.0.1",
            f"--port={port}",
            "--num-cpus=1",
            "--include-dashboard=false",
            "--disable-usage-stats",
            f"--temp-dir={temp_dir}",
        )
        ray("start", f"--address=127.0.0.1:{port}", "--node-ip-address=127.0.0.1", "--num-cpus=1")
        out = tmp_path / "sweep"
        address = f"127.0.0.1:{port}"
        driver = subprocess.run(
            [*_agent_envs(), "sweep", "--preset", "smoke", "--out", str(out), "--address", address],
            env=env,
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=600,
        )
    finally:
        _end_cluster(temp_dir)
    assert driver.returncode == 0, driver.stderr[-2000:]
    report = (out / "report" / "report.md").read_text()
    assert "ppo (seed 0)" in report and "ppo (seed 1)" in report
    nodes = pd.read_csv(out / "report" / "trial_wall_times.csv")["node"]
    assert len(nodes) == 5 and nodes.nunique() == 2  # both nodes ran trials


def _end_cluster(temp_dir: Path) -> None:
    """End the processes of the test's Ray cluster: those holding a file of its session, under
    its temp dir (the head node) or under Ray's default /tmp/ray with the same session name
    (a worker node started with --address), then remove the temp dir."""
    import shutil

    from agent_envs.training.ray_session import end_processes, session_processes

    sessions = sorted(temp_dir.glob("session_2*"))
    folders = [str(s) for s in sessions]
    folders += [str(Path("/tmp/ray") / s.name) for s in sessions]
    processes = {p.pid: p for folder in folders for p in session_processes(folder)}
    end_processes(list(processes.values()))
    shutil.rmtree(temp_dir, ignore_errors=True)


def _free_port() -> int:
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def test_reference_trial_without_ray_evaluates_once_then_reuses(tmp_path):
    """`execute_trial` (what each Tune trial runs) evaluates the reference on the test seeds
    into its folder; run again (a resumed trial), it reuses the finished evaluation."""
    from agent_envs.training.commands.experiment import TRIAL_LOG, evaluation_dir
    from agent_envs.training.commands.sweep import execute_trial
    from agent_envs.training.results.tables import EvaluationResults

    trial = next(t for t in build_trials(PRESETS["smoke"]) if t.policy == "turnpike")
    first = execute_trial(trial, tmp_path)
    folder = evaluation_dir(trial, tmp_path)
    episodes = EvaluationResults.load(folder).episodes
    assert list(episodes["seed"]) == list(trial.test_seeds)
    assert first["mean_cost"] == pytest.approx(episodes["total_cost"].mean())
    second = execute_trial(trial, tmp_path)
    assert second["mean_cost"] == first["mean_cost"]
    assert "reusing the finished evaluation" in (folder / TRIAL_LOG).read_text()


def test_paper_preset_takes_optimal_and_mpc_once_the_baselines_have_them(monkeypatch):
    """With `optimal` and `mpc` registered (the optimal-control branch), the main env gets all
    six references (shared with the EM-trained contrast) and eps = 1 all but MPC."""
    from agent_envs.baselines import BASELINES

    for name in ("optimal", "mpc"):
        monkeypatch.setitem(BASELINES, name, object)
    trials = build_trials(PRESETS["paper"], ExperimentOptions(vec_env="dummy"))
    by_setting: dict[str, set[str]] = {}
    for t in trials:
        if t.kind == REFERENCE:
            for setting in t.settings:
                by_setting.setdefault(setting, set()).add(t.policy)
    six = {"optimal", "mpc", "turnpike", "proportional", "zero", "proportional-common"}
    assert by_setting == {
        "main": six,
        "em-to-serb": six,
        "eps1": six - {"mpc"},
        "bound150": six - {"mpc"},
    }


def test_paper_preset_builds_mpc_on_the_noise_free_model_and_the_rest_on_defaults():
    """The paper preset's MPC trial carries `noise_free=True` (certainty-equivalent MPC: the
    20-path re-solve at every step would cost ~1.7 core-h for 20 episodes); no other reference
    gets arguments, and the arguments survive the grid's JSON round trip (resume)."""
    trials = build_trials(PRESETS["paper"], ExperimentOptions(vec_env="dummy"))
    kwargs = {t.trial_id: t.policy_kwargs for t in trials if t.kind == REFERENCE}
    assert kwargs.pop("main__mpc") == {"noise_free": True}
    assert kwargs and all(v == {} for v in kwargs.values())
    for trial in trials:
        assert Trial.from_dict(json.loads(json.dumps(trial.to_dict()))) == trial


def test_trial_saved_before_policy_kwargs_existed_loads_with_none():
    """A grid.json written before `policy_kwargs` (an interrupted sweep resumed by this version)
    loads with empty arguments."""
    trial = next(t for t in build_trials(PRESETS["smoke"]) if t.kind == REFERENCE)
    old = trial.to_dict()
    del old["policy_kwargs"]
    assert Trial.from_dict(old) == trial and Trial.from_dict(old).policy_kwargs == {}


def test_reference_trial_builds_its_controller_with_the_trial_kwargs(tmp_path):
    """`execute_trial` builds a reference with its `policy_kwargs`: the noise-free MPC plans
    one path (its repr says so) and its evaluation differs from no controller at all."""
    from agent_envs.training.commands.experiment import TRIAL_LOG, evaluation_dir
    from agent_envs.training.commands.sweep import execute_trial
    from agent_envs.training.results.tables import EvaluationResults

    env = {"n_agents": 4, "n_steps": 4}
    trial = Trial(
        "main__mpc",
        REFERENCE,
        "main",
        "mpc",
        None,
        env,
        (10000, 10001),
        ("main",),
        policy_kwargs={"noise_free": True},
    )
    zero = Trial("main__zero", REFERENCE, "main", "zero", None, env, (10000, 10001), ("main",))
    mpc_metrics, zero_metrics = execute_trial(trial, tmp_path), execute_trial(zero, tmp_path)
    folder = evaluation_dir(trial, tmp_path)
    assert "built with {'noise_free': True}" in (folder / TRIAL_LOG).read_text()
    episodes = EvaluationResults.load(folder).episodes
    assert list(episodes["seed"]) == [10000, 10001]
    assert mpc_metrics["mean_cost"] < zero_metrics["mean_cost"]


# ----------------------------------------------------------------- one preset, two commands


def test_compare_runs_one_seed_of_the_sweeps_grid():
    """`compare --preset paper` and `sweep --preset paper` mean the same setting: compare's
    learner configs are the sweep's main-setting configs of its seed, but for the run folder
    naming (compare finds finished runs by their configuration) and compare's progress bar."""
    from agent_envs.training.commands.compare import CompareConfig

    compare = [t for t in CompareConfig(preset="paper", out="x").trials() if t.kind == LEARNER]
    sweep = [
        t
        for t in build_trials(PRESETS["paper"], runs_dir="x/runs")
        if t.kind == LEARNER and t.setting == "main" and t.seed == 0
    ]
    assert [t.policy for t in compare] == [t.policy for t in sweep]
    for c, s in zip(compare, sweep, strict=True):
        same = {"run_name": None, "progress_bar": None, "progress": None}
        assert {**c.train, **same} == {**s.train, **same}
        assert c.eval_env_kwargs == s.eval_env_kwargs and c.test_seeds == s.test_seeds
    # a contrast setting: its learners, its env, its evaluation env
    em = CompareConfig(preset="paper", setting="em-to-serb", seed=2, out="x").trials()
    learners = [t for t in em if t.kind == LEARNER]
    assert [(t.policy, t.seed) for t in learners] == [("ppo", 2), ("sac", 2), ("apg", 2)]
    assert learners[0].train["env_kwargs"]["integrator"] == "em"
    assert {t.eval_env_kwargs["integrator"] for t in em} == {"serb"}


def test_compare_references_are_the_presets_with_optimum_chosen():
    from agent_envs.training.commands.compare import CompareConfig

    def references(**kw):
        return [t.policy for t in CompareConfig(out="x", **kw).trials() if t.kind == REFERENCE]

    # the quick preset: the optimum but no MPC (equal to it within 0.03% at sigma = 0.01 on the
    # validation seeds, docs/presets.md), and the centre law, the summary/common learners' fair
    # baseline
    feedback = ["turnpike", "proportional", "zero", "proportional-common"]
    assert references() == [*feedback, "optimal"]
    assert references(optimum="") == feedback
    assert references(optimum="mpc") == [*feedback, "mpc"]
    assert references(optimum="optimal,mpc") == [*feedback, "optimal", "mpc"]
    # the paper preset's MPC plans on the noise-free model, in compare as in the sweep
    mpc = next(t for t in CompareConfig(preset="paper", out="x").trials() if t.policy == "mpc")
    assert mpc.policy_kwargs == {"noise_free": True}


def test_no_two_presets_share_a_name_and_unknown_names_say_the_known_ones():
    from agent_envs.training.commands.presets import get_preset

    with pytest.raises(ValueError, match="smoke, quick, paper"):
        get_preset("paper-sweep")
    assert len({p.name for p in PRESETS.values()}) == len(PRESETS)
    assert all(name == preset.name for name, preset in PRESETS.items())


def test_training_table_counts_validations_above_twice_the_first():
    from agent_envs.training.commands.sweep_report import _env_options, rising_evaluations

    curve = [{"cost_mean": c} for c in (0.5, 0.9, 1.2, 0.3, 1.01)]
    assert rising_evaluations(curve) == 2  # 1.2 and 1.01 exceed 2 x 0.5; 0.9 does not
    assert rising_evaluations([]) == 0
    assert rising_evaluations(curve, factor=3.0) == 0
    trial = Trial(
        trial_id="t",
        kind=LEARNER,
        setting="main",
        policy="ppo",
        seed=0,
        eval_env_kwargs={},
        test_seeds=(1,),
        settings=("main",),
        train={"env_kwargs": {"n_agents": 5, "observation": "summary", "action_basis": "common"}},
    )
    assert _env_options(trial) == "observation=summary, action_basis=common"
