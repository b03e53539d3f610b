"""The quick preset's budget design table (docs/presets.md): its renderer on a small synthetic
runs.csv, and the committed files' consistency (the published check of the page's block against
the render is tests/test_published_tables.py's)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
from scripts import load_script

from agent_envs.training.results.design_runs import read_runs, write_runs
from agent_envs.training.results.quick_design import (
    VALIDATION_SEEDS,
    best_gaps,
    mean_cost,
    quick_design_table,
    read_references,
    write_references,
)

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results" / "quick-design"


def _run(variant: str, seed: int, timesteps: int, cost: float) -> dict:
    return {
        "task": "quick",
        "variant": variant,
        "training_seed": seed,
        "timesteps": timesteps,
        "cost_mean": cost,
        "proportional_cost": 3.0,
        "zero_cost": float("nan"),
    }


def _synthetic(tmp_path: Path) -> tuple[Path, Path, Path]:
    runs, references, variants = (
        tmp_path / "runs.csv",
        tmp_path / "references.csv",
        tmp_path / "variants.json",
    )
    write_runs(
        [
            _run("a", 0, 100, 3.0),
            _run("a", 0, 200, 2.5),  # the best validation of run (a, 0)
            _run("a", 0, 300, 2.75),
            _run("a", 2, 100, 4.0),
            _run("b", 1, 100, 2.0),
        ],
        runs,
    )
    # V = 2 (optimal's per-seed costs 1 and 3), proportional 3 (gap +50%), centre law 2.2
    rows = []
    for i, seed in enumerate(VALIDATION_SEEDS):
        rows.append({"policy": "optimal", "seed": seed, "total_cost": [1.0, 3.0][i % 2]})
        rows.append({"policy": "proportional", "seed": seed, "total_cost": 3.0})
        rows.append({"policy": "proportional-common", "seed": seed, "total_cost": 2.2})
    write_references(rows, references)
    variants.write_text(json.dumps({"b": {"label": "B"}, "a": {"label": "A (kept)"}}))
    return runs, references, variants


def test_quick_design_table_is_the_gap_of_the_best_validation(tmp_path):
    """Each cell is J_best / V - 1 (the run's lowest validation cost over the optimum's mean
    cost); rows in variants.json's order, blank for a seed not run; the laws' gaps last."""
    runs, references, variants = _synthetic(tmp_path)
    assert best_gaps(runs, references) == {
        ("a", 0): pytest.approx(0.25),
        ("a", 2): pytest.approx(1.0),
        ("b", 1): pytest.approx(0.0),
    }
    assert quick_design_table(runs, references, variants).splitlines() == [
        "| design run | training seed 0 | seed 1 | seed 2 |",
        "|---|---|---|---|",
        "| B |  | +0.00% |  |",
        "| A (kept) | +25.00% |  | +100.00% |",
        "| the proportional controller (no training) | +50.00% | +50.00% | +50.00% |",
        "| the centre law `proportional-common` (no training) | +10.00% | +10.00% | +10.00% |",
    ]


def test_quick_design_refuses_other_seeds_and_unknown_variants(tmp_path):
    runs, references, variants = _synthetic(tmp_path)
    variants.write_text(json.dumps({"a": {"label": "A"}}))
    with pytest.raises(ValueError, match="not in"):
        quick_design_table(runs, references, variants)
    write_references([{"policy": "optimal", "seed": 1000, "total_cost": 1.0}], references)
    with pytest.raises(ValueError, match="validation seeds"):
        read_references(references)


def test_committed_runs_were_validated_on_the_reference_seeds():
    """Every committed run's validation logged the proportional law's mean cost over the seeds
    of references.csv (so they are the same 10 validation seeds), and names a variant."""
    costs = read_references(RESULTS / "references.csv")
    law = mean_cost(costs, "proportional")
    variants = json.loads((RESULTS / "variants.json").read_text())
    rows = read_runs(RESULTS / "runs.csv")
    assert rows
    for row in rows:
        assert row["variant"] in variants
        assert row["proportional_cost"] == pytest.approx(law, rel=1e-9), row


def test_kept_variants_are_the_quick_presets_learners():
    """A variant labelled "(kept)" trains exactly the quick preset's learner."""
    from agent_envs.training.commands.presets import PRESETS

    module = load_script(ROOT / "benchmarks" / "quick_design.py")
    quick = PRESETS["quick"]
    variants = json.loads((RESULTS / "variants.json").read_text())
    kept = [name for name, v in variants.items() if "(kept)" in v["label"]]
    assert kept
    for name in kept:
        preset, learner = module.variant_preset(name)
        base = next(lr for lr in quick.learners if lr.name == variants[name]["learner"])
        hyper = dict(learner.hyperparams)
        hyper.pop("n_eval_episodes", None)  # apg: validated on the 10 seeds (docs/presets.md)
        assert dataclasses.replace(learner, name=base.name, hyperparams=hyper) == base
        assert preset.evaluations == quick.evaluations


def test_presets_prose_is_what_the_files_say():
    """The figures docs/presets.md quotes under the table, recomputed from runs.csv and
    references.csv."""
    costs = read_references(RESULTS / "references.csv")
    value = mean_cost(costs, "optimal")
    rows = read_runs(RESULTS / "runs.csv")
    gaps = best_gaps(RESULTS / "runs.csv", RESULTS / "references.csv")
    page = " ".join((ROOT / "docs" / "presets.md").read_text().split())

    def curve(variant: str, seed: int) -> list[dict]:
        return [r for r in rows if (r["variant"], r["training_seed"]) == (variant, seed)]

    last_five = [r["cost_mean"] for r in curve("sac-4000", 1)[-5:]]
    assert f"({min(last_five):.3f}-{max(last_five):.3f} in the last five" in page
    assert gaps["sac-4000", 1] > 0.10 > max(gaps["sac", s] for s in range(3))
    assert all(gaps["sac", s] < gaps["sac-4000", s] for s in range(3))
    bad = curve("ppo-shared-entry", 2)
    assert f"validation cost of {bad[0]['cost_mean']:.1f} on seed 2" in page
    assert f"(after {bad[0]['timesteps']:,} agent-steps".replace(",", " ") in page
    assert f"zero control's {bad[0]['zero_cost']:.2f})" in page
    assert f"still at {bad[-1]['cost_mean']:.1f} when" in page
    assert f"seed 1's best is +{100 * gaps['ppo-shared-entry', 1]:.0f}%" in page
    kept = sorted(gaps["ppo-shared", s] for s in range(3))
    assert f"(+{100 * kept[0]:.1f}% to +{100 * kept[-1]:.1f}%)" in page
    centre = mean_cost(costs, "proportional-common") / value - 1
    law = mean_cost(costs, "proportional") / value - 1
    for seed in range(3):
        ppo = curve("ppo", seed)
        assert ppo[-1]["cost_mean"] == min(r["cost_mean"] for r in ppo)
        assert gaps["ppo", seed] < law
        assert (gaps["ppo", seed] < centre) == (seed == 2)
        apg = curve("apg", seed)
        at_100 = next(r["cost_mean"] for r in apg if r["timesteps"] == 100 * 20)
        assert (at_100 - min(r["cost_mean"] for r in apg)) / value < 0.0015
