"""The benchmark's tasks: ids, envs, shipped references, the score and its bad input."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import agent_envs  # noqa: F401  (registers the task ids)
from agent_envs.tasks import (
    TASK_LIST,
    TASKS,
    PolicyError,
    get_task,
    load_references,
    parallel_env,
    score,
)
from agent_envs.tasks.bounds import centre_lower_bound, centre_paths_cost_bound
from agent_envs.tasks.catalog import INTERFACE_KWARGS, check_disjoint_seeds
from agent_envs.tasks.references import HASH_FILE, data_dir, recorded_hashes, sha256_hex
from agent_envs.tasks.scores import gap, iqm, normalized_score, summarize

ROOT = Path(__file__).resolve().parents[1]
NOISY = "agent_envs/NoisySwarm-v0"
STIFF = "agent_envs/StiffSwarm-v0"


# ------------------------------------------------------------------------ the catalogue


def test_at_least_five_tasks_each_with_its_references():
    assert len(TASK_LIST) >= 5
    for task in TASK_LIST:
        assert task.id.startswith("agent_envs/") and task.id.endswith(f"-v{task.version}")
        assert len(task.test_seeds) == 20 and task.tests
        refs = load_references(task)  # hash-checked
        assert refs.seeds == task.test_seeds
        assert {"zero", task.yardstick} <= set(refs.costs)


def test_seed_sets_are_disjoint():
    check_disjoint_seeds((0, 1, 2))
    for task in TASK_LIST:
        assert not set(task.test_seeds) & set(task.validation_seeds)
    with pytest.raises(ValueError, match=r"training and|and training"):
        check_disjoint_seeds((TASK_LIST[0].test_seeds[0],))


def test_unknown_task_and_version_errors():
    with pytest.raises(ValueError, match="the tasks are agent_envs/StiffSwarm-v0"):
        get_task("agent_envs/NoSuchSwarm-v0")
    with pytest.raises(ValueError, match="has no version v7; it has v0"):
        get_task("agent_envs/StiffSwarm-v7")
    with pytest.raises(ValueError, match="not a task id"):
        get_task("StiffSwarm")
    with pytest.raises(TypeError):
        get_task(3)
    assert get_task("StiffSwarm-v0") is TASKS[STIFF]  # the namespace may be left out


def test_a_task_fixes_everything_but_the_interface():
    with pytest.raises(ValueError, match=r"fixes n_agents.*observation, action_basis"):
        gym.make(STIFF, n_agents=10)
    with pytest.raises(ValueError, match="fixes sigma"):
        parallel_env(NOISY, sigma=0.1)
    env = gym.make(NOISY, observation="summary", action_basis="common")
    assert env.observation_space.shape == (4,) and env.action_space.shape == (1,)
    assert set(INTERFACE_KWARGS) >= {"observation", "action_basis", "agent_reward"}


@pytest.mark.parametrize("task", TASK_LIST, ids=lambda t: t.file_stem)
def test_task_env_equals_the_free_env_with_its_kwargs(task):
    """gym.make(task) is agent_envs/Swarm-v0 with the task's kwargs, bit for bit."""
    steps = 2 if task.n_agents > 1000 else task.n_steps
    a = gym.make(task.id)
    b = gym.make("agent_envs/Swarm-v0", **dict(task.env_kwargs))
    assert a.spec.max_episode_steps == task.n_steps
    rng = np.random.default_rng(0)
    oa, _ = a.reset(seed=task.test_seeds[0])
    ob, _ = b.reset(seed=task.test_seeds[0])
    assert np.array_equal(oa, ob)
    for _ in range(steps):
        action = rng.uniform(-0.3, 0.3, a.action_space.shape).astype(np.float32)
        ra, rb = a.step(action), b.step(action)
        assert np.array_equal(ra[0], rb[0]) and ra[1] == rb[1] and ra[2:4] == rb[2:4]


def test_vector_entry_point_and_pettingzoo_twin_cost_the_same():
    venv = gym.make_vec(NOISY, num_envs=2, vectorization_mode="vector_entry_point")
    env = gym.make(NOISY)
    par = parallel_env(NOISY)
    seed = get_task(NOISY).test_seeds[3]
    obs_v, _ = venv.reset(seed=[seed, seed + 1])
    obs_g, _ = env.reset(seed=seed)
    par.reset(seed=seed)
    assert np.array_equal(obs_v[0], obs_g)
    total_v = total_g = total_p = 0.0
    for step in range(20):
        action = np.full(10, 0.1 * np.sin(step), np.float32)
        _, rv, *_ = venv.step(np.stack([action, action]))
        _, rg, *_ = env.step(action)
        _, rp, *_ = par.step({a: action[k : k + 1] for k, a in enumerate(par.possible_agents)})
        total_v, total_g, total_p = total_v + rv[0], total_g + rg, total_p + sum(rp.values())
    assert total_v == total_g
    assert total_p == pytest.approx(total_g, rel=1e-12)


# --------------------------------------------------------------------- the score's arithmetic


def test_gap_and_score_by_hand():
    assert gap(1.1, 1.0) == pytest.approx(0.1)
    assert gap(np.array([0.5, 2.0]), np.array([1.0, 1.0])).tolist() == [-0.5, 1.0]
    # 0 at the zero control, 100 at V, 50 half way, above 100 below V, below 0 above J0
    assert normalized_score(5.0, 1.0, 5.0) == 0.0
    assert normalized_score(1.0, 1.0, 5.0) == 100.0
    assert normalized_score(3.0, 1.0, 5.0) == 50.0
    assert normalized_score(0.6, 1.0, 5.0) == pytest.approx(110.0)
    assert normalized_score(7.0, 1.0, 5.0) == pytest.approx(-50.0)


def test_summary_by_hand():
    values = np.array([1.0, 2.0, 3.0, 4.0, 100.0, 5.0, 6.0, 7.0])
    s = summarize(values)
    assert s.mean == pytest.approx(values.mean())
    # t-interval: mean +- t_{0.975, 7} * sd / sqrt(8), t_{0.975, 7} = 2.364624
    half = 2.3646242510102993 * values.std(ddof=1) / np.sqrt(8)
    assert (s.mean_low, s.mean_high) == pytest.approx((values.mean() - half, values.mean() + half))
    # IQM of 8 values: drop 2 at each end -> mean of 3, 4, 5, 6
    assert s.iqm == pytest.approx(4.5) == iqm(values)
    assert s.iqm_low <= s.iqm <= s.iqm_high
    assert summarize(values) == s  # the bootstrap is seeded
    matrix = np.array([[1.0, 2.0, 3.0], [3.0, 4.0, 5.0]])
    m = summarize(matrix)
    assert (m.n_runs, m.n_seeds) == (2, 3) and m.mean == pytest.approx(3.0)
    with pytest.raises(ValueError, match="shape"):
        summarize(np.zeros((2, 2, 2)))


def test_iqm_is_rliables():
    metrics = pytest.importorskip("rliable.metrics")
    x = np.random.default_rng(1).normal(size=(3, 20))
    assert iqm(x) == pytest.approx(float(metrics.aggregate_iqm(x)), rel=1e-14)


@pytest.mark.parametrize("task", TASK_LIST, ids=lambda t: t.file_stem)
def test_yardstick_scores_100_and_zero_scores_0_from_the_shipped_data(task):
    refs = load_references(task)
    v, zero = refs.yardstick, refs.zero
    assert np.allclose(normalized_score(v, v, zero), 100.0, atol=1e-12)
    assert np.allclose(normalized_score(zero, v, zero), 0.0, atol=1e-12)
    # the references' order holds on every seed: V below proportional below the zero control
    assert np.all(v < refs.costs["proportional"]) and np.all(refs.costs["proportional"] < zero)
    if "optimal" in refs.solver:
        assert all(r["converged"] for r in refs.solver["optimal"])
        if task.yardstick == "optimal":
            score_opt = normalized_score(refs.costs["optimal"], v, zero)
            assert np.all(np.abs(score_opt - 100.0) <= 0.05)


@pytest.mark.parametrize(
    "task", [t for t in TASK_LIST if t.n_agents <= 1000], ids=lambda t: t.file_stem
)
def test_live_references_reproduce_the_shipped_costs(task):
    """The zero and proportional controllers run live give the shipped costs (env determinism:
    the references were made on the same env)."""
    from agent_envs.baselines import ProportionalController

    refs = load_references(task)
    seeds = task.test_seeds[:3]
    zero = score(lambda obs: np.zeros(task.n_agents * task.dim, np.float32), task, seeds=seeds)
    assert np.allclose(zero.scores, 0.0, atol=1e-9)
    prop = score(ProportionalController, task, name="proportional", seeds=seeds)
    shipped = [refs.cost("proportional", s) for s in seeds]
    assert np.allclose(prop.costs, shipped, rtol=1e-12, atol=0)


def test_large_swarm_zero_control_scores_zero():
    task = get_task("agent_envs/LargeSwarm-v0")
    result = score(lambda obs: np.zeros(10_000, np.float32), task, seeds=task.test_seeds[:2])
    assert np.allclose(result.scores, 0.0, atol=1e-9)


# ------------------------------------------------------------------------- the shipped data


def _copy_data(tmp_path: Path) -> Path:
    folder = tmp_path / "data"
    shutil.copytree(data_dir(), folder)
    return folder


def test_shipped_files_match_their_recorded_hashes():
    hashes = recorded_hashes()
    for task in TASK_LIST:
        name = f"{task.file_stem}.json"
        assert sha256_hex((data_dir() / name).read_bytes()) == hashes[name]


def test_an_edited_reference_file_is_refused(tmp_path):
    folder = _copy_data(tmp_path)
    path = folder / "NoisySwarm-v0.json"
    data = json.loads(path.read_text())
    data["seeds"][0]["costs"]["mpc"] *= 0.5  # a better-looking yardstick
    path.write_text(json.dumps(data, indent=1) + "\n")
    with pytest.raises(ValueError, match="does not match the hash recorded"):
        load_references(NOISY, folder)


def test_missing_file_or_hash_is_refused(tmp_path):
    folder = _copy_data(tmp_path)
    (folder / "NoisySwarm-v0.json").unlink()
    with pytest.raises(ValueError, match="no reference data for agent_envs/NoisySwarm-v0"):
        load_references(NOISY, folder)
    folder = _copy_data(tmp_path / "b")
    lines = (folder / HASH_FILE).read_text().splitlines()
    (folder / HASH_FILE).write_text("\n".join(x for x in lines if "Noisy" not in x) + "\n")
    with pytest.raises(ValueError, match="no hash recorded"):
        load_references(NOISY, folder)


def test_a_file_for_another_setting_is_refused(tmp_path):
    from agent_envs.tasks.references import parse_references

    raw = (data_dir() / "NoisySwarm-v0.json").read_bytes()
    data = json.loads(raw)
    data["env_kwargs"]["sigma"] = 0.1
    with pytest.raises(ValueError, match="env kwargs differ"):
        parse_references(get_task(NOISY), json.dumps(data).encode(), "x")
    with pytest.raises(ValueError, match="the file is for"):
        parse_references(get_task(STIFF), raw, "x")


# --------------------------------------------------------------------------- the lower bound


def test_lower_bound_by_hand_one_step():
    """m = 1: nothing to optimize; LB = tau (S^0 + |c^0 - xbar|^2 + path variance)."""
    x0 = np.array([[0.0], [1.0]])  # c = 0.5, S = 0.25
    centres = np.array([[[0.5], [0.5]], [[0.6], [0.4]]])
    assert centre_lower_bound(x0, centres, np.array([1.0]), 0.1, 0.01) == pytest.approx(
        0.1 * (0.25 + 0.25)
    )


def test_lower_bound_solves_the_centre_problem():
    """The least-squares minimum equals a direct minimization of the same objective."""
    from scipy.optimize import minimize

    rng = np.random.default_rng(0)
    m, k, dt, gamma, target = 6, 3, 0.1, 0.05, np.array([0.7, -0.2])
    noise = np.cumsum(rng.normal(0, 0.05, size=(m + 1, k, 2)), axis=0)
    noise[0] = 0.0
    centres = 0.1 + noise

    def objective(flat):
        u = flat.reshape(m, 2)
        total = 0.0
        for n in range(m):
            c = centres[n] + dt * u[:n].sum(axis=0)
            total += ((c - target) ** 2).sum(axis=1).mean() + gamma * (u[n] ** 2).sum()
        return dt * total

    best = minimize(objective, np.zeros(2 * m), method="BFGS", options={"gtol": 1e-12}).fun
    bound = centre_paths_cost_bound(centres, 0.0, target, dt, gamma)
    assert bound == pytest.approx(best, rel=1e-8)


def test_lower_bound_is_below_every_policy_on_a_noisy_swarm():
    """Random feedback laws (per-agent, clipped) never cost less than the seed's bound."""
    from agent_envs.baselines import ZeroController

    env = gym.make("agent_envs/Swarm-v0", n_agents=8, n_steps=10, sigma=0.3, n_paths=3)
    inner = env.unwrapped
    rng = np.random.default_rng(5)
    for seed in range(3):
        obs, info = env.reset(seed=seed)
        x0 = np.array(info["positions"][0])
        positions = [np.array(info["positions"])]
        zero = ZeroController(env)
        done = False
        while not done:
            obs, _, te, tr, info = env.step(zero.predict(obs)[0])
            positions.append(np.array(info["positions"]))
            done = te or tr
        bound = centre_lower_bound(
            x0, np.stack(positions), inner.params.target_vector, inner.dt, inner.params.gamma
        )
        for _ in range(5):
            gain, push = rng.uniform(0, 5), rng.uniform(-1, 1, 8)
            obs, _ = env.reset(seed=seed)
            cost, done = 0.0, False
            while not done:
                action = np.clip(gain * (0.7 - obs[:8]) / 10 + 0.1 * push, -1, 1)
                obs, r, te, tr, _ = env.step(action.astype(np.float32))
                cost, done = cost - r, te or tr
            assert bound <= cost


@pytest.mark.parametrize(
    "task",
    [t for t in TASK_LIST if t.env_kwargs["kernel"] == "symmetric"],
    ids=lambda t: t.file_stem,
)
def test_shipped_lower_bound_is_below_every_reference(task):
    refs = load_references(task)
    bound = refs.costs["lower_bound"]
    for name in task.references:
        if name != "lower_bound":
            assert np.all(bound <= refs.costs[name]), name


# ------------------------------------------------------------------- scoring any policy


class _Predictor:
    def __init__(self, env=None) -> None:
        self.env = env

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        return np.zeros(10, np.float32), state


def test_the_three_kinds_of_policy():
    seeds = get_task(NOISY).test_seeds[:2]
    by_callable = score(lambda obs: np.zeros(10), NOISY, seeds=seeds)
    by_predict = score(_Predictor(), NOISY, seeds=seeds)

    def factory(env):
        assert env.action_space.shape == (10,)
        return lambda obs: np.zeros(10)

    by_factory = score(factory, NOISY, seeds=seeds)
    by_class = score(_Predictor, NOISY, seeds=seeds)  # a class is a factory
    for result in (by_callable, by_predict, by_factory, by_class):
        assert result.costs == by_callable.costs
    rows = by_callable.rows()
    assert [r["seed"] for r in rows] == list(seeds)
    assert rows[0]["score"] == pytest.approx(0.0, abs=1e-12)


def test_per_agent_policy_on_the_pettingzoo_twin_matches_the_gym_env():
    seeds = get_task(NOISY).test_seeds[:2]

    def per_agent(rows):  # (N, 2d + d + 1) absolute rows: x_k, drift_k, xbar, t/T
        return np.clip(12 * (rows[:, 2:3] - rows[:, 0:1]) / 25, -1, 1)

    def global_law(obs):
        return np.clip(12 * (obs[20] - obs[:10]) / 25, -1, 1)

    a = score(per_agent, NOISY, per_agent=True, seeds=seeds)
    b = score(global_law, NOISY, seeds=seeds)
    assert np.allclose(a.costs, b.costs, rtol=1e-10)
    team = score(per_agent, NOISY, per_agent=True, seeds=seeds, interface={"agent_reward": "team"})
    assert np.allclose(team.costs, b.costs, rtol=1e-10)


@pytest.mark.parametrize(
    "policy, message",
    [
        (lambda obs: np.zeros(3), r"the action has shape \(3,\)"),
        (lambda obs: np.full(10, np.nan), "NaN or inf"),
        (lambda obs: np.full(10, np.inf), "NaN or inf"),
        (lambda obs: np.zeros(10, dtype=bool), "dtype bool"),
        (lambda obs: np.zeros(10, dtype=complex), "dtype complex"),
        (lambda obs: ["a"] * 10, "dtype <U1"),
        (lambda obs: 1 / 0, "raised ZeroDivisionError"),
        (lambda obs: [[0.0], [0.0, 1.0]], "not an array"),
    ],
)
def test_bad_policies_name_the_policy_seed_and_step(policy, message):
    pattern = f"policy 'mine', seed 25000, step 0: .*{message}"
    with pytest.raises(PolicyError, match=pattern):
        score(policy, NOISY, name="mine", seeds=[25000])


def test_a_policy_failing_later_names_that_step():
    calls = {"n": 0}

    def late(obs):
        calls["n"] += 1
        return np.zeros(10) if calls["n"] < 8 else np.full(10, np.nan)

    with pytest.raises(PolicyError, match="seed 25000, step 7"):
        score(late, NOISY, seeds=[25000])


def test_bad_predict_return_and_objects():
    class NoTuple:
        def predict(self, obs, *args, **kwargs):
            return np.zeros(10)

    with pytest.raises(PolicyError, match=r"predict must return \(action, state\)"):
        score(NoTuple(), NOISY, seeds=[25000])
    with pytest.raises(TypeError, match="a policy must have predict"):
        score(3, NOISY, seeds=[25000])
    with pytest.raises(TypeError, match="factory must return"):
        score(lambda env: 3, NOISY, seeds=[25000])
    with pytest.raises(ValueError, match="test seeds"):
        score(lambda obs: np.zeros(10), NOISY, seeds=[0])


# ---------------------------------------------------------------------- the command line


def _cli(args, cwd, env=None):
    return subprocess.run(
        [sys.executable, "-m", "agent_envs.training.commands.cli", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        env={**os.environ, **(env or {})},
        timeout=300,
    )


_POLICIES = textwrap.dedent(
    """
    import numpy as np

    def act(obs):
        return np.clip(12.0 * (obs[20] - obs[:10]) / 25.0, -1, 1)

    def nan(obs):
        return np.full(10, np.nan)

    def per_agent(rows):
        return np.clip(12.0 * (rows[:, 2:3] - rows[:, 0:1]) / 25.0, -1, 1)

    NOT_CALLABLE = 3
    """
)


@pytest.fixture
def user_dir(tmp_path):
    (tmp_path / "third_party.py").write_text(_POLICIES)
    (tmp_path / "broken.py").write_text("raise RuntimeError('boom')\n")
    return tmp_path


def test_cli_lists_the_tasks(tmp_path):
    done = _cli(["tasks"], tmp_path)
    assert done.returncode == 0, done.stderr
    for task in TASK_LIST:
        assert task.id in done.stdout
    listed = json.loads(_cli(["tasks", "--json"], tmp_path).stdout)
    assert [r["id"] for r in listed] == [t.id for t in TASK_LIST]
    assert all(r["V"] > 0 for r in listed)


def test_cli_scores_and_writes_the_files(user_dir):
    done = _cli(
        [
            "evaluate",
            "--task",
            NOISY,
            "-p",
            "third_party:act",
            "-p",
            "proportional",
            "-p",
            "shared=per-agent:third_party:per_agent",
            "--out",
            "out",
        ],
        user_dir,
    )
    assert done.returncode == 0, done.stderr
    import csv

    with open(user_dir / "out" / "scores.csv") as handle:
        rows = list(csv.DictReader(handle))
    for name in ("act", "proportional", "shared"):
        mine = [r for r in rows if r["policy"] == name and r["kind"] == "policy"]
        assert len(mine) == 20
        for r in mine:
            cost, v, z = float(r["cost"]), float(r["value"]), float(r["zero_cost"])
            assert float(r["score"]) == pytest.approx(100 * (z - cost) / (z - v), rel=1e-12)
            assert float(r["gap"]) == pytest.approx((cost - v) / v, rel=1e-12)
    refs = [r for r in rows if r["kind"] == "reference"]
    assert {r["policy"] for r in refs} == set(get_task(NOISY).references)
    meta = json.loads((user_dir / "out" / "meta.json").read_text())
    assert meta["references_sha256"] == recorded_hashes()["NoisySwarm-v0.json"]
    assert "| act | policy |" in (user_dir / "out" / "scores.md").read_text()


def test_cli_a_failing_policy_is_one_line_and_the_others_are_written(user_dir):
    done = _cli(
        ["evaluate", "--task", NOISY, "-p", "third_party:nan", "-p", "zero", "--out", "out"],
        user_dir,
    )
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "policy 'nan', seed 25000, step 0" in lines[0], done.stderr
    scores = (user_dir / "out" / "scores.csv").read_text()
    assert ",zero,policy," in scores and ",nan,policy," not in scores


@pytest.mark.parametrize(
    "args, message",
    [
        (["-p", "third_party:NOT_CALLABLE"], "neither callable"),
        (["-p", "third_party:missing"], "has no attribute 'missing'"),
        (["-p", "no_such_module:act"], "does not import"),
        (["-p", "broken:act"], "does not import (RuntimeError: boom)"),
        (["--env-kwargs", '{"n_agents": 3}'], "fixes n_agents"),
        (["--seeds", "0-3"], "are not test seeds"),
        (["--env-id", "CartPole-v1"], "leave out --env-id"),
        (["--target", "0.3"], "fixes the target"),
    ],
)
def test_cli_bad_input_is_one_line_exit_2(user_dir, args, message):
    done = _cli(["evaluate", "--task", NOISY, *args, "--out", "out"], user_dir)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert message in lines[0]


@pytest.mark.parametrize(
    "task, message",
    [("agent_envs/Nope-v0", "the tasks are"), ("agent_envs/StiffSwarm-v9", "has no version v9")],
)
def test_cli_unknown_task(user_dir, task, message):
    done = _cli(["evaluate", "--task", task, "--out", "out"], user_dir)
    assert done.returncode == 2 and message in done.stderr
    done = _cli(["tasks", "--verify", task], user_dir)
    assert done.returncode == 2 and message in done.stderr


def test_per_agent_spec_needs_a_task(user_dir):
    done = _cli(["evaluate", "-p", "per-agent:third_party:per_agent", "--out", "o"], user_dir)
    assert done.returncode == 2 and "give --task" in done.stderr


def test_scoring_needs_neither_torch_nor_pandas(user_dir):
    """The core-only path: with torch, pandas and SB3 made unimportable, scoring still works."""
    code = textwrap.dedent(
        """
        import sys

        class Blocked:  # as if the train extra were not installed
            def find_spec(self, name, path=None, target=None):
                if name.split(".")[0] in ("torch", "pandas", "stable_baselines3"):
                    raise ModuleNotFoundError(f"No module named {name!r}", name=name)

        sys.meta_path.insert(0, Blocked())
        from agent_envs.training.commands.cli import main
        code = main(["evaluate", "--task", "agent_envs/NoisySwarm-v0", "-p", "third_party:act",
                     "-p", "proportional", "--out", "core"])
        assert code == 0, code
        assert main(["tasks"]) == 0
        assert not {"torch", "pandas"} & set(sys.modules)
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=user_dir, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    assert (user_dir / "core" / "scores.csv").is_file()


# ------------------------------------------------------------------------- re-solving (slow)


@pytest.mark.slow
def test_resolving_matches_the_shipped_references():
    """The optimum, MPC and the bound re-solved on two noisy-task seeds and one stiff-task seed
    match the shipped numbers to 1e-5 relative (`agent-envs tasks --verify`)."""
    pytest.importorskip("torch")
    from agent_envs.training.commands.task_references import verify

    rows = verify(NOISY, 2) + verify(STIFF, 1)
    assert {r["reference"] for r in rows} >= {"optimal", "mpc"}
    bad = [r for r in rows if not r["ok"]]
    assert not bad, bad


@pytest.mark.slow
def test_cli_report_runs_the_same_episodes(user_dir):
    """--report (train extra): the usual evaluation on the task env; its costs are the scores'."""
    pytest.importorskip("pandas")
    import csv

    done = _cli(
        [
            "evaluate",
            "--task",
            NOISY,
            "-p",
            "third_party:act",
            "-p",
            "zero",
            "--report",
            "--no-progress",
            "--out",
            "out",
        ],
        user_dir,
    )
    assert done.returncode == 0, done.stderr
    assert (user_dir / "out" / "report" / "report.html").is_file()
    with open(user_dir / "out" / "scores.csv") as handle:
        scored = {
            (r["policy"], int(r["seed"])): float(r["cost"])
            for r in csv.DictReader(handle)
            if r["kind"] == "policy"
        }
    with open(user_dir / "out" / "evaluation" / "episodes.csv") as handle:
        evaluated = {
            (r["policy"], int(r["seed"])): float(r["total_cost"]) for r in csv.DictReader(handle)
        }
    assert evaluated.keys() == scored.keys()
    for key, cost in scored.items():
        assert evaluated[key] == pytest.approx(cost, rel=1e-12), key
