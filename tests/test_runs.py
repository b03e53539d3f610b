"""Run directories and the trust boundary (issue 11, items 1-3 and 6a).

Fast: atomic files, exclusive run directories and their lock, the manifest's hash checks, which
statistics an evaluation may unpickle (named, verified by a run manifest, an rl-zoo3 run) and the
core-only subcommand without the `train` extra. Slow: two `agent-envs train` processes started
at once into one run directory, `--resume` past a truncated checkpoint zip / statistics file
(and nothing rewritten when no checkpoint is valid), and an rl-zoo3 model evaluated with its
statistics.
"""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from agent_envs.training.defaults import GYM_ENV_ID
from agent_envs.training.storage import (
    RunDirectoryBusy,
    RunLock,
    RunManifest,
    atomic_path,
    check_output_dir,
    create_run_directory,
    remove_stale_temporaries,
    save_recorded,
    write_text_atomic,
)

SMALL = {"n_agents": 4, "n_steps": 4}
REPO = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------------------ storage


def test_atomic_write_keeps_the_old_file_on_failure(tmp_path):
    path = tmp_path / "summary.json"
    write_text_atomic(path, "old")
    with pytest.raises(RuntimeError), atomic_path(path) as tmp:
        tmp.write_text("half")
        raise RuntimeError("crash while writing")
    assert path.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["summary.json"]  # no temp left
    write_text_atomic(path, "new")
    assert path.read_text() == "new"


def test_temporaries_of_a_killed_writer_are_removed(tmp_path):
    code = (
        "import os, sys\n"
        "from agent_envs.training.storage import atomic_path\n"
        "with atomic_path(sys.argv[1]) as tmp:\n"
        "    tmp.write_bytes(b'x' * 1000)\n"
        "    os.kill(os.getpid(), 9)\n"
    )
    target = tmp_path / "rl_model_replay_buffer_100_steps.pkl"
    done = subprocess.run([sys.executable, "-c", code, str(target)], timeout=120)
    assert done.returncode == -9 and not target.exists()
    (left,) = tmp_path.iterdir()  # the killed process could not clean up
    assert left.name.startswith(".rl_model_replay_buffer_100_steps.pkl.tmp-")
    (tmp_path / "keep.pkl").write_bytes(b"")
    assert remove_stale_temporaries(tmp_path) == [left]
    assert [p.name for p in tmp_path.iterdir()] == ["keep.pkl"]


def test_run_directory_is_created_exclusively_and_locked(tmp_path):
    run = create_run_directory(tmp_path / "runs" / "a")
    with pytest.raises(RunDirectoryBusy, match="exists already"):
        create_run_directory(tmp_path / "runs" / "a")
    with RunLock(run):
        with pytest.raises(RunDirectoryBusy, match="in use"):
            RunLock(run).acquire()
    RunLock(run).acquire().release()  # released with the first holder


def test_check_output_dir(tmp_path):
    (tmp_path / "f").write_text("x")
    assert check_output_dir(tmp_path / "new" / "deeper") == tmp_path / "new" / "deeper"
    assert not (tmp_path / "new").exists()  # checks, creates nothing
    with pytest.raises(ValueError, match=r"--out .* not a folder"):
        check_output_dir(tmp_path / "f")
    with pytest.raises(ValueError, match="is a file"):
        check_output_dir(tmp_path / "f" / "sub", "--out")


def _unprivileged_exit_code(check) -> int:
    """Run `check()` in a forked child as an ordinary user (as is, when not root); the exit code
    is check's (0, or 1 for an exception). Forking keeps the imported code: a root-only
    interpreter path (pyenv under /root) could not be exec'd by the unprivileged user."""
    pid = os.fork()
    if pid == 0:  # pragma: no cover - in the child
        code = 1
        try:
            if os.geteuid() == 0:
                os.setgroups([])
                os.setgid(65534)  # nobody / nogroup
                os.setuid(65534)
            code = check()
        finally:
            os._exit(code)
    _, status = os.waitpid(pid, 0)
    return os.waitstatus_to_exitcode(status)


def test_check_output_dir_refuses_a_folder_without_write_permission():
    """CI runs as root, who may write anywhere: the check then runs in a child that dropped to
    the user nobody, on a folder nobody owns with mode 0o500 (read and search, no write)."""
    import tempfile

    base = Path(tempfile.mkdtemp(prefix="agent-envs-perm-"))
    try:
        base.chmod(0o755)
        locked = base / "locked"
        locked.mkdir(mode=0o500)
        locked.chmod(0o500)  # read and search, no write, for its owner
        if os.geteuid() == 0:
            os.chown(locked, 65534, 65534)  # owned by the user the check runs as

        def refused() -> int:
            try:
                check_output_dir(locked / "out")
            except ValueError as error:
                return 0 if "no permission" in str(error) else 2
            return 3

        assert _unprivileged_exit_code(refused) == 0
        # the same user is not refused where it may write (a folder it owns, mode 0o700)
        free = base / "free"
        free.mkdir(mode=0o700)
        if os.geteuid() == 0:
            os.chown(free, 65534, 65534)

        def allowed() -> int:
            return 0 if check_output_dir(free / "out") == free / "out" else 4

        assert _unprivileged_exit_code(allowed) == 0
    finally:
        shutil.rmtree(base, ignore_errors=True)


def test_manifest_detects_truncation_and_tampering(tmp_path):
    path = save_recorded(tmp_path, tmp_path / "stats.pkl", lambda tmp: tmp.write_bytes(b"x" * 64))
    manifest = RunManifest(tmp_path)
    assert manifest.problem(path) is None
    path.write_bytes(b"x" * 63 + b"y")
    assert "SHA-256" in manifest.problem(path)
    path.write_bytes(b"x" * 10)
    assert "10 bytes" in manifest.problem(path)
    assert "not recorded" in manifest.problem(tmp_path / "other.pkl")


# ------------------------------------------------------------------------ trust boundary


def _model_with_statistics():
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    venv = VecNormalize(DummyVecEnv([lambda: gym.make(GYM_ENV_ID, **SMALL)]))
    model = PPO("MlpPolicy", venv, n_steps=8, batch_size=8, n_epochs=1, seed=0, device="cpu")
    model.learn(16)
    return model


def test_statistics_of_a_run_are_used_only_while_they_match_the_manifest(tmp_path):
    from agent_envs.training.learners.checkpoints import save_model_with_statistics
    from agent_envs.training.learners.policies import ModelSpec, find_statistics

    model = _model_with_statistics()
    run = tmp_path / "run"
    run.mkdir()
    path = save_model_with_statistics(model, run, "best_model.zip")
    stats = run / "best_model_vecnormalize.pkl"
    found = find_statistics(ModelSpec.parse(path))
    assert (found.path, found.source) == (stats, "manifest")
    data = stats.read_bytes()
    stats.write_bytes(data[:-1] + bytes([data[-1] ^ 1]))  # one bit changed after saving
    with pytest.raises(ValueError, match=r"SHA-256 .* differs"):
        find_statistics(ModelSpec.parse(path))
    # the user may still name the file: then it is their call
    named = find_statistics(ModelSpec.parse(f"{path}:{stats}"))
    assert named.source == "named"
    (run / "manifest.json").unlink()
    with pytest.raises(ValueError, match=r"no manifest\.json"):
        find_statistics(ModelSpec.parse(path))


def test_rl_zoo3_layout_statistics_are_found(tmp_path):
    from agent_envs.training.learners.policies import ModelSpec, find_statistics

    model = _model_with_statistics()
    run = tmp_path / "ppo" / "agent_envs-Swarm-v0_1"
    (run / "agent_envs-Swarm-v0").mkdir(parents=True)
    model.save(run / "agent_envs-Swarm-v0.zip")
    model.save(run / "rl_model_16_steps.zip")
    model.get_vec_normalize_env().save(str(run / "agent_envs-Swarm-v0" / "vecnormalize.pkl"))
    model.get_vec_normalize_env().save(str(run / "rl_model_vecnormalize_16_steps.pkl"))
    # not yet an rl-zoo3 run: no args.yml / config.yml; the pickle is not vouched for
    assert find_statistics(ModelSpec.parse(run / "agent_envs-Swarm-v0.zip")) is None
    for name in ("args.yml", "config.yml"):
        (run / "agent_envs-Swarm-v0" / name).write_text("{}\n")
    found = find_statistics(ModelSpec.parse(run / "agent_envs-Swarm-v0.zip"))
    assert (found.path, found.source) == (
        run / "agent_envs-Swarm-v0" / "vecnormalize.pkl",
        "rl-zoo3",
    )
    checkpoint = find_statistics(ModelSpec.parse(run / "rl_model_16_steps.zip"))
    assert checkpoint.path == run / "rl_model_vecnormalize_16_steps.pkl"


# ------------------------------------------------------------------------ minimal install

_WITHOUT_TRAIN_EXTRA = """
import sys
for name in ("torch", "stable_baselines3", "pandas", "tqdm", "supersuit", "tensorboard", "rich"):
    sys.modules[name] = None  # `import name` now fails as if the extra were not installed
from agent_envs.training.commands.cli import main
sys.exit(main(sys.argv[1:]))
"""


def _run_without_train_extra(*argv: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", _WITHOUT_TRAIN_EXTRA, *argv],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )


def test_core_subcommands_without_the_train_extra(tmp_path):
    done = _run_without_train_extra(
        "reproduce", "uncontrolled", "--n-agents", "3", "--n-paths", "1", "--out", "u", cwd=tmp_path
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert (tmp_path / "u" / "results.md").is_file()
    for argv in (["evaluate", "--out", "e"], ["reproduce", "turnpike", "--out", "t"]):
        done = _run_without_train_extra(*argv, cwd=tmp_path)
        lines = done.stderr.strip().splitlines()
        assert done.returncode == 1 and len(lines) == 1, done.stderr
        assert 'pip install "agent-envs[train]"' in lines[0]


# ------------------------------------------------------------------------------- slow runs

_TINY_TRAIN = [
    "--env-kwargs",
    json.dumps(SMALL),
    "--n-envs",
    "1",
    "--hyperparams",
    '{"n_steps": 16, "batch_size": 16, "n_epochs": 1}',
    "--eval-freq",
    "0",
    "--no-progress-bar",
    "--no-tensorboard",
]


@pytest.mark.slow
def test_two_trains_started_at_once_never_share_a_run_directory(tmp_path):
    argv = ["train", "--out", str(tmp_path), "--run-name", "same", "--timesteps", "32"]
    argv += ["--checkpoint-freq", "16", *_TINY_TRAIN]
    command = [sys.executable, "-m", "agent_envs.training.commands.cli", *argv]
    procs = [
        subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for _ in range(2)
    ]
    results = [(p.wait(timeout=300), *p.communicate()) for p in procs]
    codes = sorted(code for code, _, _ in results)
    assert codes == [0, 2], results
    (loser,) = [err for code, _, err in results if code == 2]
    assert len(loser.strip().splitlines()) == 1 and "exists already" in loser
    run = tmp_path / "same"
    manifest = RunManifest(run)
    files = manifest.files()
    assert "final_model.zip" in files and "checkpoints/rl_model_32_steps.zip" in files
    assert all(manifest.problem(run / rel) is None for rel in files)


def _snapshot(folder: Path) -> dict[str, tuple[int, bytes]]:
    return {
        str(p.relative_to(folder)): (p.stat().st_mtime_ns, p.read_bytes())
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


@pytest.mark.slow
def test_resume_skips_truncated_checkpoints_and_rewrites_nothing_before(tmp_path, capsys):
    from agent_envs.training.commands.cli import main

    argv = ["train", "--out", str(tmp_path), "--run-name", "r", "--checkpoint-freq", "16"]
    assert main([*argv, "--timesteps", "64", *_TINY_TRAIN]) == 0
    run = tmp_path / "r"
    ck = run / "checkpoints"
    assert (ck / "rl_model_64_steps.zip").is_file() and (ck / "rl_model_48_steps.zip").is_file()

    # no valid checkpoint at all: an error, and not one byte of the run changes
    broken = tmp_path / "broken"
    shutil.copytree(run, broken)
    for path in (broken / "checkpoints").glob("rl_model_*_steps.zip"):
        _truncate(path)
    before = _snapshot(broken)
    capsys.readouterr()
    assert main(["train", "--resume", str(broken), "--timesteps", "96"]) == 2
    err = capsys.readouterr().err
    assert "no valid checkpoint" in err and len(err.strip().splitlines()) == 1
    assert _snapshot(broken) == before

    # a truncated newest model zip: resumes from the one before, saying so
    _truncate(ck / "rl_model_64_steps.zip")
    assert main(["train", "--resume", str(run), "--timesteps", "96"]) == 0
    out, err = capsys.readouterr()
    assert "skipping the damaged checkpoint at 64 timesteps" in err
    assert "rl_model_48_steps.zip" in err and "resuming r from rl_model_48_steps.zip" in out
    summary = json.loads((run / "summary.json").read_text())
    assert summary["timesteps"] == 96

    # a truncated newest statistics file: the same
    _truncate(ck / "rl_model_vecnormalize_96_steps.pkl")
    assert main(["train", "--resume", str(run), "--timesteps", "112"]) == 0
    out, err = capsys.readouterr()
    assert "checkpoint at 96 timesteps" in err and "rl_model_vecnormalize_96_steps.pkl" in err
    assert "resuming r from rl_model_80_steps.zip" in out
    assert json.loads((run / "config.json").read_text())["timesteps"] == 112


@pytest.mark.slow
def test_evaluate_uses_the_statistics_of_an_rl_zoo3_run(tmp_path, capsys):
    """Issue 11, 6a: the rl-zoo3 run's vecnormalize.pkl is found, reported and applied."""
    # not importorskip: importing rl_zoo3 patches gymnasium's TimeLimit for the whole process
    # (rl_zoo3.gym_patches adds "TimeLimit.truncated" to every info), which changed the infos
    # of every later test; the run itself happens in a subprocess
    if importlib.util.find_spec("rl_zoo3") is None:
        pytest.skip("rl_zoo3 is the optional 'zoo' extra")
    import pandas as pd
    from stable_baselines3 import PPO

    from agent_envs.training.commands.cli import main
    from agent_envs.training.commands.evaluate import evaluate_policies
    from agent_envs.training.config import hyperparams_file

    command = [sys.executable, "-m", "rl_zoo3.train", "--algo", "ppo", "--env", GYM_ENV_ID]
    command += ["--gym-packages", "agent_envs", "--conf-file", str(hyperparams_file("ppo"))]
    command += ["--env-kwargs", "n_agents:5", "n_steps:10", "-n", "256", "-f", str(tmp_path)]
    command += ["--seed", "0", "--num-threads", "1", "--eval-freq", "-1", "--verbose", "0"]
    command += ["--hyperparams", "n_steps:32", "batch_size:64"]
    done = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    (run,) = (tmp_path / "ppo").iterdir()
    model = run / "agent_envs-Swarm-v0.zip"
    stats = run / "agent_envs-Swarm-v0" / "vecnormalize.pkl"
    env_kwargs = '{"n_agents": 5, "n_steps": 10}'
    argv = ["evaluate", "-p", f"zoo={model}", "--env-kwargs", env_kwargs, "--seeds", "0-5"]
    assert main([*argv, "--out", str(tmp_path / "ev"), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert f"zoo: VecNormalize statistics {stats} (the rl-zoo3 run's statistics)" in out
    meta = json.loads((tmp_path / "ev" / "meta.json").read_text())
    assert meta["policies"]["zoo"]["vecnormalize"] == str(stats)
    res = evaluate_policies(
        {"named": f"{model}:{stats}", "raw": PPO.load(model, device="cpu")},
        env_kwargs={"n_agents": 5, "n_steps": 10},
        seeds=range(6),
        progress=False,
    )
    ep = res.episodes.set_index(["policy", "seed"])["total_cost"]
    cli_costs = pd.read_csv(tmp_path / "ev" / "episodes.csv")["total_cost"].to_numpy()
    # the CLI's costs are those of the model with its statistics, not of the raw model
    np.testing.assert_allclose(cli_costs, ep["named"].to_numpy())
    assert not np.allclose(ep["named"].to_numpy(), ep["raw"].to_numpy())
