"""Policy evaluation (library + CLI), SB3 model loading, reports, and the Section 5.2 runs."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest

import agent_envs  # noqa: F401
from agent_envs.baselines import TurnpikeController, ZeroController
from agent_envs.training.commands.cli import main as cli_main
from agent_envs.training.commands.evaluate import evaluate_policies
from agent_envs.training.commands.evaluate_options import parse_policy_specs
from agent_envs.training.defaults import parse_env_kwargs, parse_seeds
from agent_envs.training.learners.policies import (
    ModelSpec,
    PerAgentPolicy,
    detect_algo,
    find_statistics,
    own_run_candidates,
)
from agent_envs.training.results.report import ReportSection, build_report
from agent_envs.training.results.rollout import rollout
from agent_envs.training.results.tables import (
    EvaluationResults,
    mean_confidence_interval,
    summarize,
)

ENV_ID = "agent_envs/Swarm-v0"
SMALL = {"n_agents": 5, "n_steps": 6, "n_paths": 2}


@pytest.fixture(scope="module")
def small_results(tmp_path_factory):
    out = tmp_path_factory.mktemp("eval")
    res = evaluate_policies(
        {
            "turnpike": "turnpike",
            "proportional": "proportional",
            "zero": "zero",
            "factory": lambda env: TurnpikeController(env, beta=4.0),
        },
        ENV_ID,
        SMALL,
        seeds=[3, 4, 5],
        progress=False,
        out_dir=out,
    )
    return res, out


def test_evaluate_policies_table_and_identities(small_results):
    res, _ = small_results
    ep = res.episodes
    assert list(ep["policy"].unique()) == ["turnpike", "proportional", "zero", "factory"]
    for _, group in ep.groupby("policy"):
        assert list(group["seed"]) == [3, 4, 5]  # same seeds for every policy
    assert not ep["diverged"].any() and np.all(np.isfinite(ep["total_cost"]))
    assert (ep.loc[ep.policy == "zero", "control_energy"] == 0).all()
    dt = res.meta["env"]["dt"]
    for name, tr in res.trajectories.items():
        assert tr["mean_positions"].shape == (3, 7, 5, 1)
        assert tr["controls"].shape == (3, 6, 5, 1)
        assert tr["turnpike_distance"].shape == (3, 7)
        # total cost = -sum(rewards) = tau sum_n c(x^n, u^n) (the env's reward identity)
        costs = ep.loc[ep.policy == name, "total_cost"].to_numpy()
        np.testing.assert_allclose(costs, dt * np.nansum(tr["running_cost"], axis=1), rtol=1e-9)
    # turnpike (beta = 12) and factory (beta = 4) differ in cost and control on every seed;
    # tbar only for switching policies
    for column in ("total_cost", "control_energy"):
        turnpike = ep.loc[ep.policy == "turnpike", column].to_numpy()
        factory = ep.loc[ep.policy == "factory", column].to_numpy()
        assert np.all(np.abs(turnpike - factory) > 1e-6 * np.abs(turnpike)), column
    assert np.all(ep.loc[ep.policy == "zero", "turnpike_time"].isna())
    assert np.all(ep.loc[ep.policy == "turnpike", "turnpike_time"] > 0)


def test_evaluate_is_deterministic_and_round_trips(small_results):
    res, out = small_results
    again = evaluate_policies(["turnpike"], ENV_ID, SMALL, seeds=[3, 4, 5], progress=False)
    np.testing.assert_array_equal(
        again.episodes["total_cost"],
        res.episodes.loc[res.episodes.policy == "turnpike", "total_cost"],
    )
    loaded = EvaluationResults.load(out)
    pd.testing.assert_frame_equal(loaded.episodes, res.episodes, check_dtype=False)
    np.testing.assert_array_equal(
        loaded.trajectories["zero"]["mean_positions"], res.trajectories["zero"]["mean_positions"]
    )
    records = json.loads((out / "episodes.json").read_text())
    assert len(records) == 12 and {"total_cost", "final_distance", "diverged"} <= set(records[0])


def test_rollout_reports_divergence_without_nan():
    env = gym.make(
        ENV_ID, n_agents=5, n_steps=6, integrator="em", epsilon=1e-4, divergence_threshold=5.0
    )
    ep = rollout(ZeroController(env), env, seed=0)
    assert ep.diverged  # EM with eps = 1e-4, tau = 1/6 leaves |x| <= 5 at once
    assert np.isfinite(ep.total_cost) and np.isnan(ep.final_distance)
    assert ep.n_steps_run == ep.divergence_step
    assert np.all(np.isnan(ep.mean_positions[ep.n_steps_run :]))


def test_per_agent_policy_matches_gym_controller():
    env = gym.make(ENV_ID, **SMALL, target=0.9)
    gym_ep = rollout(TurnpikeController(env), env, seed=7)
    per_agent = PerAgentPolicy(TurnpikeController(env), n_agents=5, dim=1)
    pa_ep = rollout(per_agent, env, seed=7)
    assert pa_ep.total_cost == pytest.approx(gym_ep.total_cost, rel=1e-6)


# ------------------------------------------------------------------------------------------
# Saved SB3 models
# ------------------------------------------------------------------------------------------


class _PerAgentSpaces(gym.Env):
    """Only the spaces of one PettingZoo agent (d = 1), to build a per-agent SB3 model."""

    observation_space = gym.spaces.Box(-1e4, 1e4, (4,), np.float32)
    action_space = gym.spaces.Box(-1, 1, (1,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return np.zeros(4, np.float32), {}

    def step(self, action):
        return np.zeros(4, np.float32), 0.0, False, True, {}


def test_saved_sb3_model_with_vecnormalize_evaluates(tmp_path):
    from stable_baselines3 import A2C, PPO, SAC
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    venv = VecNormalize(DummyVecEnv([lambda: gym.make(ENV_ID, **SMALL)]))
    model = PPO("MlpPolicy", venv, n_steps=12, batch_size=12, n_epochs=1, seed=0, device="cpu")
    model.learn(12)
    model.save(tmp_path / "best_model")
    venv.save(str(tmp_path / "vecnormalize.pkl"))
    stats = tmp_path / "vecnormalize.pkl"
    # statistics next to a model that no run manifest vouches for are refused, not unpickled
    with pytest.raises(ValueError, match="refusing to load the statistics"):
        find_statistics(ModelSpec.parse(tmp_path / "best_model.zip"))
    named = find_statistics(ModelSpec.parse(f"{tmp_path / 'best_model.zip'}:{stats}"))
    assert (named.path, named.source) == (stats, "named")
    assert detect_algo(tmp_path / "best_model.zip") == "ppo"
    # training's names: best_model.zip + best_model_vecnormalize.pkl; checkpoints as
    # CheckpointCallback names them
    assert own_run_candidates(tmp_path / "best_model.zip")[0].name == "best_model_vecnormalize.pkl"
    assert own_run_candidates(tmp_path / "checkpoints" / "rl_model_64_steps.zip")[1].name == (
        "rl_model_vecnormalize_64_steps.pkl"
    )
    SAC("MlpPolicy", gym.make(ENV_ID, **SMALL), device="cpu").save(tmp_path / "sac")
    A2C("MlpPolicy", gym.make(ENV_ID, **SMALL), device="cpu").save(tmp_path / "a2c")
    assert detect_algo(tmp_path / "sac.zip") == "sac"
    assert detect_algo(tmp_path / "a2c.zip") == "a2c"
    (tmp_path / "shared").mkdir()
    PPO("MlpPolicy", _PerAgentSpaces(), n_steps=8, batch_size=8, device="cpu").save(
        tmp_path / "shared" / "ma_ppo"
    )
    res = evaluate_policies(
        {
            "ppo": f"{tmp_path / 'best_model.zip'}:{stats}",
            "ppo2": f"ppo:{tmp_path / 'best_model'}:{stats}",
            "ma": str(tmp_path / "shared" / "ma_ppo.zip"),
            "turnpike": "turnpike",
        },
        ENV_ID,
        SMALL,
        seeds=[0, 1],
        progress=False,
    )
    assert res.meta["policies"]["ppo"]["vecnormalize"] == str(stats)
    assert res.meta["policies"]["ppo"]["vecnormalize_source"] == "named"
    assert res.meta["policies"]["ma"].get("per_agent") is True
    assert np.all(np.isfinite(res.episodes["total_cost"]))
    ppo = res.episodes[res.episodes.policy == "ppo"]["total_cost"].to_numpy()
    np.testing.assert_array_equal(ppo, res.episodes[res.episodes.policy == "ppo2"]["total_cost"])
    stats.unlink()
    with pytest.raises(ValueError, match="expects observations"):
        evaluate_policies(
            {"bad": str(tmp_path / "sac.zip")},
            ENV_ID,
            {**SMALL, "n_agents": 4},
            seeds=[0],
            progress=False,
        )


# ------------------------------------------------------------------------------------------
# Reports
# ------------------------------------------------------------------------------------------


def test_confidence_interval_and_summary_by_hand():
    mean, lo, hi = mean_confidence_interval([1.0, 2.0, 3.0])
    half = 4.302652729911275 / np.sqrt(3)  # t_{0.975, 2} * s / sqrt(n), s = 1
    assert (mean, lo, hi) == pytest.approx((2.0, 2.0 - half, 2.0 + half))
    episodes = pd.DataFrame(
        {
            "policy": ["turnpike"] * 3 + ["other"] * 3,
            "seed": [0, 1, 2] * 2,
            "total_cost": [1.0, 2.0, 3.0, 2.0, 4.0, 6.0],
            "final_distance": [0.1] * 6,
            "diverged": [False] * 5 + [True],
            "control_energy": [1.0] * 6,
        }
    )
    s = summarize(episodes).set_index("policy")
    assert s.loc["other", "divergence_rate"] == pytest.approx(1 / 3)
    assert np.isnan(s.loc["other", "ratio_to_reference"])  # a diverged episode: no ratio
    s = summarize(episodes.assign(diverged=False)).set_index("policy")
    assert s.loc["other", "ratio_to_reference"] == pytest.approx(2.0)
    assert s.loc["other", "paired_ratio"] == pytest.approx(2.0)
    assert s.loc["other", "paired_ratio_ci_low"] == pytest.approx(2.0)
    assert s.loc["turnpike", "cost_ci_low"] == pytest.approx(2.0 - half)


def _synthetic_results(seed: int = 0) -> EvaluationResults:
    rng = np.random.default_rng(seed)
    s, m, n = 4, 10, 6
    rows, traj = [], {}
    for k, policy in enumerate(["turnpike", "zero", "learned"]):
        costs = rng.uniform(1, 2, s) * (k + 1)
        for i in range(s):
            rows.append(
                {
                    "policy": policy,
                    "seed": i,
                    "total_cost": costs[i],
                    "final_distance": 0.1,
                    "final_sq_distance": 0.06,
                    "diverged": False,
                    "divergence_step": None,
                    "control_energy": 1.0,
                    "saturated_fraction": 0.0,
                    "turnpike_time": 0.5 if policy == "turnpike" else np.nan,
                    "n_steps_run": m,
                    "wall_time_s": 0.1,
                }
            )
        traj[policy] = {
            "seeds": np.arange(s),
            "times": np.linspace(0, 1, m + 1),
            "mean_positions": rng.normal(size=(s, m + 1, n, 1)),
            "controls": rng.normal(size=(s, m, n, 1)),
            "running_cost": rng.uniform(1e-3, 1, (s, m)),
            "turnpike_distance": rng.uniform(1e-3, 10, (s, m + 1)),
            "target": np.full((s, 1), 0.7),
            "turnpike_time": np.full(s, 0.5 if policy == "turnpike" else np.nan),
        }
    meta = {
        "env_id": ENV_ID,
        "env_kwargs": {"n_agents": n},
        "seeds": list(range(s)),
        "env": {"integrator": "serb", "n_steps": m, "n_paths": 1},
    }
    return EvaluationResults(pd.DataFrame(rows), traj, meta)


def test_build_report_from_synthetic_results(tmp_path):
    from matplotlib.figure import Figure

    curve = tmp_path / "curves.png"
    fig = Figure()
    fig.subplots().plot([0, 1], [1, 0])
    fig.savefig(curve)
    res = _synthetic_results()
    res.save(tmp_path / "res")
    paths = build_report(
        [tmp_path / "res"],
        tmp_path / "report",
        command="agent-envs evaluate ...",
        extra_sections=[
            ReportSection(
                "Learning curves",
                text="PPO vs SAC.",
                images=[curve],
                table=pd.DataFrame({"a": [1]}),
            )
        ],
    )
    md = paths["markdown"].read_text()
    assert "ratio to turnpike" in md and "| learned |" in md and "## Learning curves" in md
    for name in ("trajectories.png", "running_cost.png", "turnpike_distance.png", "curves.png"):
        assert (tmp_path / "report" / name).stat().st_size > 1000
        assert f"]({name})" in md
    html_text = paths["html"].read_text()
    assert html_text.count("data:image/png;base64,") == 4 and "<table>" in html_text
    summary = pd.read_csv(paths["summary"])
    assert set(summary["policy"]) == {"turnpike", "zero", "learned"}


def test_report_leaves_the_matplotlib_backend_alone(tmp_path):
    """Reports draw on `Figure` objects: a notebook user's backend stays what it was."""
    import matplotlib

    before = matplotlib.get_backend()
    matplotlib.use("pdf")  # any backend other than the Agg a global switch would set
    try:
        paths = build_report(_synthetic_results(), tmp_path / "rep")
        assert paths["trajectories"].stat().st_size > 1000
        assert matplotlib.get_backend() == "pdf"
    finally:
        matplotlib.use(before)


def test_report_merges_results_with_clashing_names(tmp_path):
    a, b = _synthetic_results(0), _synthetic_results(1)
    a.save(tmp_path / "a")
    b.save(tmp_path / "b")
    paths = build_report([tmp_path / "a", tmp_path / "b"], tmp_path / "rep")
    summary = pd.read_csv(paths["summary"])
    assert "zero@b" in set(summary["policy"]) and len(summary) == 6


# ------------------------------------------------------------------------------------------
# CLI and parsing
# ------------------------------------------------------------------------------------------


def test_parsers():
    assert parse_seeds(["0-2", "7", "10:12"]) == [0, 1, 2, 7, 10, 11]
    assert parse_env_kwargs('{"n_agents": 5, "integrator": "em"}') == {
        "n_agents": 5,
        "integrator": "em",
    }
    assert parse_env_kwargs(None) == {}
    # one syntax for every subcommand: a JSON object (the key=value form is gone)
    with pytest.raises(ValueError, match="--env-kwargs must be a JSON object"):
        parse_env_kwargs("n_agents=5")
    with pytest.raises(ValueError, match="JSON object"):
        parse_env_kwargs("[1, 2]")
    assert parse_policy_specs(["turnpike", "ppo=runs/x/best.zip", "sac:m/final.zip"]) == {
        "turnpike": "turnpike",
        "ppo": "runs/x/best.zip",
        "final": "sac:m/final.zip",
    }


@pytest.mark.filterwarnings("ignore:.*clipped:RuntimeWarning")  # N = 6: stiff exact-J run
def test_cli_evaluate_report_and_reproduce(tmp_path, capsys):
    out = tmp_path / "ev"
    argv = [
        "evaluate",
        "-p",
        "turnpike",
        "-p",
        "zero",
        "--env-kwargs",
        '{"n_agents": 5, "n_steps": 6}',
        "--seeds",
        "0-1",
        "--out",
        str(out),
        "--no-progress",
        "--report",
    ]
    assert cli_main(argv) == 0
    assert (out / "episodes.csv").is_file() and (out / "report" / "report.html").is_file()
    # the one error path: a bad option is one line on stderr and exit code 2
    capsys.readouterr()
    assert cli_main(["evaluate", "--env-kwargs", "n_agents=5", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("agent-envs evaluate: error: --env-kwargs must be a JSON object")
    assert cli_main(["report", str(tmp_path / "missing"), "--out", str(tmp_path / "r")]) == 2
    assert "missing does not exist" in capsys.readouterr().err
    assert cli_main(["report", str(out), "--out", str(tmp_path / "rep")]) == 0
    assert "ratio to turnpike" in (tmp_path / "rep" / "report.md").read_text()
    rt = tmp_path / "rt"
    argv = [
        "reproduce",
        "turnpike",
        "--out",
        str(rt),
        "--n-agents",
        "6",
        "--n-steps",
        "8",
        "--n-paths",
        "2",
        "--no-progress",
    ]
    assert cli_main(argv) == 0
    table = pd.read_csv(rt / "results.csv")
    assert len(table) == 10 and set(table["mode"]) == {"env", "closed-loop"}
    for png in ("turnpike_env.png", "turnpike_closed_loop.png", "lyapunov.png"):
        assert (rt / png).is_file()
    for sub in ("evaluate", "report", "reproduce-turnpike"):
        with pytest.raises(SystemExit) as exc:
            cli_main([sub, "--help"])
        assert exc.value.code == 0
    capsys.readouterr()


def test_paper_setting_em_unstable_after_tbar_serb_reaches_target():
    # Section 5.2 at the paper's setting (N = 100, m = 50, 20 paths), the paper's procedure.
    from agent_envs.draws import uniform_positions
    from agent_envs.training.experiments.turnpike_controlled import (
        PAPER_RUNS,
        run_closed_loop_mode,
        summarize_record,
    )

    x0 = uniform_positions(np.random.default_rng(0), 100, 1)
    rows = {}
    for run in PAPER_RUNS[:2]:  # EM and SERB, xbar = 0.7
        rec = run_closed_loop_mode(run, 0, x0, 50, 20)
        rows[run.integrator] = summarize_record(run, "closed-loop", 0, rec)
    em, serb = rows["em"], rows["serb"]
    assert em["tbar"] == pytest.approx(0.534, abs=1e-3)
    assert em["L_at_tbar"] < 2e-4 and serb["L_at_tbar"] < 3e-4  # turnpike reached at tbar
    assert em["L_at_T"] > 1e3 * em["L_at_tbar"]  # EM: unstable once the control is off
    assert serb["L_at_T"] < 1e-3  # SERB: stays at the target


def test_ratio_is_not_reported_when_episodes_diverged():
    """A diverged episode has a partial cost; its ratio to the reference would flatter it."""
    import pandas as pd

    from agent_envs.training.results.tables import summarize

    rows = []
    for seed in range(3):
        rows.append(
            dict(
                policy="turnpike",
                seed=seed,
                total_cost=2.0,
                diverged=False,
                final_distance=0.1,
                control_energy=1.0,
            )
        )
        rows.append(
            dict(
                policy="quitter",
                seed=seed,
                total_cost=0.1,
                diverged=seed == 0,
                final_distance=0.1,
                control_energy=1.0,
            )
        )
        rows.append(
            dict(
                policy="steady",
                seed=seed,
                total_cost=1.0,
                diverged=False,
                final_distance=0.1,
                control_energy=1.0,
            )
        )
    table = summarize(pd.DataFrame(rows), reference="turnpike").set_index("policy")
    assert np.isnan(table.loc["quitter", "ratio_to_reference"])
    assert table.loc["quitter", "divergence_rate"] == pytest.approx(1 / 3)
    assert table.loc["steady", "ratio_to_reference"] == pytest.approx(0.5)


def test_gap_to_optimal_is_paired_per_seed_and_hidden_for_diverged():
    import pandas as pd

    from agent_envs.training.results.report import display_table, summarize

    costs = {"optimal": [1.0, 2.0, 4.0], "mpc": [0.99, 2.0, 3.96], "twice": [2.0, 4.0, 8.0]}
    rows = [
        dict(
            policy=policy,
            seed=seed,
            total_cost=cost,
            diverged=policy == "quitter" and seed == 0,
            final_distance=0.1,
            control_energy=1.0,
        )
        for policy, values in {**costs, "quitter": [0.5, 0.5, 0.5]}.items()
        for seed, cost in enumerate(values)
    ]
    table = summarize(pd.DataFrame(rows), reference=None).set_index("policy")
    assert table.loc["optimal", "gap_to_optimal"] == 0.0
    assert table.loc["twice", "gap_to_optimal"] == pytest.approx(1.0)
    assert table.loc["twice", "gap_ci_low"] == pytest.approx(1.0)
    assert table.loc["mpc", "gap_to_optimal"] == pytest.approx(-2 / 300)
    assert np.isnan(table.loc["quitter", "gap_to_optimal"])
    shown = display_table(table.reset_index(), None).set_index("policy")
    assert shown.loc["twice", "gap to optimal [95% CI]"].startswith("+100.00%")
    without = summarize(pd.DataFrame([r for r in rows if r["policy"] != "optimal"]), None)
    assert "gap_to_optimal" not in without
