"""The paper sweep's tables in docs/results.md, recomputed from its committed per-trial files.

Every trial of ``agent-envs sweep --preset paper`` writes one ``episodes.csv`` (a learner
run's ``runs/TRIAL/test_evaluation/``, a reference's ``references/SETTING/REF/``); the
committed copies are named by trial id, ``SETTING__POLICY__SEED.csv`` for a trained model and
``SETTING__REF.csv`` for a reference controller, all on the same test seeds (10000..10019).

Costs are the discrete cost functional (`eq:discrete_cost_functional`) of each test episode.
For a policy with training seeds s = 1..S and test episodes i, with V_i the open-loop optimum
on the same episode (`optimal`):

- mean cost: the mean of cost_{s,i} over every (s, i);
- gap to optimal: g_s = mean_i (cost_{s,i} - V_i) / V_i per training seed, quoted as the mean
  of the g_s with their range (min .. max) over seeds;
- IQM cost [95% CI] and P(cost < proportional): the across-seed statistics of the sweep report
  (`seed_statistics.across_seed_table`), a diverged episode counting as the worst score. The
  bootstrap's generator is seeded with 0 for each table, which draws for its own policies in
  its own order, so a CI can differ from the report's (``across_seeds.csv``) in its last digit.

A contrast setting whose references the sweep evaluates once with the main setting's (the
``em-to-serb`` learners are evaluated on the main env) names that setting in
``reference_setting``; its table then shows that setting's `BORROWED` references.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

#: the sweep's trial ids: SETTING__POLICY for a reference, SETTING__POLICY__SEED for a model
ID_SEPARATOR = "__"
#: the reference every gap is taken against, and the one P(cost < .) is quoted for
OPTIMUM = "optimal"
BASELINE = "proportional"
#: the references a setting evaluated on another setting's env shows of that setting: the
#: optimum, the proportional law and the centre law (the summary/common learners' fair baseline)
BORROWED = (OPTIMUM, BASELINE, "proportional-common")


@dataclass(frozen=True)
class PolicyRuns:
    """One policy of one setting: its (training seeds, test episodes) costs and diverged flags,
    the test seeds in the order of `seeds`."""

    setting: str
    policy: str
    training_seeds: tuple[int | None, ...]
    seeds: tuple[int, ...]
    costs: np.ndarray
    diverged: np.ndarray


def _trial_parts(path: Path) -> tuple[str, str, int | None]:
    """(setting, policy, training seed or None) from a committed file's trial-id name."""
    parts = path.stem.split(ID_SEPARATOR)
    if len(parts) == 2:
        return parts[0], parts[1], None
    if len(parts) == 3 and parts[2].isdigit():
        return parts[0], parts[1], int(parts[2])
    raise ValueError(
        f"{path.name}: a sweep trial file is named SETTING__POLICY.csv or SETTING__POLICY__SEED.csv"
    )


def read_runs(files: list[Path]) -> dict[tuple[str, str], PolicyRuns]:
    """{(setting, policy): PolicyRuns} from the per-trial files, training seeds in file order;
    every file must hold the same test seeds (in any order: rows are sorted by seed)."""
    grouped: dict[tuple[str, str], list[tuple[int | None, pd.DataFrame]]] = defaultdict(list)
    seeds: tuple[int, ...] | None = None
    for path in files:
        setting, policy, training_seed = _trial_parts(path)
        episodes = pd.read_csv(path).sort_values("seed")
        these = tuple(int(s) for s in episodes["seed"])
        if seeds is None:
            seeds = these
        elif these != seeds:
            raise ValueError(f"{path.name}: its test seeds differ from the other files'")
        grouped[setting, policy].append((training_seed, episodes))
    runs = {}
    for (setting, policy), parts in grouped.items():
        # a reference (no seed) is one file: with any other of its name, a clash
        if len(parts) > 1 and any(seed is None for seed, _ in parts):
            raise ValueError(
                f"{setting}__{policy}: a reference (no seed) and trained runs, or two "
                "reference files, share the name"
            )
        runs[setting, policy] = PolicyRuns(
            setting,
            policy,
            tuple(s for s, _ in parts),
            seeds or (),
            np.stack([e["total_cost"].to_numpy(float) for _, e in parts]),
            np.stack([e["diverged"].astype(bool).to_numpy() for _, e in parts]),
        )
    return runs


def seed_gaps(runs: PolicyRuns, optimum: PolicyRuns) -> np.ndarray:
    """(training seeds,) mean per-episode relative gap (cost - V) / V to the optimum."""
    values = optimum.costs[0]
    return ((runs.costs - values) / values).mean(axis=1)


def _percent(value: float) -> str:
    """A relative gap in percent: 3 significant digits from 1% up, 3 decimals from 0.01% to 1%
    (so 0.054% keeps two digits), scientific with 2 digits below 0.001%."""
    if abs(value) < 1e-5:
        return f"{100 * value:+.1e}%"
    if abs(value) >= 0.995:
        return f"{100 * value:+.0f}%"
    if abs(value) >= 0.0995:
        return f"{100 * value:+.1f}%"
    if abs(value) >= 0.00995:
        return f"{100 * value:+.2f}%"
    return f"{100 * value:+.3f}%"


def _gap_text(gaps: np.ndarray) -> str:
    if gaps.size == 1:
        return _percent(float(gaps[0]))
    return f"{_percent(float(gaps.mean()))} ({_percent(gaps.min())} .. {_percent(gaps.max())})"


def _setting_rows(
    runs: Mapping[tuple[str, str], PolicyRuns], setting: str, references_from: str
) -> list[dict[str, str]]:
    """The rows of one setting, by mean cost: its own policies, and the reference controllers
    of `references_from` (the setting itself, or the one whose env it is evaluated on)."""
    from agent_envs.training.results.seed_statistics import PolicyScores, across_seed_table

    own = {p: r for (s, p), r in runs.items() if s == setting}
    if references_from != setting:
        own.update({p: r for (s, p), r in runs.items() if s == references_from and p in BORROWED})
    if OPTIMUM not in own or BASELINE not in own:
        raise ValueError(f"setting {setting}: the files lack its {OPTIMUM} or {BASELINE} trial")
    scores = {p: PolicyScores(r.costs, r.diverged) for p, r in own.items()}
    stats = across_seed_table(scores, [BASELINE], np.random.default_rng(0)).set_index("policy")
    rows = []
    for policy, r in sorted(own.items(), key=lambda item: float(item[1].costs.mean())):
        row = stats.loc[policy]
        improvement = "-" if policy == BASELINE else f"{row[f'poi_vs_{BASELINE}']:.2f}"
        rows.append(
            {
                "policy": policy,
                "training seeds": str(len(r.training_seeds))
                if r.training_seeds[0] is not None
                else "-",
                "mean cost": f"{r.costs.mean():.4g}",
                "gap to optimal (seeds' range)": "0"
                if policy == OPTIMUM
                else _gap_text(seed_gaps(r, own[OPTIMUM])),
                "IQM cost [95% CI]": f"{row['iqm_cost']:.4g} [{row['iqm_cost_ci_low']:.4g}, "
                f"{row['iqm_cost_ci_high']:.4g}]",
                f"P(cost < {BASELINE})": improvement,
                "diverged": f"{int(r.diverged.sum())}/{r.diverged.size}",
            }
        )
    return rows


def _markdown(rows: list[dict[str, str]]) -> str:
    header = list(rows[0])
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row[k] for k in header) + " |" for row in rows]
    return "\n".join(lines)


def paper_sweep_table(*files: Path, setting: str = "main") -> str:
    """The table of one setting (its files among `files`), policies by mean cost."""
    return _markdown(_setting_rows(read_runs(list(files)), setting, setting))


def paper_sweep_contrasts(
    *files: Path, settings: tuple[str, ...], reference_setting: Mapping[str, str] | None = None
) -> str:
    """One table of the contrast `settings`, a ``setting`` column first; a setting named in
    `reference_setting` takes its reference controllers from that setting's files."""
    runs = read_runs(list(files))
    shared = dict(reference_setting or {})
    rows = []
    for setting in settings:
        rows += [
            {"setting": setting, **row}
            for row in _setting_rows(runs, setting, shared.get(setting, setting))
        ]
    return _markdown(rows)


__all__ = ["PolicyRuns", "paper_sweep_contrasts", "paper_sweep_table", "read_runs", "seed_gaps"]
