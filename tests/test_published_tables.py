"""Every published result table is its committed files, digit for digit (`agent-envs tables`).

One case per registered table (`published.PUBLISHED`): the page's marked block equals the
table rendered from the files under docs/results/. The inventory in docs/development.md lists
every result table of README.md and docs/ with its files (or "no file"); the tables it marks
as rendered are exactly the registered ones.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest

from agent_envs.training.commands.published import (
    PUBLISHED,
    marked_block,
    replace_block,
    stale_tables,
    write_tables,
)

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("table", PUBLISHED, ids=[t.name for t in PUBLISHED])
def test_published_table_is_its_files(table):
    page = (ROOT / table.page).read_text()
    assert marked_block(page, table.marker) == table.rendered(ROOT).strip(), table.name


def test_every_marker_on_the_pages_is_registered_once():
    """A marked block no table owns would go stale silently; a name registered twice would be
    rewritten twice."""
    names = [t.name for t in PUBLISHED]
    assert len(names) == len(set(names))
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("**/*.md"))]
    found = set()
    for path in pages:
        for marker in re.findall(r"^<!-- ([\w-]+):start -->$", path.read_text(), re.M):
            found.add(f"{path.relative_to(ROOT)}#{marker}")
    assert found == set(names)


def test_inventory_names_every_registered_table():
    """docs/development.md's "Published tables and their files" names each registered table."""
    text = (ROOT / "docs" / "development.md").read_text()
    inventory = text.split("## Published tables and their files", 1)[1].split("\n## ", 1)[0]
    for table in PUBLISHED:
        assert f"`{table.marker}`" in inventory, table.name


def _copy(tmp_path: Path) -> Path:
    """README.md, the pages and the results of a checkout (what the command reads)."""
    root = tmp_path / "root"
    shutil.copytree(ROOT / "docs", root / "docs")
    shutil.copy(ROOT / "README.md", root / "README.md")
    (root / "agent_envs" / "tasks" / "data").mkdir(parents=True)
    shutil.copy(ROOT / "agent_envs/tasks/data/SHA256SUMS", root / "agent_envs/tasks/data")
    return root


def test_check_names_a_stale_table_and_writing_restores_it(tmp_path, capsys):
    from agent_envs.training.commands.cli import main

    root = _copy(tmp_path)
    page = root / "docs" / "env-options.md"
    original = page.read_text()
    page.write_text(original.replace("| 0.06756 |", "| 0.06757 |"))
    assert stale_tables(root) == ["docs/env-options.md#env-options-table"]
    assert main(["tables", "--root", str(root), "--check"]) == 1
    assert "stale: docs/env-options.md#env-options-table" in capsys.readouterr().out
    assert write_tables(root) == ["docs/env-options.md#env-options-table"]
    assert page.read_text() == original
    assert main(["tables", "--root", str(root), "--check"]) == 0


def test_replace_block_keeps_the_markers_and_refuses_a_missing_one():
    text = "a\n<!-- t:start -->\nold\n\n<!-- t:end -->\nb\n"
    assert replace_block(text, "t", "new\n") == "a\n<!-- t:start -->\nnew\n<!-- t:end -->\nb\n"
    with pytest.raises(ValueError, match="no <!-- u:start -->"):
        replace_block(text, "u", "new")


def _agrees(printed: str, value: float) -> bool:
    """`printed` is `value` rounded to the printed digits."""
    decimals = len(printed.split(".")[1]) if "." in printed else 0
    return abs(float(printed) - value) <= 0.5 * 10.0**-decimals * 1.0001


def test_long_horizon_figures_are_the_committed_run():
    """docs/cheap-control-bound.md's "Longer horizons" V_fresh and F are the committed CSV's."""
    from agent_envs.training.experiments.cheap_control_bound import read_rows

    path = ROOT / "docs/results/cheap-control-bound/long-horizon/cheap_control_bound.csv"
    rows = [r for r in read_rows(path) if r["case"] == "V(T)" and r["sigma"] > 0]
    assert [r["T"] for r in rows] == [4.0, 8.0, 16.0, 32.0]
    text = " ".join((ROOT / "docs" / "cheap-control-bound.md").read_text().split())
    quoted = re.search(r"V_fresh = ([\d., ]+) for T = 4, 8, 16, 32 against F = ([\d., ]+) -", text)
    assert quoted is not None
    for group, column in ((1, "V_fresh"), (2, "floor")):
        printed = [p.strip() for p in quoted.group(group).split(",")]
        assert len(printed) == len(rows)
        for cell, row in zip(printed, rows, strict=True):
            assert _agrees(cell, row[column]), (column, cell, row[column])
    assert all(r["corrected_holds"] for r in read_rows(path))


def _gaps_percent(path: Path) -> dict[str, list[float]]:
    """Per-policy list of 100 (cost - V) / V over the seeds of one episodes.csv."""
    import csv

    costs: dict[str, dict[int, float]] = {}
    with path.open() as f:
        for row in csv.DictReader(f):
            costs.setdefault(row["policy"], {})[int(row["seed"])] = float(row["total_cost"])
    optimal = costs["optimal"]
    return {
        name: [100.0 * (c - optimal[s]) / optimal[s] for s, c in by_seed.items()]
        for name, by_seed in costs.items()
    }


def test_optimum_page_seed_by_seed_figures_are_the_committed_runs():
    """docs/optimum.md's seed-by-seed prose (the proportional law's range, MPC's wins, each
    quick-preset learner's range over its 3 training seeds) is the committed episodes'."""
    text = " ".join((ROOT / "docs" / "optimum.md").read_text().split())
    gaps = _gaps_percent(ROOT / "docs/results/evaluate/quick-optimum/episodes.csv")
    quoted = re.search(r"proportional controller costs ([\d.]+)% to ([\d.]+)% more", text)
    assert quoted is not None
    assert _agrees(quoted.group(1), min(gaps["proportional"]))
    assert _agrees(quoted.group(2), max(gaps["proportional"]))
    quoted = re.search(
        r"MPC is cheaper than it on (\d+) of the 20 seeds, by at most ([\d.]+)%, and dearer on "
        r"the other three by at most ([\d.]+)%",
        text,
    )
    assert quoted is not None
    mpc = gaps["mpc"]
    assert len(mpc) == 20 and int(quoted.group(1)) == sum(g < 0 for g in mpc) == 17
    assert _agrees(quoted.group(2), -min(mpc))
    assert _agrees(quoted.group(3), max(mpc))
    learners: dict[str, list[float]] = {}
    for seed in (0, 1, 2):
        for name, values in _gaps_percent(
            ROOT / f"docs/results/quick/seed{seed}/episodes.csv"
        ).items():
            learners.setdefault(name, []).extend(values)
    for label, name in (
        ("`apg` is", "apg"),
        ("SAC", "sac"),
        ("parameter-shared PPO", "ppo-shared"),
        ("and PPO", "ppo"),
    ):
        quoted = re.search(re.escape(label) + r" ([\d.]+)% to ([\d.]+)%", text)
        assert quoted is not None, label
        assert _agrees(quoted.group(1), min(learners[name])), name
        assert _agrees(quoted.group(2), max(learners[name])), name


def test_em_transfer_prose_is_the_committed_runs():
    """docs/results.md's EM-to-SERB prose: the EM-trained learners cost 14% to 118% more on
    SERB than the SERB-trained runs of the same seed, and none is below the centre law."""
    import pandas as pd

    from agent_envs.training.commands.published import EM_TO_SERB_FILES, QUICK_FILES

    text = " ".join((ROOT / "docs" / "results.md").read_text().split())
    quoted = re.search(r"cost (\d+)% to (\d+)% more than the policies trained on SERB", text)
    assert quoted is not None
    excess, fair = [], []
    for seed in range(3):
        serb = pd.read_csv(ROOT / EM_TO_SERB_FILES[2 * seed + 1]).groupby("policy")
        trained = pd.read_csv(ROOT / QUICK_FILES[seed]).groupby("policy")
        for learner in ("ppo", "ppo-shared"):
            cost = serb["total_cost"].mean()[learner]
            excess.append(100 * (cost / trained["total_cost"].mean()[learner] - 1))
            fair.append(cost > serb["total_cost"].mean()["proportional-common"])
    assert _agrees(quoted.group(1), min(excess)) and _agrees(quoted.group(2), max(excess))
    assert all(fair)


def test_mean_field_slopes_are_the_committed_run():
    """docs/large-swarms.md's W1 slopes against N (at T and at t = 0) are the log-log fits of
    the committed mean-field rows."""
    import csv

    import numpy as np

    with open(ROOT / "docs/results/large-swarms/mean_field.csv", newline="") as handle:
        rows = [r for r in csv.DictReader(handle) if r["n_agents"] != r["reference_n"]]
    text = " ".join((ROOT / "docs" / "large-swarms.md").read_text().split())
    quoted = re.search(r"slope (-[\d.]+) at T against (-[\d.]+) at t = 0", text)
    assert quoted is not None
    for group, time in ((1, "T"), (2, "0")):
        mine = [r for r in rows if r["time"] == time]
        n = np.log([float(r["n_agents"]) for r in mine])
        w1 = np.log([float(r["w1_to_reference"]) for r in mine])
        assert len(mine) == 3
        assert _agrees(quoted.group(group), float(np.polyfit(n, w1, 1)[0]))


def _table_rows(page: str, header_start: str) -> list[list[str]]:
    """The body cells of the Markdown table on `page` whose header row starts with
    `header_start` (bold marks stripped)."""
    lines = (ROOT / page).read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if line.strip().startswith(header_start))
    rows = []
    for line in lines[start + 2 :]:
        if not line.strip().startswith("|"):
            break
        rows.append([c.strip().replace("**", "") for c in line.strip().strip("|").split("|")])
    return rows


def test_marl_study_tables_are_the_committed_files():
    """docs/learners/marl-libraries.md's fresh-policy and design-run tables are the committed
    files of docs/results/marl-study/, to the printed digits."""
    import csv
    import json

    page = "docs/learners/marl-libraries.md"
    study = ROOT / "docs/results/marl-study"
    fresh = json.loads((study / "fresh_policy.json").read_text())["rows"]
    rows = _table_rows(page, "| s (train bound)")
    assert len(rows) == 4
    for cells in rows:
        scale = {"1": 1.0, "1/2": 0.5, "1/4": 0.25, "1/8": 0.125}[cells[0].split()[0]]
        mine = {r["layout"]: r for r in fresh if r["action_scale"] == scale}
        for cell, layout in zip(cells[1:4], ("swarm", "relative", "local"), strict=True):
            assert _agrees(cell, mine[layout]["fresh"]), (scale, layout)
        assert _agrees(cells[4], mine["swarm"]["zero"])
        assert _agrees(cells[5], mine["swarm"]["proportional"])
    curves = {}
    for algorithm in ("mappo", "ippo"):
        path = study / "StiffSwarm-v0" / f"{algorithm}_seed0" / "validation.csv"
        with open(path, newline="") as handle:
            curves[algorithm] = {int(r["frames"]): r for r in csv.DictReader(handle)}
    rows = _table_rows(page, "| frames | MAPPO: J")
    assert len(rows) == len(curves["mappo"])
    for cells in rows:
        frames = int(cells[0].replace(",", ""))
        for algorithm, (j, wall) in (("mappo", cells[1:3]), ("ippo", cells[3:5])):
            if j == "-":
                assert frames not in curves[algorithm]
                continue
            assert _agrees(j, float(curves[algorithm][frames]["validation_cost"]))
            assert _agrees(wall, float(curves[algorithm][frames]["seconds"]))


def test_paper_size_cheap_control_figures_are_the_committed_run():
    """docs/cheap-control-bound.md's "At the paper's sizes and noise" figures (V_fresh and F at
    x^0 = xbar, the crossings, the contraction factors, the rows where the corrected bound
    holds) are the committed paper-size run's."""
    import csv

    from agent_envs.training.experiments.cheap_control_bound import read_rows

    folder = ROOT / "docs/results/cheap-control-bound/paper-size"
    rows = read_rows(folder / "cheap_control_bound.csv")
    text = " ".join((ROOT / "docs" / "cheap-control-bound.md").read_text().split())
    quoted = re.search(
        r"x\^0 = xbar: V_fresh = ([\d.e, -]+) against F = ([\d.e, -]+) for T = 0.5, 1, 2", text
    )
    assert quoted is not None
    at_target = [r for r in rows if r["case"] == "x0=xbar"]
    assert [r["T"] for r in at_target] == [0.5, 1.0, 2.0]
    for group, column in ((1, "V_fresh"), (2, "floor")):
        printed = [p.strip() for p in quoted.group(group).split(",")]
        for cell, row in zip(printed, at_target, strict=True):
            mantissa, exponent = cell.split("e")
            assert _agrees(mantissa, row[column] / 10.0 ** int(exponent)), (column, cell)
    noisy = next(r for r in rows if r["case"] == "V(T)" and r["sigma"] > 0)
    random = next(r for r in rows if r["case"] == "random x0")
    for printed, value in (
        ("1.05e5", noisy["T_cross_lemma"]),
        ("2.1e6", noisy["T_cross_theorem"]),
        ("1.8e6", random["T_cross_lemma"]),
    ):
        assert f"at T = {printed}" in text or f"at {printed}" in text, printed
        mantissa, exponent = printed.split("e")
        assert _agrees(mantissa, value / 10.0 ** int(exponent)), printed
    assert f"holds on all {len(rows)} rows" in text and all(r["corrected_holds"] for r in rows)
    with open(folder / "contraction.csv", newline="") as handle:
        held = {
            r["control"]: float(r["factor_median"])
            for r in csv.DictReader(handle)
            if float(r["sigma"]) == 0 and "held" in r["control"]
        }
    frozen, exact = (held[k] for k in sorted(held, key=lambda k: "exact" in k))
    quoted = re.search(r"contracts L by ([\d.]+) \(frozen J\) and ([\d.]+) \(exact J\)", text)
    assert quoted is not None
    assert _agrees(quoted.group(1), frozen) and _agrees(quoted.group(2), exact)


def _turnpike_rows(folder: str) -> list[dict[str, str]]:
    import csv

    path = ROOT / "docs/results/turnpike-property" / folder / "turnpike_property.csv"
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def test_turnpike_property_prose_is_the_committed_runs():
    """docs/turnpike-theory.md's paper-size figures (V, the entry rates at the longest horizon
    against the predicted one, the noise-free shares) and the multi-seed share ranges are the
    committed runs'."""
    text = " ".join((ROOT / "docs" / "turnpike-theory.md").read_text().split())
    rows = _turnpike_rows("paper-size")
    quoted = re.search(
        r"V = ([\d.]+) for every T \(([\d.]+)-([\d.]+) with sigma = 0.01\), entry rates "
        r"([\d.]+) \(sigma = 0\) and ([\d.]+) \(sigma = 0.01\) against the predicted ([\d.]+), "
        r"shares within delta ([\d.]+) / ([\d.]+) / ([\d.]+) for T = 1 / 2 / 4",
        text,
    )
    assert quoted is not None
    assert all(_agrees(quoted.group(1), float(r["V"])) for r in rows if float(r["sigma"]) == 0)
    noisy = [float(r["V"]) for r in rows if float(r["sigma"]) == 0.01]
    assert _agrees(quoted.group(2), min(noisy)) and _agrees(quoted.group(3), max(noisy))
    longest = {float(r["sigma"]): r for r in rows if float(r["T"]) == 4.0}
    assert _agrees(quoted.group(4), float(longest[0.0]["entry_rate"]))
    assert _agrees(quoted.group(5), float(longest[0.01]["entry_rate"]))
    assert _agrees(quoted.group(6), float(longest[0.0]["predicted_entry_rate"]))
    noiseless = {float(r["T"]): r for r in rows if float(r["sigma"]) == 0}
    for group, horizon in ((7, 1.0), (8, 2.0), (9, 4.0)):
        assert _agrees(quoted.group(group), float(noiseless[horizon]["share_within_delta"]))
    rows = _turnpike_rows("multi-seed")
    assert len(rows) == 90 and all(r["converged"] == "True" for r in rows)
    quoted = re.search(
        r"the share at T = 8 is ([\d.]+)-([\d.]+) with delta = 2e-4, ([\d.]+)-([\d.]+) with delta "
        r"/ 10 and ([\d.]+)-([\d.]+) with 10 delta \(([\d.]+)-([\d.]+), ([\d.]+)-([\d.]+), "
        r"([\d.]+)-([\d.]+) at T = 2\)",
        text,
    )
    assert quoted is not None
    columns = ("share_within_delta", "share_delta_over_10", "share_delta_times_10")
    group = 1
    for horizon in (8.0, 2.0):
        mine = [r for r in rows if float(r["T"]) == horizon and float(r["sigma"]) == 0]
        assert len(mine) == 9
        for column in columns:
            values = [float(r[column]) for r in mine]
            assert _agrees(quoted.group(group), min(values)), (horizon, column)
            assert _agrees(quoted.group(group + 1), max(values)), (horizon, column)
            group += 2


def test_mappo_leaderboard_runs_are_the_quoted_ones():
    """marl-libraries.md's best validation costs of the leaderboard's MAPPO units are their
    committed run folders' (one per training seed, all at the last batch)."""
    import json

    text = " ".join((ROOT / "docs/learners/marl-libraries.md").read_text().split())
    quoted = re.search(r"best validation costs ([\d.]+), ([\d.]+), ([\d.]+) on the seeds", text)
    assert quoted is not None
    folder = ROOT / "docs/results/marl-study/leaderboard/StiffSwarm-v0"
    for seed in range(3):
        result = json.loads((folder / f"mappo_seed{seed}" / "result.json").read_text())
        assert _agrees(quoted.group(seed + 1), result["best_validation_cost"])
        assert result["best_frames"] == result["frames"] == 12_000


def _best_validation(path: Path) -> float:
    import csv

    with open(path, newline="") as handle:
        return min(float(row["cost_mean"]) for row in csv.DictReader(handle))


def test_apg_contrast_prose_is_the_committed_run():
    """docs/learners/apg.md's contrast prose: the EM runs' validation cost at the initial law
    and at their last iteration, and the gradient norms of the part `gradient`."""
    import csv
    import json

    text = " ".join((ROOT / "docs" / "learners" / "apg.md").read_text().split())
    quoted = re.search(
        r"rose from ([\d.]+) at the initial law to ([\d.]+), ([\d.]+) and ([\d.]+)", text
    )
    assert quoted is not None
    for seed in range(3):
        path = ROOT / f"docs/results/apg/curves/em-serb-seed{seed}.csv"
        with open(path, newline="") as handle:
            rows = list(csv.DictReader(handle))
        assert _agrees(quoted.group(1), float(rows[0]["cost_mean"]))
        assert _agrees(quoted.group(2 + seed), float(rows[-1]["cost_mean"]))
        assert int(rows[-1]["iteration"]) == 300
    grads = json.loads((ROOT / "docs/results/apg/results.json").read_text())["gradient"]["rows"]
    norm = {(r["epsilon"], r["integrator"], r["seed"]): r["grad_norm"] for r in grads}
    norms = re.search(
        r"SERB ([\d.]+) / ([\d.]+) and EM ([\d.]+)e16 / ([\d.]+)e16 at eps = 0.05", text
    )
    assert norms is not None
    for group, key, scale in (
        (1, (0.05, "serb", 0), 1.0),
        (2, (0.05, "serb", 1), 1.0),
        (3, (0.05, "em", 0), 1e16),
        (4, (0.05, "em", 1), 1e16),
    ):
        assert _agrees(norms.group(group), norm[key] / scale), (key, norm[key])


def test_tune_prose_is_the_paper_sweeps_runs():
    """docs/tune.md: the hand-chosen entries' best validation cost on seeds 0, 1, 2 are the
    paper sweep's runs (seed 0's curve is committed for the rendered table; all three for this
    prose)."""
    from agent_envs.training.results.tune_tables import best_trial_cost

    text = " ".join((ROOT / "docs" / "tune.md").read_text().split())
    hand = {
        learner: [
            _best_validation(ROOT / f"docs/results/paper-sweep/curves/main__{learner}__{s}.csv")
            for s in range(3)
        ]
        for learner in ("ppo", "sac", "td3")
    }
    best = {
        learner: best_trial_cost(ROOT / f"docs/results/tune-paper-{learner}/trials.csv")[1]
        for learner in hand
    }
    # "SAC's best trial is inside the spread between seeds, PPO's just below it, and TD3's
    # (0.0716) below all three"
    assert "SAC's best trial is inside the spread between seeds, PPO's just below it" in text
    assert min(hand["sac"]) <= best["sac"] <= max(hand["sac"])
    assert best["ppo"] < min(hand["ppo"]) and best["td3"] < min(hand["td3"])
    assert _agrees(re.search(r"and TD3's \(([\d.]+)\) below all three", text).group(1), best["td3"])
    for label, learner in (("PPO", "ppo"), ("SAC", "sac"), ("TD3", "td3")):
        quoted = re.search(rf"{label} ([\d.]+), ([\d.]+), ([\d.]+)", text)
        assert quoted is not None, label
        for seed in range(3):
            curve = ROOT / f"docs/results/paper-sweep/curves/main__{learner}__{seed}.csv"
            assert _agrees(quoted.group(1 + seed), _best_validation(curve)), (learner, seed)


def _sweep_costs(trial: str):
    import pandas as pd

    path = ROOT / "docs" / "results" / "paper-sweep" / "episodes" / f"{trial}.csv"
    episodes = pd.read_csv(path).sort_values("seed")
    assert not episodes["diverged"].astype(bool).any(), trial  # "No episode diverged."
    return episodes["total_cost"].to_numpy(float)


def test_paper_sweep_prose_is_the_committed_episodes():
    """docs/results.md "Results at the paper's scale": the claims the bullets make of the
    rendered tables (every episode, every seed, how many seeds) hold on the per-trial files."""
    import numpy as np

    text = " ".join((ROOT / "docs" / "results.md").read_text().split())
    proportional, centre = (
        _sweep_costs("main__proportional"),
        _sweep_costs("main__proportional-common"),
    )
    optimum = _sweep_costs("main__optimal")
    seeds = range(3)
    # every learner but ppo-modes below the proportional controller on every test episode
    assert "Every learner but `ppo-modes` is below the proportional controller on every" in text
    for learner in ("ppo", "sac", "td3", "ppo-shared", "ppo-local", "apg"):
        for seed in seeds:
            assert (_sweep_costs(f"main__{learner}__{seed}") < proportional).all(), learner
    assert not all((_sweep_costs(f"main__ppo-modes__{s}") < proportional).all() for s in seeds)

    # against the centre law, by training seed: each seed's gap to the optimum (the table's)
    def gap(costs):
        return float(((costs - optimum) / optimum).mean())

    below = {
        learner: sum(gap(_sweep_costs(f"main__{learner}__{s}")) < gap(centre) for s in seeds)
        for learner in ("ppo-shared", "ppo", "sac", "td3")
    }
    assert below == {"ppo-shared": 3, "ppo": 3, "sac": 2, "td3": 0}
    assert "`ppo-shared` and PPO are below it on every training seed, SAC on two of three" in text
    em_ppo = sum(gap(_sweep_costs(f"em-to-serb__ppo__{s}")) < gap(centre) for s in seeds)
    assert em_ppo == 1 and "below the centre law on one seed of three" in text
    # apg within +0.061% on every seed
    worst = max(((_sweep_costs(f"main__apg__{s}") - optimum) / optimum).mean() for s in seeds)
    assert "within +0.061% of the optimum on every seed" in text and 0 < worst < 0.00061 + 5e-7
    # MPC: 5e-7 below on average, at most 2e-6 on one episode
    mpc = _sweep_costs("main__mpc") / optimum - 1
    assert "5e-7 below it on average, at most 2e-6 on one episode" in text
    assert _agrees("5", -mpc.mean() * 1e7) and _agrees("2", -mpc.min() * 1e6)
    # eps = 1: ppo-shared below, ppo-local above the proportional controller on every episode
    eps1 = _sweep_costs("eps1__proportional")
    assert all((_sweep_costs(f"eps1__ppo-shared__{s}") < eps1).all() for s in seeds)
    assert all((_sweep_costs(f"eps1__ppo-local__{s}") > eps1).all() for s in seeds)
    assert "`ppo-local` is +15.7% to +39.6%, above the proportional controller on every" in text
    # EM-trained apg keeps the proportional law: the same cost within 2e-6 relative
    assert "the same cost within 2e-6 relative on every episode" in text
    for seed in seeds:
        ratio = _sweep_costs(f"em-to-serb__apg__{seed}") / proportional
        assert np.allclose(ratio, 1.0, rtol=0, atol=2e-6), seed


#: timing prose: (page, the printed figure in the page's words, its output file, the same
#: figure in the output): each quoted number is the committed run's
TIMING_PROSE = (
    (
        "benchmarks.md",
        r"at the edge \(([\d.]+)x, frozen J",
        "bench_integrators",
        r"\| 100 \| 1 \| serb \(frozen\) \| [\d.]+ \| ([\d.]+) \|",
    ),
    (
        "benchmarks.md",
        r"\*\*not met\*\* \(([\d.]+)x\)",
        "bench_integrators",
        r"\| 100 \| 20 \| serb \(frozen\) \| [\d.]+ \| [\d.]+ \| ([\d.]+) \|",
    ),
    (
        "benchmarks.md",
        r"only at m = 3200: ([\d.]+)x and [\d.]+x",
        "bench_integrators",
        r"error at T: EM needs m = 3200 to match SERB\(25\): ([\d.]+)x",
    ),
    (
        "benchmarks.md",
        r"only at m = 3200: [\d.]+x and ([\d.]+)x",
        "bench_integrators",
        r"error at T: EM needs m = 3200 to match SERB\(25\): ([\d.]+)x the wall time\s*\Z",
    ),
    (
        "benchmarks.md",
        r"one gradient costs ([\d.]+)x a torch forward",
        "bench_gradient",
        r"\| krylov \|[^|]+\|[^|]+\|[^|]+\| ([\d.]+) \|",
    ),
    (
        "benchmarks.md",
        r"takes ([\d.]+)x a torch forward simulation",
        "bench_optimal",
        r"gradient / forward \(torch\)\s+([\d.]+) x",
    ),
    (
        "benchmarks.md",
        r"and ([\d.]+)x the numpy `simulate`",
        "bench_optimal",
        r"gradient / forward \(numpy\)\s+([\d.]+) x",
    ),
    (
        "benchmarks.md",
        r"relative gradient of 1e-6 takes ([\d.]+) s",
        "bench_optimal",
        r"solve to relative gradient 1e-06: ([\d.]+) s",
    ),
    (
        "benchmarks.md",
        r"the limit changes nothing \(([\d.]+)x; entering it costs ([\d.]+) us",
        "bench_blas_threads",
        r"ratio limited / default: ([\d.]+); entering hot_path_threads\(\): ([\d.]+) us",
    ),
    (
        "large-swarms.md",
        r"from N = 10\^4 to 10\^6: ([\d.]+) \(spread\), ([\d.]+) \(clustered\)",
        "bench_large_swarms",
        r"spread step time, N = 1e4 -> 1e6: ([\d.]+)[\s\S]*"
        r"clustered step time, N = 1e4 -> 1e6: ([\d.]+)",
    ),
    (
        "large-swarms.md",
        r"matrix-free is ([\d.]+)x faster",
        "bench_large_swarms",
        r"\| 1e\+04 \|[^\n]*\| ([\d.]+) \|\n",
    ),
    (
        "large-swarms.md",
        r"9x faster there with one path \(([\d.]+)\)",
        "bench_large_swarms_crossover",
        r"(?m)^\| 500 \| 1 \|[^|]+\|[^|]+\| ([\d.]+) \|",
    ),
    (
        "large-swarms.md",
        r"3\.7x with 20 paths \(([\d.]+)\)",
        "bench_large_swarms_crossover",
        r"(?m)^\| 500 \| 20 \|[^|]+\|[^|]+\| ([\d.]+) \|",
    ),
)


@pytest.mark.parametrize(
    "page, quoted, script, printed",
    TIMING_PROSE,
    ids=[t[2] + ":" + t[1][:24] for t in TIMING_PROSE],
)
def test_timing_prose_is_the_committed_run(page, quoted, script, printed):
    text = " ".join((ROOT / "docs" / page).read_text().split())
    output = (ROOT / "docs" / "results" / "benchmarks" / "other" / f"{script}.txt").read_text()
    found = re.search(quoted, text)
    assert found is not None, quoted
    source = re.search(printed, output)
    assert source is not None, printed
    groups = [g for g in found.groups() if g is not None]
    assert groups and len(groups) <= len(source.groups())
    for cell, value in zip(groups, source.groups()[: len(groups)], strict=True):
        assert _agrees(cell, float(value)), (cell, value)


def test_user_step_tables_are_the_committed_run():
    """docs/benchmarks.md "Where users step": every value and A/B figure of its two tables is
    the committed JSON's (`bench_user_step.py --json`), rounded as printed."""
    import json

    data = json.loads((ROOT / "docs/results/user-step/bench_user_step_ab.json").read_text())
    steps = {s["figure"]: s for s in data["steps"]}
    text = (ROOT / "docs" / "benchmarks.md").read_text()
    section = text.split("### Where users step", 1)[1].split("\n## ", 1)[0]
    rows = [
        [c.strip() for c in line.strip("|").split("|")]
        for line in section.splitlines()
        if line.startswith("|") and not line.startswith("|---")
    ]
    by_figure = {row[1]: row for row in rows if len(row) >= 4}

    def check(row_figure: str, json_figure: str) -> None:
        row, step = by_figure[row_figure], steps[json_figure]
        assert _agrees(row[2], step["value"]), (row_figure, row[2], step["value"])
        if row[3]:
            assert _agrees(row[3].split("x")[0], step["old_over_new"]), (row_figure, row[3])

    check(
        "`gym.make` env step (default wrappers) / native per-env step, B = 64",
        "`gym.make` env step / native per-env step (B = 64), 1 path",
    )
    check(
        "bare `SwarmEnv` step (no wrapper) / the same floor",
        "bare `SwarmEnv` step (no wrapper) / native per-env step",
    )
    check(
        "first steps of a fresh process / the same steps warm",
        "`gym.make` env, first steps of a fresh process / warm",
    )
    check(
        "parallel env step, N = 100 / native per-env step",
        "PettingZoo step, N = 100 / native per-env step",
    )
    check(
        "the same / its five dicts of N entries alone (PettingZoo's API)",
        "PettingZoo step, N = 100 / its five dicts alone",
    )
    check(
        "the same / (native per-env step + five dicts)",
        "PettingZoo step, N = 100 / (native per-env step + five dicts)",
    )
    check(
        "parallel env step, N = 10 / native per-env step, N = 10",
        "PettingZoo step, N = 10 / native per-env step, N = 10",
    )
    check(
        "`gym.make` env step / native per-env step, 20 paths, B = 64",
        "`gym.make` env step / native per-env step, 20 paths",
    )
    shares = by_figure[
        "each wrapper's share of the `gym.make` step: OrderEnforcing; PassiveEnvChecker; TimeLimit"
    ][2].split(";")
    for cell, name in zip(
        shares, ("OrderEnforcing", "PassiveEnvChecker", "TimeLimit"), strict=True
    ):
        value = steps[f"{name}'s share of the `gym.make` step"]["value"]
        assert _agrees(cell.replace("%", "").strip(), 100 * value), (name, cell)
    ppo = {p["vec_env"]: p for p in data["ppo"]}
    for label, key in (
        ("`DummyVecEnv` of `gym.make` envs", "dummy"),
        ("`NativeVecEnv`", "native"),
        ("parameter-shared PPO through SuperSuit", "supersuit"),
    ):
        row = next(r for r in rows if r[0] == label)
        assert _agrees(row[1].replace(",", ""), round(ppo[key]["learn"])), (label, row[1])
        assert _agrees(row[2].replace("%", "").strip(), 100 * ppo[key]["env_share"]), label
        assert _agrees(row[3], ppo[key]["new_over_old"]), (label, row[3])


@pytest.mark.parametrize("setting", ["main", "eps1", "bound150", "em-to-serb"])
def test_sweep_learning_curve_figures_replot_from_the_committed_curves(setting, tmp_path):
    """`agent-envs tables --figures`: each paper-sweep learning-curve figure re-plotted from the
    committed per-run curves draws the points the sweep's report wrote
    (learning_curves_SETTING.csv), and writes a PNG."""
    import numpy as np
    import pandas as pd

    from agent_envs.training.commands.published import FIGURES

    (figure,) = [f for f in FIGURES if f.path.endswith(f"learning_curves_{setting}.png")]
    from agent_envs.training.commands.sweep_report import committed_learning_curves

    out = tmp_path / "curves.png"
    points = committed_learning_curves(
        *[ROOT / s for s in figure.sources], setting=setting, path=out
    )
    assert out.stat().st_size > 10_000
    report = pd.read_csv(ROOT / "docs/results/paper-sweep" / f"learning_curves_{setting}.csv")
    assert list(points["learner"]) == list(report["learner"])
    for column in ("swarm steps", "mean", "min", "max"):
        assert np.allclose(points[column], report[column], rtol=1e-12), column


def test_paper_sweep_file_lists_are_the_presets_trials():
    """published.py names the paper sweep's per-trial files by setting; they are exactly the
    paper preset's trials, so a learner or reference added to the preset fails here until its
    files are committed and the tables list them."""
    from agent_envs.training.commands.experiment import build_trials
    from agent_envs.training.commands.presets import get_preset
    from agent_envs.training.commands.published import _paper_sweep_files

    trials = {t.trial_id for t in build_trials(get_preset("paper"))}
    listed = {Path(f).stem for f in _paper_sweep_files(("main", "eps1", "bound150", "em-to-serb"))}
    assert listed == trials


def test_auto_threshold_sits_at_the_committed_crossover():
    """`AUTO_MATRIX_FREE_MIN_AGENTS[1]` (d = 1) is where the committed crossover run puts it:
    below it the dense step wins with one path, from it matrix-free wins with 20 paths."""
    from agent_envs.dynamics.operators import AUTO_MATRIX_FREE_MIN_AGENTS

    output = (ROOT / "docs/results/benchmarks/other/bench_large_swarms_crossover.txt").read_text()
    ratio = {
        (int(n), int(p)): float(r)
        for n, p, r in re.findall(r"(?m)^\| (\d+) \| (\d+) \|[^|]+\|[^|]+\| ([\d.]+) \|", output)
    }
    threshold = AUTO_MATRIX_FREE_MIN_AGENTS[1]
    assert f"(auto: matrix-free from N = {threshold} for d = 1)" in output
    below = max(n for n, _ in ratio if n < threshold)
    assert ratio[below, 1] < 1.0  # dense still wins below the threshold (one path)
    assert ratio[threshold, 20] > 1.0  # matrix-free wins from it (20 paths)
