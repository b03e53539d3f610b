"""The quick preset (the paper's study in miniature), its fair-baseline reference, its table.

- the preset's learners are the paper preset's (interfaces, hyperparameters) with the quick
  budgets; MPC is left out (optimal is kept), the centre law is a reference;
- the centre law evaluated through its interface on the default env costs what the same law
  costs on an env built with that interface;
- the published quick table (docs/results.md) is `seed_table_markdown` of the committed
  per-episode files (docs/results/quick/), digit for digit.
"""

from __future__ import annotations

import re
from pathlib import Path

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest

import agent_envs  # noqa: F401  (registers the env ids)
from agent_envs.training.commands.experiment import REFERENCE, ExperimentOptions, build_trials
from agent_envs.training.commands.interface_references import (
    CENTRE_LAW,
    INTERFACE_REFERENCES,
    CentreLaw,
    fair_baseline,
    interface_reference,
)
from agent_envs.training.commands.presets import (
    PAPER_BUDGETS,
    QUICK_BUDGETS,
    QUICK_ENV,
    SUMMARY_COMMON,
    SWARM_TEAM,
    get_preset,
)
from agent_envs.training.defaults import GYM_ENV_ID

ROOT = Path(__file__).resolve().parents[1]
QUICK_FILES = [ROOT / "docs" / "results" / "quick" / f"seed{s}" / "episodes.csv" for s in range(3)]


def test_quick_preset_is_the_paper_study_in_miniature():
    quick, paper = get_preset("quick"), get_preset("paper")
    assert quick.env_kwargs == QUICK_ENV == {"n_agents": 10, "n_steps": 20, "max_control": 25.0}
    by_name = {lr.name: lr for lr in paper.learners}
    assert [lr.name for lr in quick.learners] == ["ppo", "sac", "ppo-shared", "apg"]
    for learner in quick.learners:
        twin = by_name[learner.name]
        assert learner.timesteps == QUICK_BUDGETS[learner.name]
        assert (learner.algo, learner.env_id, learner.env_kwargs) == (
            twin.algo,
            twin.env_id,
            twin.env_kwargs,
        )
        assert learner.n_envs == twin.n_envs
        # the paper preset's ppo-shared normalizes its observations since issue 41; the quick
        # preset's published learner does not (QUICK's comment)
        wanted = False if learner.name == "ppo-shared" else twin.normalize
        assert learner.normalize == wanted, learner.name
        changed = {k for k in twin.hyperparams if learner.hyperparams.get(k) != twin.hyperparams[k]}
        # the replay buffer holds the budget; the shared policy starts near the zero control
        assert changed <= {"buffer_size", "policy_kwargs"}, (learner.name, changed)
    learners = {lr.name: lr for lr in quick.learners}
    assert learners["ppo"].env_kwargs == learners["sac"].env_kwargs == SUMMARY_COMMON
    assert learners["ppo-shared"].env_kwargs == SWARM_TEAM
    assert learners["sac"].hyperparams["buffer_size"] == QUICK_BUDGETS["sac"]
    policy = learners["ppo-shared"].hyperparams["policy_kwargs"]
    assert policy == {**by_name["ppo-shared"].hyperparams["policy_kwargs"], "ortho_init": True}
    assert "mpc" not in quick.references and {"optimal", CENTRE_LAW} <= set(quick.references)
    # the paper preset keeps its budgets and MPC
    assert {lr.name: lr.timesteps for lr in paper.learners if lr.name in PAPER_BUDGETS} == (
        PAPER_BUDGETS
    )
    assert "mpc" in paper.references


def test_fair_baselines_by_interface():
    assert fair_baseline(SUMMARY_COMMON) == CENTRE_LAW
    # the swarm row shows the centre: the centre law is a law of that interface too
    assert fair_baseline(SWARM_TEAM) == CENTRE_LAW
    assert fair_baseline({"observation": "modes", "action_basis": "modes"}) == CENTRE_LAW
    assert fair_baseline({}) == fair_baseline({"observation": "local"}) == "proportional"


def test_the_centre_law_reference_is_a_trial_compare_evaluates():
    trials = build_trials(get_preset("quick"), ExperimentOptions(seeds=(0,)), "runs")
    reference = next(t for t in trials if t.kind == REFERENCE and t.policy == CENTRE_LAW)
    env = gym.make(GYM_ENV_ID, **reference.eval_env_kwargs)
    try:
        policy = reference.reference_spec()(env)
        obs, _ = env.reset(seed=1000)
        action, _ = policy.predict(obs)
    finally:
        env.close()
    assert action.shape == (10,) and action.dtype == np.float32
    assert np.all(action == action[0])  # one common control
    with pytest.raises(ValueError, match="unknown interface reference"):
        interface_reference("proportional", env)


def _cost(env, policy, seed: int) -> float:
    obs, _ = env.reset(seed=seed)
    cost, done = 0.0, False
    while not done:
        action, _ = policy.predict(obs)
        obs, reward, terminated, truncated, _ = env.step(action)
        cost -= float(reward)
        done = terminated or truncated
    return cost


@pytest.mark.parametrize("seed", [1000, 1001])
def test_centre_law_through_its_interface_equals_the_law_in_its_own_env(seed):
    """u_k = 12 (xbar - c) for every agent: on the default env through `InterfacePolicy` as on
    an env made with the summary observation and the common action basis."""
    default = gym.make(GYM_ENV_ID, **QUICK_ENV)
    own = gym.make(GYM_ENV_ID, **QUICK_ENV, **INTERFACE_REFERENCES[CENTRE_LAW])
    try:
        through = _cost(default, interface_reference(CENTRE_LAW, default), seed)
        law = CentreLaw(1, own.unwrapped.max_control)
        direct = _cost(own, law, seed)
    finally:
        default.close()
        own.close()
    assert through == pytest.approx(direct, rel=1e-6)
    assert through > 0


def test_fair_baseline_table_pairs_each_learner_with_its_baseline():
    from agent_envs.training.commands.compare import fair_baseline_table

    rows = []
    for seed, costs in ((0, (1.0, 2.0, 4.0, 2.0)), (1, (3.0, 3.0, 6.0, 6.0))):
        for policy, cost in zip(("sac", CENTRE_LAW, "proportional", "apg"), costs, strict=True):
            rows.append({"policy": policy, "seed": seed, "total_cost": cost})
    learners = {lr.name: lr for lr in get_preset("quick").learners if lr.name in ("sac", "apg")}
    table = fair_baseline_table(pd.DataFrame(rows), learners).set_index("learner")
    assert table.loc["sac", "fair baseline"] == CENTRE_LAW
    assert table.loc["sac", "ratio to fair baseline"] == pytest.approx((0.5 + 1.0) / 2)
    assert table.loc["sac", "ratio to proportional"] == pytest.approx((0.25 + 0.5) / 2)
    assert table.loc["apg", "fair baseline"] == "proportional"
    assert table.loc["apg", "ratio to fair baseline"] == pytest.approx((0.5 + 1.0) / 2)


def test_published_quick_table_is_its_episodes_files():
    from agent_envs.training.commands.seed_table import seed_table_markdown

    page = (ROOT / "docs" / "results.md").read_text()
    match = re.search(r"<!-- quick-table:start -->\n(.*?)<!-- quick-table:end -->", page, re.S)
    assert match, "no quick-table markers in docs/results.md"
    assert match.group(1).strip() == seed_table_markdown("quick", QUICK_FILES).strip()


def test_every_quick_learner_is_below_the_proportional_controller_on_every_seed():
    """The issue's targets, on the published files: every learner below the proportional
    controller (mean over the test seeds) for each training seed; SAC within +10% of the
    optimum."""
    for path in QUICK_FILES:
        costs = pd.read_csv(path).pivot(index="seed", columns="policy", values="total_cost")
        for learner in get_preset("quick").learners:
            assert costs[learner.name].mean() < costs["proportional"].mean(), (path, learner)
        gap = ((costs["sac"] - costs["optimal"]) / costs["optimal"]).mean()
        assert gap < 0.10, (path, gap)


def test_seed_table_refuses_references_that_differ_between_files(tmp_path):
    from agent_envs.training.commands.seed_table import seed_table_markdown

    rows = [
        {"policy": p, "seed": 10_000, "total_cost": c}
        for p, c in (("optimal", 1.0), ("proportional", 2.0), ("apg", 1.5))
    ]
    first, second = tmp_path / "a.csv", tmp_path / "b.csv"
    pd.DataFrame(rows).to_csv(first, index=False)
    rows[1]["total_cost"] = 2.5
    pd.DataFrame(rows).to_csv(second, index=False)
    assert "| **apg** | proportional | 1.5 / 1.5 | +50.00% / +50.00% |" in seed_table_markdown(
        "quick", [first, first]
    )
    with pytest.raises(ValueError, match="differs between the training seeds"):
        seed_table_markdown("quick", [first, second])
