"""The report of a sweep: the trials' evaluations gathered per env setting, written with
`agent_envs.training.results.report.build_report` (the report of `agent-envs compare`).

Sections: the per-policy table and plots of `build_report` for the main (first) setting, one
row per trained model (``ppo (seed 0)``, ...) and per reference controller; the across-seed
statistics of every setting (`agent_envs.training.results.seed_statistics`: IQM with
stratified-bootstrap CIs, probability of improvement against the references, next to the
per-episode mean); the learning curves of every learner with a band over training seeds;
the training runs; the run (command, wall times).
"""

from __future__ import annotations

import json
import time
from collections import defaultdict
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from agent_envs.training.commands.experiment import LEARNER, Trial
from agent_envs.training.commands.presets import Preset, get_preset
from agent_envs.training.defaults import interface_of

#: references the probability of improvement is taken against, in this order, when present
IMPROVEMENT_REFERENCES = ("optimal", "mpc", "turnpike", "proportional", "zero")
#: references that get their own per-policy table (the gap to them), when present
GAP_REFERENCES = ("optimal", "mpc", "proportional")


def model_label(trial: Trial) -> str:
    """The policy name of one trained model in the per-policy table: ``{learner} (seed s)``."""
    return f"{trial.policy} (seed {trial.seed})" if trial.kind == LEARNER else trial.policy


def setting_results(trials: list[Trial], setting: str, out: Path):
    """The evaluations of one setting merged into one `EvaluationResults` (models renamed)."""
    from agent_envs.training.commands.experiment import evaluation_dir
    from agent_envs.training.results.tables import EvaluationResults, merge_results

    parts = []
    for trial in trials:
        if setting not in trial.settings:
            continue
        res = EvaluationResults.load(evaluation_dir(trial, out))
        label = model_label(trial)
        res.episodes = res.episodes.assign(policy=label)
        (arrays,) = res.trajectories.values()  # one policy per trial
        res.trajectories = {label: arrays}
        res.meta = {**res.meta, "policies": {label: res.meta.get("policies", {})}}
        parts.append(res)
    return merge_results(parts)


def policy_scores(trials: list[Trial], setting: str, out: Path) -> dict[str, Any]:
    """{learner or reference: PolicyScores (runs = training seeds, tasks = test seeds)}."""
    from agent_envs.training.commands.experiment import evaluation_dir
    from agent_envs.training.results.seed_statistics import PolicyScores
    from agent_envs.training.results.tables import EvaluationResults

    rows: dict[str, list[tuple[np.ndarray, np.ndarray]]] = defaultdict(list)
    for trial in trials:
        if setting not in trial.settings:
            continue
        episodes = EvaluationResults.load(evaluation_dir(trial, out)).episodes
        episodes = episodes.set_index("seed").loc[list(trial.test_seeds)]
        rows[trial.policy].append(_costs_and_divergence(episodes))
    return {
        name: PolicyScores(np.stack([c for c, _ in runs]), np.stack([d for _, d in runs]))
        for name, runs in rows.items()
    }


def _costs_and_divergence(episodes: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """One run's (test episodes,) total costs and diverged flags, in the frame's row order."""
    return episodes["total_cost"].to_numpy(float), episodes["diverged"].astype(bool).to_numpy()


def across_seed_markdown(*files: Path, bootstrap_seed: int = 0) -> str:
    """The report's across-seed table of one setting from its trials' ``episodes.csv`` files
    (a learner run's ``test_evaluation/`` or a reference's folder; one policy each, the test
    seeds in the same order in every file), given in the sweep's trial order: what
    `agent-envs tables` renders from the committed files (docs/sweep.md). The bootstrap's
    generator is seeded with `bootstrap_seed` as the report's is, so the intervals are the
    report's digit for digit when the setting is the sweep's first."""
    from agent_envs.training.results.report import markdown_table
    from agent_envs.training.results.seed_statistics import (
        PolicyScores,
        across_seed_table,
        display_across_seed_table,
    )

    rows: dict[str, list[tuple[np.ndarray, np.ndarray]]] = defaultdict(list)
    for path in files:
        episodes = pd.read_csv(path)
        (policy,) = episodes["policy"].unique()
        rows[policy].append(_costs_and_divergence(episodes))
    scores = {
        name: PolicyScores(np.stack([c for c, _ in runs]), np.stack([d for _, d in runs]))
        for name, runs in rows.items()
    }
    refs = [r for r in IMPROVEMENT_REFERENCES if r in scores]
    table = across_seed_table(scores, refs, np.random.default_rng(bootstrap_seed))
    return markdown_table(display_across_seed_table(table, refs))


#: references the training callback does not log on the validation seeds (too costly to run at
#: every evaluation): the learning curves show their mean cost on the test seeds instead
TEST_SEED_LINES = ("optimal", "mpc")


def _add_curve(
    curves: dict[str, list[tuple[np.ndarray, np.ndarray]]],
    references: dict[str, float],
    learner: str,
    rows: list[dict[str, Any]],
    per_step: int,
) -> None:
    """Add one run's learning curve (its rows; timesteps / `per_step` = swarm steps) to
    `learner`'s curves, and its last row's reference costs on the validation seeds."""
    steps = np.array([r["timesteps"] for r in rows], float) / per_step
    curves[learner].append((steps, np.array([r["cost_mean"] for r in rows], float)))
    for name in IMPROVEMENT_REFERENCES:
        if f"{name}_cost" in rows[-1]:
            references[name] = float(rows[-1][f"{name}_cost"])


def plot_learning_curve_bands(
    trials: list[Trial],
    out: Path,
    setting: str,
    path: Path,
    test_references: dict[str, float] | None = None,
) -> pd.DataFrame | None:
    """Validation cost against swarm steps per learner: mean over training seeds (line) and the
    range over seeds (band); the reference controllers on the same validation seeds as black
    lines, and `test_references` (name -> mean cost on the test seeds; the optimal control and
    MPC) as grey lines. Returns the plotted points, or None when no run logged a curve."""

    from agent_envs.training.commands.experiment import learner_run_dir
    from agent_envs.training.defaults import is_multiagent
    from agent_envs.training.learners.callbacks import read_learning_curve

    curves: dict[str, list[tuple[np.ndarray, np.ndarray]]] = defaultdict(list)
    references: dict[str, float] = {}
    for trial in trials:
        if trial.kind != LEARNER or trial.setting != setting:
            continue
        run_dir = learner_run_dir(trial, out)
        rows = read_learning_curve(run_dir / "learning_curve.csv")
        if not rows:
            continue
        n_agents = json.loads((run_dir / "env.json").read_text())["n_agents"]
        per_step = n_agents if is_multiagent(trial.train["env_id"]) else 1
        _add_curve(curves, references, trial.policy, rows, per_step)
    if not curves:
        return None
    return _plot_curve_bands(curves, references, test_references, setting, path)


def _plot_curve_bands(
    curves: Mapping[str, list[tuple[np.ndarray, np.ndarray]]],
    references: Mapping[str, float],
    test_references: Mapping[str, float] | None,
    setting: str,
    path: Path,
) -> pd.DataFrame:
    """The figure of `plot_learning_curve_bands` from its curves: {learner: [(swarm steps,
    validation costs) per training seed]}, the references on the validation seeds and on the
    test seeds; returns the plotted points."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 4.5))
    ax = fig.subplots()
    points = []
    for i, (name, runs) in enumerate(curves.items()):
        # the runs share the evaluation schedule; cut to the shortest (an unfinished run)
        k = min(len(s) for s, _ in runs)
        steps = runs[0][0][:k]
        costs = np.stack([c[:k] for _, c in runs])
        mean = costs.mean(axis=0)
        ax.plot(steps, mean, "o-", ms=3, color=f"C{i}", label=f"{name} ({len(runs)} seeds)")
        ax.fill_between(steps, costs.min(axis=0), costs.max(axis=0), color=f"C{i}", alpha=0.2)
        for s, m, lo, hi in zip(steps, mean, costs.min(axis=0), costs.max(axis=0), strict=True):
            points.append({"learner": name, "swarm steps": s, "mean": m, "min": lo, "max": hi})
    styles = {"turnpike": "--", "proportional": "-.", "zero": ":", "optimal": "-", "mpc": "-"}
    for name, value in references.items():
        ax.axhline(value, ls=styles.get(name, "-"), color="k", lw=1, label=name)
    for name, value in (test_references or {}).items():
        ax.axhline(value, ls=styles.get(name, "-"), color="0.5", lw=1.5, label=f"{name} (test)")
    ax.set_yscale("log")
    ax.set_xlabel("swarm steps (env transitions)")
    ax.set_ylabel("validation cost (mean over validation seeds)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(
        f"Learning curves, setting {setting}: mean over training seeds, band min-max", fontsize=10
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return pd.DataFrame(points)


def committed_learning_curves(*files: Path, setting: str, path: Path) -> pd.DataFrame:
    """Re-plot a setting's learning-curve figure from the committed files of a paper sweep:
    each learner run's curve ``curves/SETTING__LEARNER__SEED.csv`` and the optimum's and MPC's
    per-episode files ``episodes/SETTING__REF.csv`` (their mean cost on the test seeds, the grey
    lines). Swarm steps divide a parameter-shared learner's agent-steps by N, as the sweep does
    (the learners' env ids and N from the paper preset)."""
    from agent_envs.training.defaults import is_multiagent
    from agent_envs.training.learners.callbacks import read_learning_curve

    preset = get_preset("paper")
    env_ids = {learner.name: learner.env_id for learner in preset.learners}
    n_agents = int(preset.env_kwargs["n_agents"])
    curves: dict[str, list[tuple[np.ndarray, np.ndarray]]] = defaultdict(list)
    references: dict[str, float] = {}
    tests: dict[str, float] = {}
    for file in files:
        parts = file.stem.split("__")
        if file.parent.name == "episodes":
            if parts[1] in TEST_SEED_LINES:
                tests[parts[1]] = float(pd.read_csv(file)["total_cost"].mean())
            continue
        if parts[0] != setting:
            continue
        rows = read_learning_curve(file)
        per_step = n_agents if is_multiagent(env_ids[parts[1]]) else 1
        _add_curve(curves, references, parts[1], rows, per_step)
    if not curves:
        raise ValueError(f"no learning curve of setting {setting} among the files")
    return _plot_curve_bands(curves, references, tests, setting, path)


def _env_options(trial: Trial) -> str:
    """The learner's interface options (`agent_envs.envs.interface`) that differ from the
    defaults, as "observation=summary, action_basis=common" ("-" for none)."""
    kwargs = (trial.train or {}).get("env_kwargs", {})
    changed = {k: v for k, v in interface_of(kwargs).items() if k in kwargs}
    return ", ".join(f"{k}={v}" for k, v in changed.items()) or "-"


def rising_evaluations(curve: list[dict[str, Any]], factor: float = 2.0) -> int:
    """How many validations cost more than `factor` times the first one (a learner that gets
    worse as it trains)."""
    if not curve:
        return 0
    first = curve[0]["cost_mean"]
    return sum(1 for row in curve[1:] if row["cost_mean"] > factor * first)


def training_table(trials: list[Trial], out: Path) -> pd.DataFrame:
    """One row per learner trial: env options, budget, wall time, best validation cost, and
    the validations above twice the first."""
    from agent_envs.training.commands.experiment import learner_run_dir
    from agent_envs.training.learners.callbacks import read_learning_curve

    rows = []
    for trial in trials:
        if trial.kind != LEARNER:
            continue
        run_dir = learner_run_dir(trial, out)
        summary = json.loads((run_dir / "summary.json").read_text())
        curve = read_learning_curve(run_dir / "learning_curve.csv")
        best = min(curve, key=lambda r: r["cost_mean"]) if curve else None
        rows.append(
            {
                "setting": trial.setting,
                "learner": trial.policy,
                "seed": trial.seed,
                "env options": _env_options(trial),
                "training timesteps": summary["timesteps"],
                "swarm steps": summary["swarm_steps"],
                "training wall time [s]": summary["train_wall_time_s"],
                "best validation cost": None if best is None else round(best["cost_mean"], 4),
                "validations > 2x the first": rising_evaluations(curve),
                "run": run_dir.name,
            }
        )
    return pd.DataFrame(rows)


def trial_time_table(
    trials: list[Trial], trial_times: Mapping[str, float], nodes: Mapping[str, str] | None = None
) -> pd.DataFrame:
    """One row per trial with the wall time Tune recorded for it (train + held-out evaluation
    for a learner; the evaluation for a reference), trials in grid order; with `nodes` (trial
    id -> Ray node id), the first 8 hex digits of the node each trial ran on."""
    rows = []
    for t in trials:
        if t.trial_id not in trial_times:
            continue
        row = {
            "trial": t.trial_id,
            "kind": t.kind,
            "setting": t.setting,
            "policy": t.policy,
            "seed": "" if t.seed is None else t.seed,
            "wall time [s]": round(trial_times[t.trial_id], 1),
        }
        if nodes:
            row["node"] = str(nodes.get(t.trial_id, ""))[:8]
        rows.append(row)
    return pd.DataFrame(rows)


#: What the across-seed table shows (the text of its section).
ACROSS_SEED_TEXT = (
    "Scores for rliable are the negative "
    "costs (a diverged episode scores -inf, i.e. it costs more than any finished one); "
    "the table shows the IQM of the cost (the 25% trimmed mean over training seeds x "
    "test episodes, lower is better) with a 95% stratified-bootstrap CI (training "
    "seeds resampled within each test episode; a reference controller is one run, so "
    "its interval has zero width), and P(cost < ref): the probability that a random "
    "training seed of the policy costs less than the reference on a random test "
    "episode (ties count one half), with its bootstrap CI. 'mean cost' is the "
    "per-episode mean over finished episodes, as in the per-policy table."
)
#: What the learning-curve bands show.
CURVES_TEXT = (
    "Validation cost (mean over the validation seeds 1000..1000+k) during "
    "training: the line is the mean over training seeds, the band their "
    "range (min to max). Black lines: the reference controllers on the same "
    "validation seeds (turnpike dashed, proportional dash-dotted, zero "
    "dotted); grey lines: the optimal control and MPC, when present, by "
    "their mean cost on the test seeds (not run during training). Swarm "
    "steps are env transitions (the parameter-shared learner gets N agent "
    "samples per swarm step)."
)


def _contrast_section(trials: list[Trial], setting: Any, out: Path):
    """The per-policy table of a contrast setting, against its optimum where it has one."""
    from agent_envs.training.results.report import ReportSection, display_table
    from agent_envs.training.results.tables import summarize

    results = setting_results(trials, setting.name, out)
    # the gap to the optimum where the setting has it (else the turnpike controller)
    ref = next((r for r in GAP_REFERENCES if r in results.policies), "turnpike")
    return ReportSection(
        f"Setting {setting.name}: per trained model",
        text=f"{setting.description}; evaluation env kwargs "
        f"{results.meta.get('env_kwargs')}. Ratios and gaps against {ref}.",
        table=display_table(summarize(results.episodes, ref), ref),
    )


def _curves_section(trials, out: Path, setting: Any, scores, report_dir: Path):
    """The learning-curve bands of one setting (also written as CSV), or None without curves."""
    from agent_envs.training.results.report import ReportSection

    curves_png = report_dir / f"learning_curves_{setting.name}.png"
    test_lines = {
        name: float(data.costs[~data.diverged].mean())
        for name, data in scores.items()
        if name in TEST_SEED_LINES and (~data.diverged).any()
    }
    points = plot_learning_curve_bands(trials, out, setting.name, curves_png, test_lines)
    if points is None:
        return None
    points.to_csv(report_dir / f"learning_curves_{setting.name}.csv", index=False)
    return ReportSection(
        f"Learning curves, setting {setting.name}",
        text=CURVES_TEXT,
        images=[curves_png],
        captions=[f"learning curves, setting {setting.name}"],
    )


def _setting_sections(trials, out: Path, settings: list, report_dir: Path, rng):
    """The sections of every setting (contrast table, across-seed statistics, curves) and the
    across-seed tables, which are also written to ``across_seeds.csv``."""
    from agent_envs.training.results.report import ReportSection
    from agent_envs.training.results.seed_statistics import (
        across_seed_table,
        display_across_seed_table,
    )

    sections = []
    stats_tables = []
    for setting in settings:
        scores = policy_scores(trials, setting.name, out)
        refs = [r for r in IMPROVEMENT_REFERENCES if r in scores]
        table = across_seed_table(scores, refs, rng)
        table.insert(0, "setting", setting.name)
        stats_tables.append(table)
        if setting is not settings[0]:
            sections.append(_contrast_section(trials, setting, out))
        sections.append(
            ReportSection(
                f"Across training seeds, setting {setting.name}",
                text=f"Setting {setting.name}: {setting.description}. {ACROSS_SEED_TEXT}",
                table=display_across_seed_table(table, refs),
            )
        )
        curves = _curves_section(trials, out, setting, scores, report_dir)
        if curves is not None:
            sections.append(curves)
    pd.concat(stats_tables, ignore_index=True).to_csv(report_dir / "across_seeds.csv", index=False)
    return sections


def _time_section(trials, trial_times: Mapping[str, float], nodes, report_dir: Path):
    from agent_envs.training.results.report import ReportSection

    times = trial_time_table(trials, trial_times, nodes)
    times.to_csv(report_dir / "trial_wall_times.csv", index=False)
    return ReportSection(
        "Wall time per trial",
        text=(
            "As Tune recorded it: a learner trial's training and held-out evaluation, "
            "a reference trial's evaluation. Trials run side by side, one per "
            "--cpus-per-trial CPUs of the Ray instance, so they share the machine; 'node' is "
            "the Ray node a trial ran on (the first 8 digits of its id)."
        ),
        table=times,
    )


def _run_section(preset: Preset, timing: dict[str, float], command: str):
    from agent_envs.training.commands.experiment import available_references
    from agent_envs.training.results.report import ReportSection

    _, lacking = available_references(preset)
    sources = [
        f"Preset {preset.name}: {preset.description}.",
        f"Reference controllers: {', '.join(r for r in preset.references if r not in lacking)}"
        + (
            f" ({', '.join(lacking)} wanted by the preset but not in this install's "
            "agent_envs.baselines.BASELINES, so left out)."
            if lacking
            else "."
        ),
    ]
    if preset.hyperparams_source:
        sources.append(f"Hyperparameters: {preset.hyperparams_source}")
    sources.append(
        f"Wall time: ray.init {timing.get('ray_init_s', float('nan')):.0f} s, Tune "
        f"{timing.get('tune_s', float('nan')):.0f} s (all trials), report written "
        f"{time.strftime('%Y-%m-%d %H:%M:%S')}."
    )
    return ReportSection("Run", text="\n\n".join(sources), code=command)


def _gap_sections(main: Any, main_results) -> list:
    """The main setting's per-policy table against each optimum / yardstick it has."""
    from agent_envs.training.results.report import ReportSection, display_table
    from agent_envs.training.results.tables import summarize

    return [
        ReportSection(
            f"Gap to {name}, setting {main.name}",
            text=(
                f"The per-policy table with {name} as the reference: 'ratio to {name}' divides "
                f"mean costs, the paired ratio (with its 95% t-interval) averages the per-seed "
                f"ratios cost / {name} cost on the same test episodes; the gap is ratio - 1."
            ),
            table=display_table(summarize(main_results.episodes, name), name),
        )
        for name in GAP_REFERENCES
        if name in main_results.policies
    ]


def write_sweep_report(
    config: Any,
    trials: list[Trial],
    out: Path,
    timing: dict[str, float],
    command: str,
    trial_times: Mapping[str, float] | None = None,
    nodes: Mapping[str, str] | None = None,
) -> dict[str, Path]:
    """Write OUT/report/report.md and .html (and the tables as CSV); returns the paths.

    `command` is the command line that started the sweep (a resumed sweep shows it too);
    `trial_times` the wall time of each trial by trial id (Tune's `trial_wall_time_s`),
    `nodes` the Ray node each ran on.
    """
    from agent_envs.training.results.report import ReportSection, build_report

    preset = get_preset(config.preset)
    report_dir = out / "report"
    report_dir.mkdir(parents=True, exist_ok=True)
    settings = [s for s in preset.settings if any(s.name in t.settings for t in trials)]
    rng = np.random.default_rng(config.bootstrap_seed)
    sections = _setting_sections(trials, out, settings, report_dir, rng)
    sections.append(ReportSection("Training runs", table=training_table(trials, out)))
    if trial_times:
        sections.append(_time_section(trials, trial_times, nodes, report_dir))
    sections.append(_run_section(preset, timing, command))
    main = settings[0]
    main_results = setting_results(trials, main.name, out)
    return build_report(
        main_results,
        report_dir,
        title=f"Sweep {preset.name}: learned policies vs the reference controllers "
        f"(setting {main.name})",
        extra_sections=[*_gap_sections(main, main_results), *sections],
        command=command,
    )
