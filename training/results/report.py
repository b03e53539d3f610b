"""Self-contained Markdown + HTML reports of policy evaluations, with PNG plots.

    agent-envs report RESULTS... --out DIR

RESULTS are folders written by `agent-envs evaluate` (or `EvaluationResults.save`). The report has a
table per policy (mean total cost with a 95% confidence interval from the t-distribution, ratio of
mean costs to the reference policy -- the turnpike controller by default -- and the mean of the per-
seed paired ratios with its 95% CI when the seeds match, the gap to optimal (cost - V) / V per seed
with its 95% CI when the optimal controller "optimal" was evaluated, divergence rate, final distance
to the target, control energy) and three PNGs: the path-mean agent trajectories per policy (one
seed), the running cost over time (log scale) and the turnpike distance ||E x^n - xbar||^2 +
||u^n||^2 over time (log scale), whose interior dip is the turnpike shape.

Library use (the training comparison adds its learning curves as an extra section):

    from agent_envs.training.results.report import build_report, ReportSection
    build_report([results], "report/", extra_sections=[
        ReportSection("Learning curves", text="...", images=["curves.png"])])

`report.md` references the PNGs next to it; `report.html` embeds them (base64), so it can be
mailed on its own.
"""

from __future__ import annotations

import base64
import html
import os
import shutil
from collections.abc import Sequence
from dataclasses import MISSING, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from agent_envs.training.config import option_field
from agent_envs.training.defaults import seed_text
from agent_envs.training.results.tables import (
    DEFAULT_REFERENCE,
    EvaluationResults,
    merge_results,
    summarize,
)
from agent_envs.training.storage import check_output_dir
from agent_envs.validation import check_int

#: The title of a report when none is given.
DEFAULT_TITLE = "Swarm control: policy evaluation"


@dataclass(frozen=True, kw_only=True)
class ReportConfig:
    """The options of `agent-envs report`; validated on construction (the folders' contents,
    --reference and the upper bound of --seed-index are checked when the results are loaded)."""

    results: tuple[Path, ...] = option_field(
        MISSING, "evaluation folder(s)", positional=True, nargs="+"
    )
    out: Path = option_field(MISSING, "report folder")
    title: str = option_field(DEFAULT_TITLE, "the report's title")
    reference: str | None = option_field(
        None, f"policy the cost ratios refer to (default: {DEFAULT_REFERENCE} when evaluated)"
    )
    seed_index: int = option_field(
        0, "which of the evaluated seeds (0 = the first) the trajectory plot shows"
    )

    def __post_init__(self) -> None:
        results = (self.results,) if isinstance(self.results, (str, os.PathLike)) else self.results
        object.__setattr__(self, "results", tuple(Path(r) for r in results))
        object.__setattr__(self, "out", Path(self.out))
        if not self.results:
            raise ValueError("report: name at least one evaluation folder (RESULTS)")
        check_int("--seed-index", self.seed_index, 0)


@dataclass
class ReportSection:
    """An extra section: a title, paragraphs (blank-line separated), a table, images, code.

    Images are copied into the report folder. `text` is written as is into Markdown and as
    escaped paragraphs into HTML.
    """

    title: str
    text: str = ""
    table: pd.DataFrame | None = None
    images: Sequence[str | os.PathLike] = ()
    code: str | None = None
    captions: Sequence[str] = field(default_factory=tuple)


# --------------------------------------------------------------------------------------------
# Plots
# --------------------------------------------------------------------------------------------


def _color(i: int) -> str:
    return f"C{i % 10}"


def check_seed_index(seed_index: int, n_seeds: int) -> int:
    """`seed_index` if it picks one of `n_seeds` seeds; ValueError naming --seed-index."""
    if isinstance(seed_index, bool) or not isinstance(seed_index, int):
        raise TypeError(f"--seed-index must be an integer, got {type(seed_index).__name__}")
    if not 0 <= seed_index < n_seeds:
        raise ValueError(
            f"--seed-index must be in [0, {n_seeds - 1}] (the results hold {n_seeds} seeds), "
            f"got {seed_index}"
        )
    return seed_index


def plot_trajectories(results: EvaluationResults, path: str | os.PathLike, seed_index: int = 0):
    """One panel per policy: every agent's path-mean position (coordinate 0) against time."""
    policies = [p for p in results.policies if p in results.trajectories]
    ncols = min(3, max(1, len(policies)))
    nrows = int(np.ceil(len(policies) / ncols))
    fig = Figure(figsize=(4.6 * ncols, 3.2 * nrows))
    axes = fig.subplots(nrows, ncols, squeeze=False, sharey=True)
    for ax in axes.flat[len(policies) :]:
        ax.set_visible(False)
    for ax, policy in zip(axes.flat, policies, strict=False):
        tr = results.trajectories[policy]
        s = check_seed_index(seed_index, len(tr["seeds"]))
        x = tr["mean_positions"][s, :, :, 0]
        ax.plot(tr["times"], x, lw=0.6, color="tab:blue", alpha=0.55)
        ax.axhline(tr["target"][s, 0], color="k", ls="--", lw=1, label="target")
        tb = float(tr["turnpike_time"][s]) if "turnpike_time" in tr else float("nan")
        if np.isfinite(tb):
            ax.axvline(tb, color="tab:red", ls=":", lw=1.2, label=f"tbar = {tb:.2f}")
        ax.set_title(f"{policy} (seed {int(tr['seeds'][s])})", fontsize=10)
        ax.set_xlabel("t")
        ax.legend(loc="best", fontsize=7)
    for ax in axes[:, 0]:
        ax.set_ylabel("E x_k(t)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def _band_plot(results, key, path, ylabel, title, times_slice):
    fig = Figure(figsize=(7.5, 4.2))
    ax = fig.subplots()
    for i, policy in enumerate(p for p in results.policies if p in results.trajectories):
        tr = results.trajectories[policy]
        values = np.asarray(tr[key], dtype=float)
        t = tr["times"][times_slice(values.shape[1])]
        with np.errstate(all="ignore"):
            mean = np.nanmean(values, axis=0)
            lo, hi = np.nanpercentile(values, [10, 90], axis=0)
        ax.plot(t, mean, color=_color(i), lw=1.6, label=policy)
        ax.fill_between(t, lo, hi, color=_color(i), alpha=0.15, lw=0)
        tb = np.asarray(tr.get("turnpike_time", [np.nan]), float)
        if np.isfinite(tb).any():
            ax.axvline(np.nanmean(tb), color=_color(i), ls=":", lw=1)
    ax.set_yscale("log")
    ax.set_xlabel("t")
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.25)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def plot_running_cost(results: EvaluationResults, path: str | os.PathLike) -> None:
    """Running cost c(x^n, u^n) against t_n, mean over seeds (line) and 10-90% band, log y."""
    _band_plot(
        results,
        "running_cost",
        path,
        "running cost c(x^n, u^n)",
        "running cost (mean over seeds, band 10-90%; dotted: mean tbar)",
        lambda k: slice(0, k),
    )


def plot_turnpike_distance(results: EvaluationResults, path: str | os.PathLike) -> None:
    """||E x^n - xbar||^2 + ||u^n||^2 against t_n (u^m := 0), mean over seeds and band, log y."""
    _band_plot(
        results,
        "turnpike_distance",
        path,
        "||E x^n - xbar||^2 + ||u^n||^2",
        "turnpike distance (mean over seeds, band 10-90%; dotted: mean tbar)",
        lambda k: slice(0, k),
    )


# --------------------------------------------------------------------------------------------
# Rendering
# --------------------------------------------------------------------------------------------


def _fmt(v: Any) -> str:
    if isinstance(v, (bool, np.bool_)):
        return str(bool(v))
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        if not np.isfinite(v):
            return "n/a"
        return f"{v:.4g}"
    return str(v)


def _pct(v: Any) -> str:
    return f"{100 * v:+.2f}%" if np.isfinite(v) else "n/a"


def _with_ci(summary: pd.DataFrame, point: str, low: str, high: str, fmt) -> list[str]:
    """'point [low, high]' per row of `summary`, each value written by `fmt`."""
    return [
        f"{fmt(m)} [{fmt(lo)}, {fmt(hi)}]"
        for m, lo, hi in zip(summary[point], summary[low], summary[high], strict=True)
    ]


def display_table(summary: pd.DataFrame, reference: str | None) -> pd.DataFrame:
    """The summary as strings for the report (CI merged into one column)."""
    out = pd.DataFrame({"policy": summary["policy"], "episodes": summary["episodes"]})
    out["mean cost [95% CI]"] = _with_ci(summary, "mean_cost", "cost_ci_low", "cost_ci_high", _fmt)
    if "ratio_to_reference" in summary:
        out[f"ratio to {reference}"] = summary["ratio_to_reference"].map(_fmt)
        out["paired ratio [95% CI]"] = _with_ci(
            summary, "paired_ratio", "paired_ratio_ci_low", "paired_ratio_ci_high", _fmt
        )
    if "gap_to_optimal" in summary:
        out["gap to optimal [95% CI]"] = _with_ci(
            summary, "gap_to_optimal", "gap_ci_low", "gap_ci_high", _pct
        )
    out["divergence rate"] = summary["divergence_rate"].map(lambda v: f"{100 * v:.0f}%")
    out["final RMS distance"] = summary["mean_final_distance"].map(_fmt)
    out["control energy"] = summary["mean_control_energy"].map(_fmt)
    if "mean_saturated_fraction" in summary:
        out["saturated"] = summary["mean_saturated_fraction"].map(lambda v: f"{100 * v:.1f}%")
    if "mean_turnpike_time" in summary:
        out["tbar"] = summary["mean_turnpike_time"].map(_fmt)
    return out


def markdown_table(df: pd.DataFrame) -> str:
    """A DataFrame as a Markdown table (numbers as the report shows them, "|" escaped)."""
    cols = [str(c) for c in df.columns]
    lines = ["| " + " | ".join(cols) + " |", "|" + "|".join("---" for _ in cols) + "|"]
    for _, row in df.iterrows():
        lines.append("| " + " | ".join(_fmt(v).replace("|", "\\|") for v in row) + " |")
    return "\n".join(lines)


def _html_table(df: pd.DataFrame) -> str:
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in df.columns)
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(_fmt(v))}</td>" for v in row) + "</tr>"
        for _, row in df.iterrows()
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


class _Document:
    """Blocks rendered both to Markdown and to HTML."""

    def __init__(self, title: str) -> None:
        self.title = title
        self.blocks: list[tuple[str, Any]] = []

    def heading(self, text: str) -> None:
        self.blocks.append(("h2", text))

    def paragraph(self, text: str) -> None:
        for para in str(text).strip().split("\n\n"):
            if para.strip():
                self.blocks.append(("p", para.strip()))

    def table(self, df: pd.DataFrame) -> None:
        self.blocks.append(("table", df))

    def image(self, rel_path: str, caption: str) -> None:
        self.blocks.append(("img", (rel_path, caption)))

    def code(self, text: str) -> None:
        self.blocks.append(("code", text))

    def markdown(self) -> str:
        out = [f"# {self.title}", ""]
        for kind, value in self.blocks:
            if kind == "h2":
                out += [f"## {value}", ""]
            elif kind == "p":
                out += [value, ""]
            elif kind == "table":
                out += [markdown_table(value), ""]
            elif kind == "img":
                rel, cap = value
                out += [f"![{cap}]({rel})", "", f"*{cap}*", ""]
            elif kind == "code":
                out += ["```", value.rstrip(), "```", ""]
        return "\n".join(out)

    def html(self, folder: Path) -> str:
        parts = [
            "<!DOCTYPE html><html><head><meta charset='utf-8'>",
            f"<title>{html.escape(self.title)}</title><style>",
            "body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;"
            "padding:0 1em;color:#222}table{border-collapse:collapse;margin:1em 0;font-size:13px}"
            "td,th{border:1px solid #bbb;padding:4px 8px;text-align:right}"
            "th{background:#eee}td:first-child,th:first-child{text-align:left}"
            "img{max-width:100%}figcaption{font-size:13px;color:#555}"
            "pre{background:#f4f4f4;padding:.8em;overflow-x:auto}",
            "</style></head><body>",
            f"<h1>{html.escape(self.title)}</h1>",
        ]
        for kind, value in self.blocks:
            if kind == "h2":
                parts.append(f"<h2>{html.escape(value)}</h2>")
            elif kind == "p":
                parts.append(f"<p>{html.escape(value)}</p>")
            elif kind == "table":
                parts.append(_html_table(value))
            elif kind == "img":
                rel, cap = value
                data = base64.b64encode((folder / rel).read_bytes()).decode("ascii")
                parts.append(
                    f"<figure><img alt='{html.escape(cap)}' src='data:image/png;base64,{data}'>"
                    f"<figcaption>{html.escape(cap)}</figcaption></figure>"
                )
            elif kind == "code":
                parts.append(f"<pre>{html.escape(value)}</pre>")
        parts.append("</body></html>")
        return "\n".join(parts)


def _as_results(item: Any) -> EvaluationResults:
    if isinstance(item, EvaluationResults):
        return item
    return EvaluationResults.load(item)


def _merged_results(
    results: EvaluationResults | str | os.PathLike | Sequence[Any],
    reference: str | None,
    seed_index: int,
) -> tuple[EvaluationResults, str | None]:
    """The merged results and the reference actually used (None: the default one is absent).

    Raises ValueError for a reference that is not an evaluated policy (other than the default)
    and for a `seed_index` out of the results' range.
    """
    items = [results] if isinstance(results, (EvaluationResults, str, os.PathLike)) else results
    merged = merge_results([_as_results(r) for r in items])
    if reference is not None and reference not in merged.policies:
        if reference != DEFAULT_REFERENCE:
            raise ValueError(
                f"reference {reference!r} is not an evaluated policy; the results hold "
                f"{', '.join(merged.policies)}"
            )
        reference = None
    if merged.trajectories:
        check_seed_index(seed_index, min(len(t["seeds"]) for t in merged.trajectories.values()))
    return merged, reference


def _write_plots(merged: EvaluationResults, out: Path, seed_index: int) -> dict[str, Path]:
    """The three PNGs (when the results hold trajectories); returns the paths of all outputs."""
    paths = {
        "summary": out / "summary.csv",
        "trajectories": out / "trajectories.png",
        "running_cost": out / "running_cost.png",
        "turnpike_distance": out / "turnpike_distance.png",
    }
    if merged.trajectories:
        plot_trajectories(merged, paths["trajectories"], seed_index)
        plot_running_cost(merged, paths["running_cost"])
        plot_turnpike_distance(merged, paths["turnpike_distance"])
    return paths


def _setting_text(merged: EvaluationResults) -> str:
    """The "Setting" paragraph: env, kwargs, integrator, sizes and the seeds."""
    meta = merged.meta
    seeds = meta.get("seeds", sorted(set(merged.episodes["seed"])))
    env = meta.get("env", {})
    setting = [
        f"Env `{meta.get('env_id', '?')}` with kwargs `{meta.get('env_kwargs', {})}`"
        + (f", reset options `{meta['reset_options']}`" if meta.get("reset_options") else "")
        + ".",
        f"Integrator {env.get('integrator', '?')} (Jacobian {env.get('jacobian', '?')}), "
        f"m = {env.get('n_steps', '?')} steps, {env.get('n_paths', '?')} Brownian path(s), "
        f"max_control = {env.get('max_control', '?')}.",
        f"{len(seeds)} seeds, the same for every policy: {seed_text(seeds, '..', ', ')}.",
    ]
    if meta.get("consistent") is False:
        setting.append("WARNING: the merged evaluations differ in env, kwargs or seeds.")
    return " ".join(setting)


def _results_text(summary: pd.DataFrame, reference: str | None, confidence: float) -> str:
    """The paragraph that explains the per-policy table's columns."""
    return (
        f"Total cost = minus the episode return = tau sum_n c(x^n, u^n) on the env's paths "
        f"(eq:discrete_cost_functional); lower is better. Mean over episodes with a "
        f"{100 * confidence:.0f}% t-interval. "
        + (
            f"'ratio to {reference}' divides mean costs; 'paired ratio' averages the per-seed "
            f"ratios (same seeds). "
            if reference
            else ""
        )
        + (
            "'gap to optimal' is the per-seed (cost - V) / V, V = the cost of the optimal "
            "open-loop plan (policy 'optimal', solved from each episode's start) on the same "
            "seed, mean and t-interval; a feedback policy can beat it (negative gap). "
            if "gap_to_optimal" in summary
            else ""
        )
        + "A diverged episode stops early, so its cost covers only the steps it ran: read the "
        "costs with the divergence rate. Final RMS distance: sqrt(mean_k |E x_k(T) - xbar|^2) "
        "over non-diverged episodes; control energy: tau sum_n (1/N) sum_k |u_k^n|^2; "
        "saturated: share of controls at max_control; tbar: turnpike time (eq:tptime) where the "
        "policy uses one."
    )


def _add_plots(doc: _Document, paths: dict[str, Path]) -> None:
    """The "Plots" section: the three PNGs with their captions."""
    doc.heading("Plots")
    doc.image(
        paths["trajectories"].name,
        "Path-mean position of every agent (coordinate 0) against time, one seed per policy; "
        "dashed: target, dotted red: turnpike time tbar.",
    )
    doc.image(
        paths["running_cost"].name,
        "Running cost c(x^n, u^n) against time (log scale): mean over seeds, 10-90% band.",
    )
    doc.image(
        paths["turnpike_distance"].name,
        "Turnpike distance ||E x^n - xbar||^2 + ||u^n||^2 against time (log scale; u^m := 0): "
        "small in the interior of the horizon = turnpike shape.",
    )


def _add_section(doc: _Document, section: ReportSection, out: Path) -> None:
    """One extra section; its images are copied into the report folder `out`."""
    doc.heading(section.title)
    if section.text:
        doc.paragraph(section.text)
    if section.table is not None:
        doc.table(section.table)
    for i, img in enumerate(section.images):
        src = Path(img)
        dest = out / src.name
        if src.resolve() != dest.resolve():
            shutil.copyfile(src, dest)
        cap = section.captions[i] if i < len(section.captions) else src.stem
        doc.image(dest.name, cap)
    if section.code:
        doc.code(section.code)


def build_report(
    results: EvaluationResults | str | os.PathLike | Sequence[Any],
    out_dir: str | os.PathLike,
    *,
    title: str = DEFAULT_TITLE,
    reference: str | None = DEFAULT_REFERENCE,
    extra_sections: Sequence[ReportSection] = (),
    command: str | None = None,
    seed_index: int = 0,
    confidence: float = 0.95,
) -> dict[str, Path]:
    """Write report.md, report.html, summary.csv and the PNGs into `out_dir`.

    Args:
        results: one or several `EvaluationResults` or evaluation folders (merged).
        out_dir: the report folder (created).
        title: the report's title.
        reference: the policy the ratios are taken to; the default (turnpike) is skipped when
            absent, any other name must be an evaluated policy (ValueError otherwise).
        extra_sections: `ReportSection`s appended after the standard ones.
        command: the command that produced the results, printed in the report.
        seed_index: which seed's trajectories the trajectory plot shows (ValueError when
            out of range).
        confidence: level of the confidence intervals.

    Returns:
        {"markdown": ..., "html": ..., "summary": ..., "trajectories": ..., "running_cost": ...,
        "turnpike_distance": ...} paths.
    """
    merged, reference = _merged_results(results, reference, seed_index)
    out = check_output_dir(out_dir, "--out")
    out.mkdir(parents=True, exist_ok=True)
    summary = summarize(merged.episodes, reference, confidence)
    summary.to_csv(out / "summary.csv", index=False)
    paths = _write_plots(merged, out, seed_index)

    doc = _Document(title)
    doc.heading("Setting")
    doc.paragraph(_setting_text(merged))
    if command:
        doc.code(command)
    doc.heading("Results per policy")
    doc.paragraph(_results_text(summary, reference, confidence))
    doc.table(display_table(summary, reference))
    if merged.trajectories:
        _add_plots(doc, paths)
    for section in extra_sections:
        _add_section(doc, section, out)
    md_path, html_path = out / "report.md", out / "report.html"
    md_path.write_text(doc.markdown())
    html_path.write_text(doc.html(out))
    paths.update(markdown=md_path, html=html_path)
    return paths


__all__ = [
    "DEFAULT_TITLE",
    "ReportConfig",
    "ReportSection",
    "build_report",
    "check_seed_index",
    "display_table",
    "plot_running_cost",
    "plot_trajectories",
    "plot_turnpike_distance",
]
