"""The paper sweep's tables recomputed from per-trial files (`training/results/paper_sweep`)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from agent_envs.training.results.paper_sweep import (
    paper_sweep_contrasts,
    paper_sweep_table,
    read_runs,
)

SEEDS = [10_002, 10_000, 10_001]  # written out of order: the reader sorts by seed


def _write(folder, trial_id: str, costs, diverged=None):
    diverged = diverged or [False] * len(costs)
    path = folder / f"{trial_id}.csv"
    frame = pd.DataFrame(
        {
            "policy": trial_id,
            "seed": SEEDS,
            "total_cost": costs,
            "diverged": diverged,
        }
    )
    frame.to_csv(path, index=False)
    return path


@pytest.fixture
def files(tmp_path):
    return [
        _write(tmp_path, "main__sac__0", [1.1, 2.2, 3.3]),  # gap +10% on every episode
        _write(tmp_path, "main__sac__1", [1.3, 2.6, 3.9]),  # +30%
        _write(tmp_path, "main__optimal", [1.0, 2.0, 3.0]),
        _write(tmp_path, "main__proportional", [1.25, 2.5, 3.75]),
        _write(tmp_path, "em__sac__0", [1.5, 3.0, 4.5]),  # +50% on the main env's optimum
    ]


def test_main_table_pools_the_seeds_gaps_and_orders_by_mean_cost(files):
    table = paper_sweep_table(*files[:4])
    lines = table.splitlines()
    assert lines[0].startswith("| policy | training seeds | mean cost | gap to optimal")
    assert [line.split(" | ")[0] for line in lines[2:]] == [
        "| optimal",
        "| sac",
        "| proportional",
    ]
    sac = lines[3].split(" | ")
    assert sac[1] == "2"
    assert sac[2] == f"{np.mean([1.1, 2.2, 3.3, 1.3, 2.6, 3.9]):.4g}"
    assert sac[3] == "+20.0% (+10.0% .. +30.0%)"
    assert sac[5] == "0.50"  # seed 0 beats proportional everywhere, seed 1 nowhere
    proportional = lines[4].split(" | ")
    assert proportional[1:4] == ["-", "2.5", "+25.0%"]  # one run: no range
    assert proportional[5] == "-"


def test_contrasts_borrow_the_optimum_and_the_baseline_of_another_setting(files):
    table = paper_sweep_contrasts(*files, settings=("em",), reference_setting={"em": "main"})
    rows = [line.split(" | ") for line in table.splitlines()[2:]]
    assert [(r[0], r[1]) for r in rows] == [
        ("| em", "optimal"),
        ("| em", "proportional"),
        ("| em", "sac"),
    ]
    assert rows[2][4] == "+50.0%"
    with pytest.raises(ValueError, match="lack its optimal"):
        paper_sweep_contrasts(*files, settings=("em",))


def test_files_must_share_test_seeds_and_be_named_by_trial(tmp_path, files):
    other = tmp_path / "other"
    other.mkdir()
    bad = _write(other, "main__zero", [1.0, 1.0, 1.0])
    pd.read_csv(bad).assign(seed=[1, 2, 3]).to_csv(bad, index=False)
    with pytest.raises(ValueError, match="test seeds differ"):
        read_runs([*files, bad])
    with pytest.raises(ValueError, match="SETTING__POLICY"):
        read_runs([_write(other, "main-zero", [1.0, 1.0, 1.0])])
    clash = tmp_path / "clash"
    clash.mkdir()
    both = [_write(clash, "main__sac", [1.0, 2.0, 3.0]), _write(clash, "main__sac__0", [1.0] * 3)]
    with pytest.raises(ValueError, match="share the name"):
        read_runs(both)


def test_percent_keeps_three_digits_and_a_tiny_gap_its_exponent():
    from agent_envs.training.results.paper_sweep import _percent

    assert [_percent(v) for v in (39.89, 0.1903, 0.0195, 0.00054, -5.04e-7)] == [
        "+3989%",
        "+19.0%",
        "+1.95%",
        "+0.054%",
        "-5.0e-05%",
    ]
