"""`agent-envs tables`: every published result table, re-rendered from its committed files.

    agent-envs tables            # rewrite every stale marked table of README.md and docs/
    agent-envs tables --check    # exit 1 naming each stale table; write nothing
    agent-envs tables --figures  # also re-plot the figures drawn from committed files

A published table is a block of a page between the markers ``<!-- NAME:start -->`` and
``<!-- NAME:end -->`` whose body is `render(files)`: a function that reads committed files under
``docs/results/`` (or the tasks' shipped references) and formats them; nothing trains or
simulates, so the whole command takes seconds. `PUBLISHED` lists them all (the inventory of
docs/development.md, "Published tables and their files", names the tables that have no file
behind them). A table is stale when the page's block, stripped of surrounding blank lines,
differs from the render by a single character.
"""

from __future__ import annotations

import importlib
import json
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from agent_envs.training.config import option_field
from agent_envs.training.results.benchmark_figures import benchmark_files

#: the results folder, relative to the repository root
RESULTS = "docs/results"
#: the quick preset's per-episode files, one per training seed
QUICK_FILES = tuple(f"{RESULTS}/quick/seed{s}/episodes.csv" for s in range(3))
#: the quick preset's EM-trained runs, evaluated on EM and on SERB, per training seed
EM_TO_SERB_FILES = tuple(
    f"{RESULTS}/em-to-serb/seed{s}/{integrator}/episodes.csv"
    for s in range(3)
    for integrator in ("em", "serb")
)


#: a table's render function: its source files (resolved under the root, in `sources` order)
#: -> the Markdown table
Render = Callable[[list[Path]], str]


@dataclass(frozen=True)
class PublishedTable:
    """One marked table: `marker` on `page` (relative to the repository root) is `render` of
    the files `sources` (relative paths; the command checks they exist and hands them to
    `render`, so the files named are the files read)."""

    marker: str
    page: str
    sources: tuple[str, ...]
    render: Render
    #: per-episode files the summary in `sources` aggregates; `render` gets them after the
    #: sources and recomputes the table from them when they exist (until a rerun commits
    #: them, the summary renders: `check_sources` does not require them)
    per_episode: tuple[str, ...] = ()

    @property
    def name(self) -> str:
        """``page#marker``: how the check names a stale table."""
        return f"{self.page}#{self.marker}"

    def rendered(self, root: Path) -> str:
        """The table from the files under `root` (`sources`, then `per_episode`)."""
        return self.render([root / source for source in (*self.sources, *self.per_episode)])


# ------------------------------------------------------------------------------- renderers


def _renderer(module: str, function: str, **options: Any) -> Render:
    """``agent_envs.training.MODULE.FUNCTION(*files, **options)``, imported when it renders
    (the leaderboard's and the cheap-control experiment's imports are not free)."""

    def render(files: list[Path]) -> str:
        found = importlib.import_module(f"agent_envs.training.{module}")
        return getattr(found, function)(*files, **options)

    return render


def _leaderboard(tasks: list[str] | None) -> Render:
    def render(files: list[Path]) -> str:
        from agent_envs.training.commands.leaderboard import leaderboard_table, read_episodes

        return leaderboard_table(read_episodes(files[0]), tasks=tasks)

    return render


def _quick(files: list[Path]) -> str:
    from agent_envs.training.commands.seed_table import seed_table_markdown

    return seed_table_markdown("quick", files)


def _task_references(files: list[Path]) -> str:
    """The tasks' reference table, from the shipped data of the installed package (`files`:
    its hash list, whose change means new data)."""
    from agent_envs.training.commands.task_evaluation import reference_table_markdown

    return reference_table_markdown()


def _task_design(files: list[Path]) -> str:
    from agent_envs.training.results.committed_tables import design_table

    return design_table(json.loads(files[0].read_text()))


def _cheap_control(selection: bool) -> Render:
    def render(files: list[Path]) -> str:
        from agent_envs.training.experiments import cheap_control_bound as bound

        rows = bound.read_rows(files[0])
        return bound.selected_table(rows) if selection else bound.markdown(rows, bound.SUMMARY)

    return render


def _contraction(files: list[Path]) -> str:
    from agent_envs.training.experiments import cheap_control_bound as bound

    return bound.markdown(bound.read_rows(files[0]), bound.CONTRACTION_COLUMNS)


#: docs/evaluate.md's three evaluations: (env label, episodes file)
EVALUATIONS = (
    ("SERB, 1 path", f"{RESULTS}/evaluate/serb/episodes.csv"),
    ("EM, 1 path", f"{RESULTS}/evaluate/em/episodes.csv"),
    ("SERB, 20 paths", f"{RESULTS}/evaluate/serb20/episodes.csv"),
)


def _evaluations(files: list[Path]) -> str:
    from agent_envs.training.results.command_tables import evaluation_table

    labels = [label for label, _ in EVALUATIONS]
    return evaluation_table(list(zip(labels, files, strict=True)))


def _shared_design(files: list[Path]) -> str:
    """The parameter-shared learners' design runs (runs.csv) against the optimum measured in
    the env-options folder (files[1:]: its two results files)."""
    from agent_envs.training.results.design_runs import design_table

    return design_table(files[0], files[1].parent)


_BENCHMARK = "results.committed_tables"
_COMMAND = "results.command_tables"
_LEADERBOARD = (f"{RESULTS}/leaderboard/episodes.csv",)
_APG = (f"{RESULTS}/apg/results.json",)
#: bench_apg.py's per-episode file beside it (`apg_episodes`)
_APG_EPISODES = (f"{RESULTS}/apg/episodes.csv",)
_CHEAP_CONTROL = (f"{RESULTS}/cheap-control-bound/cheap_control_bound.csv",)


def _env_options_episodes(stem: str) -> tuple[str, str]:
    """``benchmarks/env_options.py --out env-options/STEM.json``'s per-episode and per-step
    files (`env_options_episodes.episode_files`)."""
    return (f"{RESULTS}/env-options/{stem}_episodes.csv", f"{RESULTS}/env-options/{stem}_steps.csv")


#: the smoke sweep's per-episode files, in the sweep's trial order (learner runs, references):
#: OUT/runs/main__ppo__{seed}/test_evaluation/ and OUT/references/main/{ref}/ of the sweep
_SMOKE_SWEEP = tuple(
    f"{RESULTS}/smoke-sweep/{run}/episodes.csv"
    for run in ("ppo-seed0", "ppo-seed1", "turnpike", "proportional", "zero")
)

#: the paper sweep's trials (`agent-envs sweep --preset paper`) by setting: its learners,
#: trained on seeds 0, 1, 2, and its reference controllers (em-to-serb's learners are
#: evaluated on the main env, whose references the sweep runs once, for both settings)
_PAPER_LEARNERS = {
    "main": ("ppo", "ppo-modes", "sac", "td3", "ppo-shared", "ppo-local", "apg"),
    "eps1": ("ppo", "sac", "ppo-shared", "ppo-local", "apg"),
    "bound150": ("ppo",),
    "em-to-serb": ("ppo", "sac", "apg"),
}
_PAPER_REFERENCES = {
    "main": ("optimal", "mpc", "turnpike", "proportional", "zero", "proportional-common"),
    "eps1": ("optimal", "turnpike", "proportional", "zero", "proportional-common"),
    "bound150": ("optimal", "turnpike", "proportional", "zero", "proportional-common"),
    "em-to-serb": (),
}


def _paper_sweep_files(settings: tuple[str, ...]) -> tuple[str, ...]:
    """The committed per-trial episode files of `settings`, named by trial id
    (``docs/results/paper-sweep/episodes/TRIAL.csv``: a learner run's ``test_evaluation/``
    or a reference's folder of the sweep's output)."""
    trials = [
        f"{setting}__{learner}__{seed}"
        for setting in settings
        for learner in _PAPER_LEARNERS[setting]
        for seed in range(3)
    ] + [f"{setting}__{ref}" for setting in settings for ref in _PAPER_REFERENCES[setting]]
    return tuple(f"{RESULTS}/paper-sweep/episodes/{trial}.csv" for trial in trials)


#: docs/tune.md's unshipped searches: each search's trials and summary, then the hand-chosen
#: entry's training-seed-0 run of the paper sweep (its learning curve, same validation seeds)
_TUNE_SEARCHES = tuple(
    path
    for learner in ("ppo", "td3", "sac")
    for path in (
        f"{RESULTS}/tune-paper-{learner}/trials.csv",
        f"{RESULTS}/tune-paper-{learner}/tune_summary.md",
        f"{RESULTS}/paper-sweep/curves/main__{learner}__0.csv",
    )
)

#: docs/benchmarks.md's current figures: three runs of each benchmark script's printed output
#: (`benchmark_figures.SCRIPTS`), run by run
_BENCHMARK_OUTPUTS = benchmark_files(f"{RESULTS}/benchmarks")
_TIMINGS = "results.benchmark_figures"


def _printed(
    marker: str, page: str, script: str, index: int | None = 0, folder: str = "other"
) -> PublishedTable:
    """A section quoting one committed run of a benchmark script
    (``docs/results/benchmarks/FOLDER/SCRIPT.txt``): its `index`-th printed table verbatim, or
    with ``index=None`` its whole output (a script that prints lines, not a table)."""
    sources = (f"{RESULTS}/benchmarks/{folder}/{script}.txt",)
    if index is None:
        return PublishedTable(marker, page, sources, _renderer(_TIMINGS, "printed_text"))
    return PublishedTable(marker, page, sources, _renderer(_TIMINGS, "printed_table", index=index))


#: every published table that `agent-envs tables` owns, in page order
PUBLISHED: tuple[PublishedTable, ...] = (
    PublishedTable(
        "leaderboard-table", "README.md", _LEADERBOARD, _leaderboard(["agent_envs/StiffSwarm-v0"])
    ),
    PublishedTable("leaderboard-table", "docs/leaderboard.md", _LEADERBOARD, _leaderboard(None)),
    PublishedTable("quick-table", "docs/results.md", QUICK_FILES, _quick),
    PublishedTable(
        "paper-sweep-table",
        "docs/results.md",
        _paper_sweep_files(("main",)),
        _renderer("results.paper_sweep", "paper_sweep_table"),
    ),
    PublishedTable(
        "paper-sweep-contrasts",
        "docs/results.md",
        _paper_sweep_files(("main", "eps1", "bound150", "em-to-serb")),
        _renderer(
            "results.paper_sweep",
            "paper_sweep_contrasts",
            settings=("eps1", "bound150", "em-to-serb"),
            reference_setting={"em-to-serb": "main"},
        ),
    ),
    PublishedTable(
        "em-transfer-table",
        "docs/results.md",
        (*EM_TO_SERB_FILES, *QUICK_FILES),
        _renderer(_COMMAND, "em_transfer_table"),
    ),
    PublishedTable(
        "shared-transfer-table",
        "docs/learners/shared.md",
        (f"{RESULTS}/shared-across-n/issue41/across_n.csv",),
        _renderer(_BENCHMARK, "shared_transfer_table"),
    ),
    PublishedTable(
        "apg-paper-table",
        "docs/learners/apg.md",
        _APG,
        _renderer(_BENCHMARK, "apg_paper_table"),
        _APG_EPISODES,
    ),
    PublishedTable(
        "apg-quick-table",
        "docs/learners/apg.md",
        _APG,
        _renderer(_BENCHMARK, "apg_quick_table"),
        _APG_EPISODES,
    ),
    PublishedTable(
        "apg-across-n-table",
        "docs/learners/apg.md",
        _APG,
        _renderer(_BENCHMARK, "apg_across_n_table"),
        _APG_EPISODES,
    ),
    PublishedTable(
        "apg-contrasts-table",
        "docs/learners/apg.md",
        _APG,
        _renderer(_BENCHMARK, "apg_contrasts_table"),
        _APG_EPISODES,
    ),
    PublishedTable(
        "shared-design-table",
        "docs/learners/shared.md",
        (
            f"{RESULTS}/shared-design/runs.csv",
            f"{RESULTS}/env-options/results.json",
            f"{RESULTS}/env-options/results_eps1.json",
        ),
        _shared_design,
    ),
    PublishedTable(
        "quick-design-table",
        "docs/presets.md",
        tuple(
            f"{RESULTS}/quick-design/{name}"
            for name in ("runs.csv", "references.csv", "variants.json")
        ),
        _renderer("results.quick_design", "quick_design_table"),
    ),
    PublishedTable(
        "reference-table", "docs/tasks.md", ("agent_envs/tasks/data/SHA256SUMS",), _task_references
    ),
    PublishedTable("design-table", "docs/tasks.md", (f"{RESULTS}/task-design.json",), _task_design),
    PublishedTable(
        "uncontrolled-table",
        "docs/paper.md",
        (f"{RESULTS}/uncontrolled/results.csv",),
        _renderer("experiments.uncontrolled", "csv_table"),
    ),
    PublishedTable(
        "turnpike-table",
        "docs/paper.md",
        (f"{RESULTS}/turnpike/results.csv",),
        _renderer(_COMMAND, "turnpike_table"),
    ),
    PublishedTable(
        "cheap-control-table",
        "docs/cheap-control-bound.md",
        _CHEAP_CONTROL,
        _cheap_control(selection=False),
    ),
    PublishedTable(
        "contraction-table",
        "docs/cheap-control-bound.md",
        (f"{RESULTS}/cheap-control-bound/contraction.csv",),
        _contraction,
    ),
    PublishedTable(
        "turnpike-property-table",
        "docs/turnpike-theory.md",
        (f"{RESULTS}/turnpike-property/turnpike_property.csv",),
        _renderer(_COMMAND, "turnpike_property_table"),
    ),
    PublishedTable(
        "cheap-control-selection",
        "docs/turnpike-theory.md",
        _CHEAP_CONTROL,
        _cheap_control(selection=True),
    ),
    PublishedTable(
        "evaluation-table",
        "docs/evaluate.md",
        tuple(path for _, path in EVALUATIONS),
        _evaluations,
    ),
    PublishedTable(
        "mean-field-table",
        "docs/large-swarms.md",
        (f"{RESULTS}/large-swarms/mean_field.csv",),
        _renderer(_BENCHMARK, "mean_field_table"),
    ),
    PublishedTable(
        "optimum-table",
        "docs/optimum.md",
        (f"{RESULTS}/evaluate/quick-optimum/episodes.csv",),
        _renderer(_COMMAND, "optimum_table"),
    ),
    PublishedTable(
        "smoke-sweep-table",
        "docs/sweep.md",
        _SMOKE_SWEEP,
        _renderer("commands.sweep_report", "across_seed_markdown"),
    ),
    PublishedTable(
        "tune-search-table",
        "docs/tune.md",
        _TUNE_SEARCHES,
        _renderer("results.tune_tables", "tune_search_table"),
    ),
    PublishedTable(
        "benchmark-figures-table",
        "docs/benchmarks.md",
        _BENCHMARK_OUTPUTS,
        _renderer(_TIMINGS, "benchmark_figures_table"),
    ),
    _printed("scoring-overhead-table", "docs/benchmarks.md", "bench_scoring"),
    _printed("integrators-phi-table", "docs/benchmarks.md", "bench_integrators"),
    _printed("integrators-step-table", "docs/benchmarks.md", "bench_integrators", 1),
    _printed("integrators-accuracy-100-table", "docs/benchmarks.md", "bench_integrators", 2),
    _printed("integrators-accuracy-1000-table", "docs/benchmarks.md", "bench_integrators", 3),
    _printed("gradient-cost-table", "docs/benchmarks.md", "bench_gradient"),
    _printed("vector-env-rates-table", "docs/benchmarks.md", "bench_vector_env", folder="run1"),
    _printed("env-step-output", "docs/benchmarks.md", "bench_env_step", None),
    _printed("blas-threads-table", "docs/benchmarks.md", "bench_blas_threads"),
    _printed("optimal-solver-output", "docs/benchmarks.md", "bench_optimal", None),
    _printed("large-swarms-step-table", "docs/large-swarms.md", "bench_large_swarms"),
    _printed(
        "large-swarms-crossover-table", "docs/large-swarms.md", "bench_large_swarms_crossover"
    ),
    _printed("large-swarms-d2-table", "docs/large-swarms.md", "bench_large_swarms", 2),
    PublishedTable(
        "convergence-orders-table",
        "docs/core.md",
        (f"{RESULTS}/convergence-orders/convergence_orders.txt",),
        _renderer(_BENCHMARK, "convergence_orders_table"),
    ),
    PublishedTable(
        "env-options-table",
        "docs/env-options.md",
        (f"{RESULTS}/env-options/results.json",),
        _renderer(_BENCHMARK, "env_options_table", first_cell="figure", r2=True),
        _env_options_episodes("results"),
    ),
    PublishedTable(
        "env-options-eps1-table",
        "docs/env-options.md",
        (f"{RESULTS}/env-options/results_eps1.json",),
        _renderer(_BENCHMARK, "env_options_table", first_cell="figure, eps = 1", r2=False),
        _env_options_episodes("results_eps1"),
    ),
    PublishedTable(
        "max-control-table",
        "docs/envs/gymnasium.md",
        (f"{RESULTS}/max-control/max_control.txt",),
        _renderer(_BENCHMARK, "max_control_table"),
        (f"{RESULTS}/max-control/episodes.csv",),
    ),
)


# ------------------------------------------------------------------------------ figures

#: a figure's plot function: (its source files, the PNG path to write) -> None
Plot = Callable[[list[Path], Path], None]


@dataclass(frozen=True)
class PublishedFigure:
    """One figure of the docs re-plotted from committed files: `path` (relative to the root)
    is `plot(sources, path)`. A PNG's bytes depend on matplotlib's version and fonts, so
    figures are rewritten by ``agent-envs tables --figures``, not compared by ``--check``."""

    path: str
    sources: tuple[str, ...]
    plot: Plot

    def write(self, root: Path) -> None:
        self.plot([root / source for source in self.sources], root / self.path)


def _sweep_curves_figure(setting: str) -> Plot:
    def plot(files: list[Path], path: Path) -> None:
        from agent_envs.training.commands.sweep_report import committed_learning_curves

        committed_learning_curves(*files, setting=setting, path=path)

    return plot


def _sweep_curve_files(setting: str) -> tuple[str, ...]:
    """A setting's committed learning curves and the optimum's (and MPC's) episodes of the
    env it is evaluated on (the main env for em-to-serb)."""
    env_setting = "main" if setting == "em-to-serb" else setting
    tests = [r for r in ("optimal", "mpc") if r in _PAPER_REFERENCES[env_setting]]
    return (
        *(
            f"{RESULTS}/paper-sweep/curves/{setting}__{learner}__{seed}.csv"
            for learner in _PAPER_LEARNERS[setting]
            for seed in range(3)
        ),
        *(f"{RESULTS}/paper-sweep/episodes/{env_setting}__{ref}.csv" for ref in tests),
    )


#: every figure `agent-envs tables --figures` re-plots from committed files. The other figures
#: need what no committed file holds: the cheap-control bound's Lyapunov series per step, the
#: large swarms' positions (its empirical CDFs), the sweep report's trajectories, and the GIF
#: (it simulates and trains apg); each page names the command that draws them.
FIGURES: tuple[PublishedFigure, ...] = (
    *(
        PublishedFigure(
            f"{RESULTS}/paper-sweep/learning_curves_{setting}.png",
            _sweep_curve_files(setting),
            _sweep_curves_figure(setting),
        )
        for setting in ("main", "eps1", "bound150", "em-to-serb")
    ),
)


def write_figures(root: Path, figures: tuple[PublishedFigure, ...] = FIGURES) -> list[str]:
    """Re-plot every figure of `figures` under `root`; return their paths."""
    for figure in figures:
        for relative in figure.sources:
            if not (root / relative).is_file():
                raise ValueError(f"{figure.path}: {root / relative} does not exist")
    for figure in figures:
        figure.write(root)
    return [figure.path for figure in figures]


# ------------------------------------------------------------------------------ markers


def _block(marker: str) -> re.Pattern[str]:
    return re.compile(
        rf"(<!-- {re.escape(marker)}:start -->\n)(.*?)(<!-- {re.escape(marker)}:end -->)", re.S
    )


def marked_block(text: str, marker: str) -> str:
    """The body between `marker`'s start and end lines of `text`, stripped."""
    match = _block(marker).search(text)
    if match is None:
        raise ValueError(f"no <!-- {marker}:start --> ... <!-- {marker}:end --> block")
    return match.group(2).strip()


def replace_block(text: str, marker: str, body: str) -> str:
    """`text` with `marker`'s block body replaced by `body` (one newline before the end)."""
    marked_block(text, marker)  # raises when the markers are missing
    return _block(marker).sub(lambda m: m.group(1) + body.strip() + "\n" + m.group(3), text, 1)


def check_sources(root: Path, tables: tuple[PublishedTable, ...] = PUBLISHED) -> None:
    """Raise ValueError naming the first page or source file missing under `root`."""
    for table in tables:
        for relative in (table.page, *table.sources):
            if not (root / relative).is_file():
                raise ValueError(f"{table.name}: {root / relative} does not exist")


def stale_tables(root: Path, tables: tuple[PublishedTable, ...] = PUBLISHED) -> list[str]:
    """The names of the tables whose page block differs from their render."""
    check_sources(root, tables)
    return [
        t.name
        for t in tables
        if marked_block((root / t.page).read_text(), t.marker) != t.rendered(root).strip()
    ]


def write_tables(root: Path, tables: tuple[PublishedTable, ...] = PUBLISHED) -> list[str]:
    """Rewrite every stale table's block in its page; return their names."""
    stale = stale_tables(root, tables)
    for table in tables:
        if table.name in stale:
            page = root / table.page
            page.write_text(replace_block(page.read_text(), table.marker, table.rendered(root)))
    return stale


# ---------------------------------------------------------------------------------- CLI


@dataclass(frozen=True, kw_only=True)
class TablesConfig:
    """The options of `agent-envs tables`."""

    root: Path = option_field(
        Path("."), "the repository checkout holding README.md and docs/ (default: here)"
    )
    check: bool = option_field(
        False, "write nothing; exit 1 naming each table that differs from its files"
    )
    figures: bool = option_field(
        False,
        "also re-plot the figures drawn from committed files (`FIGURES`: the paper sweep's "
        "learning curves); PNGs are not compared by --check",
    )

    def __post_init__(self) -> None:
        root = Path(self.root)
        object.__setattr__(self, "root", root)
        if not (root / "README.md").is_file() or not (root / "docs").is_dir():
            raise ValueError(f"--root: {root} is not a checkout (no README.md and docs/)")


def run_tables(config: TablesConfig) -> int:
    """`agent-envs tables` (module docstring): 0 when every table is (now) current."""
    if config.check:
        stale = stale_tables(config.root)
        for name in stale:
            print(f"stale: {name} (run agent-envs tables)")
        print(f"{len(PUBLISHED) - len(stale)} of {len(PUBLISHED)} published tables current")
        return 1 if stale else 0
    for name in write_tables(config.root):
        print(f"rewrote {name}")
    print(f"{len(PUBLISHED)} published tables current")
    if config.figures:
        for name in write_figures(config.root):
            print(f"re-plotted {name}")
    return 0


__all__ = [
    "FIGURES",
    "PUBLISHED",
    "PublishedFigure",
    "PublishedTable",
    "TablesConfig",
    "check_sources",
    "marked_block",
    "replace_block",
    "run_tables",
    "stale_tables",
    "write_figures",
    "write_tables",
]
