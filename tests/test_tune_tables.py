"""docs/tune.md's search table from the searches' committed files (`tune_tables`)."""

from __future__ import annotations

import pytest

from agent_envs.training.results.tune_tables import top_importances, tune_search_table

SUMMARY = """# Tuning sac

## Best trials

| trial | validation_cost |

## Parameter importances (Optuna, fANOVA)

- log_std_init: 0.445
- one_minus_gamma: 0.317
- learning_rate: 0.207

## Best hyperparameters
- not an importance: 1.0
"""


def _search(tmp_path, learner: str, costs: list[str]):
    folder = tmp_path / f"tune-paper-{learner}"
    folder.mkdir()
    trials = folder / "trials.csv"
    trials.write_text(
        "trial,validation_cost\n" + "".join(f"t{i},{c}\n" for i, c in enumerate(costs))
    )
    summary = folder / "tune_summary.md"
    summary.write_text(SUMMARY)
    curve = tmp_path / f"{learner}_curve.csv"
    curve.write_text("timesteps,cost_mean\n100,0.09\n200,0.0681\n300,0.0700\n")
    return trials, summary, curve


def test_the_table_takes_the_best_finite_trial_and_the_runs_best_validation(tmp_path):
    files = _search(tmp_path, "sac", ["0.0712", "nan", "0.0686", "3.1"])
    table = tune_search_table(*files)
    assert table.splitlines()[2] == (
        "| sac | 4 | 0.0686 | 0.0681 | log_std_init 0.45, one_minus_gamma 0.32 |"
    )
    assert top_importances(files[1], count=5)[-1] == ("learning_rate", 0.207)


def test_bad_input_is_named(tmp_path):
    files = _search(tmp_path, "td3", ["nan"])
    with pytest.raises(ValueError, match="no trial has a finite"):
        tune_search_table(*files)
    with pytest.raises(ValueError, match="triples"):
        tune_search_table(*files[:2])
    good = _search(tmp_path, "sac", ["0.07"])
    good[2].write_text("timesteps,cost_mean\n100,nan\n200,inf\n")
    with pytest.raises(ValueError, match="no evaluation has a finite"):
        tune_search_table(*good)


def test_a_nan_evaluation_is_skipped(tmp_path):
    files = _search(tmp_path, "ppo", ["0.07"])
    files[2].write_text("timesteps,cost_mean\n100,nan\n200,0.0690\n")
    assert "| ppo | 1 | 0.07 | 0.069 |" in tune_search_table(*files)
