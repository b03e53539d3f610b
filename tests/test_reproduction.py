"""Smoke test of `agent-envs reproduce uncontrolled` on a small setting."""

import json

from agent_envs.training.commands.cli import main
from agent_envs.training.experiments import uncontrolled


def test_reproduce_uncontrolled_writes_table_and_figures(tmp_path):
    out = tmp_path / "unc"
    assert (
        main(["reproduce", "uncontrolled", "--out", str(out), "--n-agents", "12", "--n-paths", "2"])
        == 0
    )
    rows = json.loads((out / "results.json").read_text())
    assert len(rows) == 26
    assert (out / "results.md").read_text().count("\n|") >= 27
    for name in (
        "fig1_stiff_m25",
        "fig2_stiff_em",
        "fig3_nonstiff_m50",
        "fig4_deterministic_m25",
        "fig5_deterministic_m1500",
        "jacobian_study",
    ):
        assert (out / f"{name}.png").stat().st_size > 10_000
    frozen = [r for r in rows if r["integrator"] == "erb" and r["jacobian"] == "frozen"]
    # frozen-kernel exponential Euler reaches consensus at every m (sigma = 0)
    assert all(r["spread_at_T"] < 1e-9 for r in frozen)
    assert all({"spread_at_T", "max_abs_mean_x", "diverged", "wall_time_s"} <= set(r) for r in rows)
    # results.csv holds the same rows, bit for bit, and renders results.md's table
    assert uncontrolled.read_rows(out / "results.csv") == rows
    assert uncontrolled.csv_table(out / "results.csv") in (out / "results.md").read_text()
