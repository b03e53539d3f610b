"""Self-contained Markdown + HTML reports of policy evaluations, with PNG plots.

    agent-envs report RESULTS... --out DIR

RESULTS are folders written by `agent-envs evaluate` (or `EvaluationResults.save`). The report
has a table per policy (mean total cost with a 95% confidence interval from the t-distribution,
ratio of mean costs to the reference policy -- the turnpike controller by default -- and the
mean of the per-seed paired ratios with its 95% CI when the seeds match, the gap to optimal
(cost - V) / V per seed with its 95% CI when the optimal controller "optimal" was evaluated,
divergence rate, final distance to the target, control energy) and three PNGs: the path-mean
agent trajectories per policy (one seed), the running cost over time (log scale) and the
turnpike distance ||E x^n - xbar||^2 + ||u^n||^2 over time (log scale), whose interior dip is
the turnpike shape.

Library use (the training comparison adds its learning curves as an extra section):

    from agent_envs.training.report import build_report, ReportSection
    build_report([results], "report/", extra_sections=[
        ReportSection("Learning curves", text="...", images=["curves.png"])])

`report.md` references the PNGs next to it; `report.html` embeds them (base64), so it can be
mailed on its own.
"""

from __future__ import annotations

import argparse
import base64
import html
import os
import shutil
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from agent_envs.plotting import headless_pyplot
from agent_envs.training.evaluate import EvaluationResults

DEFAULT_REFERENCE = "turnpike"
#: the policy whose cost is V in the "gap to optimal" column (skipped when not evaluated)
DEFAULT_OPTIMUM = "optimal"


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
# Statistics
# --------------------------------------------------------------------------------------------


def mean_confidence_interval(values: Sequence[float], confidence: float = 0.95):
    """(mean, low, high) with the t-distribution: mean +- t_{(1+c)/2, n-1} s / sqrt(n).

    NaNs are dropped. One value gives (v, nan, nan); none gives three NaNs.
    """
    from scipy import stats

    arr = np.asarray(values, dtype=float)
    arr = arr[np.isfinite(arr)]
    if arr.size == 0:
        return float("nan"), float("nan"), float("nan")
    mean = float(arr.mean())
    if arr.size < 2:
        return mean, float("nan"), float("nan")
    half = float(
        stats.t.ppf(0.5 + confidence / 2, arr.size - 1) * arr.std(ddof=1) / np.sqrt(arr.size)
    )
    return mean, mean - half, mean + half


def summarize(
    episodes: pd.DataFrame,
    reference: str | None = DEFAULT_REFERENCE,
    confidence: float = 0.95,
    optimum: str | None = DEFAULT_OPTIMUM,
) -> pd.DataFrame:
    """One row per policy: cost statistics, ratio to `reference`, divergence rate, etc.

    Columns: policy, episodes, mean_cost, cost_ci_low, cost_ci_high, ratio_to_reference
    (mean cost / reference mean cost), paired_ratio, paired_ratio_ci_low/high (per-seed
    cost / reference cost on the same seed, mean and t-CI; only for seeds both have),
    divergence_rate, mean_final_distance (non-diverged episodes), mean_control_energy,
    mean_saturated_fraction, mean_turnpike_time.

    With `optimum` (the open-loop optimal controller, "optimal") among the policies: the gap to
    optimal (cost - V) / V per seed, V = the optimum's cost on the same seed, as gap_to_optimal
    with its t-CI gap_ci_low/high. V is the optimal open-loop plan's cost on the env's own noise,
    so a feedback policy (MPC, a learner) can have a negative gap.

    A diverged episode ends early with the cost accumulated so far, which would make a diverging
    policy look cheap: the ratios and gaps are NaN (shown as n/a) when the policy or the
    reference (optimum) has a diverged episode.
    """
    best = None
    if optimum is not None and optimum in set(episodes["policy"]):
        best_rows = episodes[episodes["policy"] == optimum]
        best = best_rows.set_index("seed")["total_cost"]
        if bool(best_rows["diverged"].astype(bool).any()):
            best = best * float("nan")
    rows = []
    ref = None
    ref_diverged = False
    if reference is not None and reference in set(episodes["policy"]):
        ref_rows = episodes[episodes["policy"] == reference]
        ref = ref_rows.set_index("seed")["total_cost"]
        ref_diverged = bool(ref_rows["diverged"].astype(bool).any())
    for policy, group in episodes.groupby("policy", sort=False):
        mean, low, high = mean_confidence_interval(group["total_cost"], confidence)
        row: dict[str, Any] = {
            "policy": policy,
            "episodes": len(group),
            "mean_cost": mean,
            "cost_ci_low": low,
            "cost_ci_high": high,
        }
        if ref is not None:
            ref_mean = float(ref.mean())
            row["ratio_to_reference"] = mean / ref_mean if ref_mean else float("nan")
            paired = group.set_index("seed")["total_cost"]
            common = paired.index.intersection(ref.index)
            ratios = (paired.loc[common] / ref.loc[common]).to_numpy(float)
            pm, pl, ph = mean_confidence_interval(ratios, confidence)
            row.update(paired_ratio=pm, paired_ratio_ci_low=pl, paired_ratio_ci_high=ph)
            if ref_diverged or bool(group["diverged"].astype(bool).any()):
                for key in (
                    "ratio_to_reference",
                    "paired_ratio",
                    "paired_ratio_ci_low",
                    "paired_ratio_ci_high",
                ):
                    row[key] = float("nan")
        if best is not None:
            paired = group.set_index("seed")["total_cost"]
            common = paired.index.intersection(best.index)
            gaps = ((paired.loc[common] - best.loc[common]) / best.loc[common]).to_numpy(float)
            if bool(group["diverged"].astype(bool).any()):
                gaps = gaps * float("nan")
            gm, gl, gh = mean_confidence_interval(gaps, confidence)
            row.update(gap_to_optimal=gm, gap_ci_low=gl, gap_ci_high=gh)
        diverged = group["diverged"].astype(bool)
        row["divergence_rate"] = float(diverged.mean())
        row["mean_final_distance"] = float(group.loc[~diverged, "final_distance"].mean())
        row["mean_control_energy"] = float(group["control_energy"].mean())
        if "saturated_fraction" in group:
            row["mean_saturated_fraction"] = float(group["saturated_fraction"].mean())
        if "turnpike_time" in group:
            tb = pd.to_numeric(group["turnpike_time"], errors="coerce")
            row["mean_turnpike_time"] = float(tb.mean()) if tb.notna().any() else float("nan")
        rows.append(row)
    return pd.DataFrame(rows)


def merge_results(results: Sequence[EvaluationResults]) -> EvaluationResults:
    """Concatenate several evaluations; clashing policy names get a ``@folder`` suffix."""
    if len(results) == 1:
        return results[0]
    frames, trajectories, metas = [], {}, []
    seen: set[str] = set()
    for i, res in enumerate(results):
        tag = res.source.name if res.source is not None else f"run{i}"
        rename = {}
        for p in res.policies:
            new = p if p not in seen else f"{p}@{tag}"
            rename[p] = new
            seen.add(new)
        frames.append(res.episodes.assign(policy=res.episodes["policy"].map(rename)))
        for p, arrays in res.trajectories.items():
            trajectories[rename.get(p, p)] = arrays
        metas.append(res.meta)
    meta = dict(metas[0])
    meta["merged_from"] = [str(r.source) if r.source else None for r in results]
    keys = ("env_id", "env_kwargs", "seeds", "reset_options")
    meta["consistent"] = all(all(m.get(k) == metas[0].get(k) for k in keys) for m in metas)
    return EvaluationResults(pd.concat(frames, ignore_index=True), trajectories, meta)


# --------------------------------------------------------------------------------------------
# Plots
# --------------------------------------------------------------------------------------------


def _color(i: int) -> str:
    return f"C{i % 10}"


def plot_trajectories(results: EvaluationResults, path: str | os.PathLike, seed_index: int = 0):
    """One panel per policy: every agent's path-mean position (coordinate 0) against time."""
    plt = headless_pyplot()
    policies = [p for p in results.policies if p in results.trajectories]
    ncols = min(3, max(1, len(policies)))
    nrows = int(np.ceil(len(policies) / ncols))
    fig, axes = plt.subplots(
        nrows, ncols, figsize=(4.6 * ncols, 3.2 * nrows), squeeze=False, sharey=True
    )
    for ax in axes.flat[len(policies) :]:
        ax.set_visible(False)
    for ax, policy in zip(axes.flat, policies, strict=False):
        tr = results.trajectories[policy]
        s = min(seed_index, len(tr["seeds"]) - 1)
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
    plt.close(fig)


def _band_plot(results, key, path, ylabel, title, times_slice):
    plt = headless_pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
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
    plt.close(fig)


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


def display_table(summary: pd.DataFrame, reference: str | None) -> pd.DataFrame:
    """The summary as strings for the report (CI merged into one column)."""
    out = pd.DataFrame({"policy": summary["policy"], "episodes": summary["episodes"]})
    out["mean cost [95% CI]"] = [
        f"{_fmt(m)} [{_fmt(lo)}, {_fmt(hi)}]"
        for m, lo, hi in zip(
            summary["mean_cost"], summary["cost_ci_low"], summary["cost_ci_high"], strict=True
        )
    ]
    if "ratio_to_reference" in summary:
        out[f"ratio to {reference}"] = summary["ratio_to_reference"].map(_fmt)
        out["paired ratio [95% CI]"] = [
            f"{_fmt(m)} [{_fmt(lo)}, {_fmt(hi)}]"
            for m, lo, hi in zip(
                summary["paired_ratio"],
                summary["paired_ratio_ci_low"],
                summary["paired_ratio_ci_high"],
                strict=True,
            )
        ]
    if "gap_to_optimal" in summary:
        out["gap to optimal [95% CI]"] = [
            f"{_pct(m)} [{_pct(lo)}, {_pct(hi)}]"
            for m, lo, hi in zip(
                summary["gap_to_optimal"],
                summary["gap_ci_low"],
                summary["gap_ci_high"],
                strict=True,
            )
        ]
    out["divergence rate"] = summary["divergence_rate"].map(lambda v: f"{100 * v:.0f}%")
    out["final RMS distance"] = summary["mean_final_distance"].map(_fmt)
    out["control energy"] = summary["mean_control_energy"].map(_fmt)
    if "mean_saturated_fraction" in summary:
        out["saturated"] = summary["mean_saturated_fraction"].map(lambda v: f"{100 * v:.1f}%")
    if "mean_turnpike_time" in summary:
        out["tbar"] = summary["mean_turnpike_time"].map(_fmt)
    return out


def _md_table(df: pd.DataFrame) -> str:
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
                out += [_md_table(value), ""]
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


def build_report(
    results: EvaluationResults | str | os.PathLike | Sequence[Any],
    out_dir: str | os.PathLike,
    *,
    title: str = "Swarm control: policy evaluation",
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
        reference: the policy the ratios are taken to (skipped when absent).
        extra_sections: `ReportSection`s appended after the standard ones.
        command: the command that produced the results, printed in the report.
        seed_index: which seed's trajectories the trajectory plot shows.
        confidence: level of the confidence intervals.

    Returns:
        {"markdown": ..., "html": ..., "summary": ..., "trajectories": ..., "running_cost": ...,
        "turnpike_distance": ...} paths.
    """
    items = [results] if isinstance(results, (EvaluationResults, str, os.PathLike)) else results
    merged = merge_results([_as_results(r) for r in items])
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if reference is not None and reference not in merged.policies:
        reference = None
    summary = summarize(merged.episodes, reference, confidence)
    summary.to_csv(out / "summary.csv", index=False)
    paths = {
        "summary": out / "summary.csv",
        "trajectories": out / "trajectories.png",
        "running_cost": out / "running_cost.png",
        "turnpike_distance": out / "turnpike_distance.png",
    }
    has_traj = bool(merged.trajectories)
    if has_traj:
        plot_trajectories(merged, paths["trajectories"], seed_index)
        plot_running_cost(merged, paths["running_cost"])
        plot_turnpike_distance(merged, paths["turnpike_distance"])

    doc = _Document(title)
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
        f"{len(seeds)} seeds, the same for every policy: {_seed_text(seeds)}.",
    ]
    if meta.get("consistent") is False:
        setting.append("WARNING: the merged evaluations differ in env, kwargs or seeds.")
    doc.heading("Setting")
    doc.paragraph(" ".join(setting))
    if command:
        doc.code(command)
    doc.heading("Results per policy")
    doc.paragraph(
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
    doc.table(display_table(summary, reference))
    if has_traj:
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
    for section in extra_sections:
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
    md_path, html_path = out / "report.md", out / "report.html"
    md_path.write_text(doc.markdown())
    html_path.write_text(doc.html(out))
    paths.update(markdown=md_path, html=html_path)
    return paths


def _seed_text(seeds: Sequence[int]) -> str:
    seeds = [int(s) for s in seeds]
    if len(seeds) > 2 and seeds == list(range(seeds[0], seeds[0] + len(seeds))):
        return f"{seeds[0]}..{seeds[-1]}"
    return ", ".join(map(str, seeds))


# --------------------------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------------------------


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("results", nargs="+", type=Path, help="evaluation folder(s)")
    parser.add_argument("--out", required=True, type=Path, help="report folder")
    parser.add_argument("--title", default="Swarm control: policy evaluation")
    parser.add_argument(
        "--reference",
        default=DEFAULT_REFERENCE,
        help="policy the cost ratios refer to (default: turnpike)",
    )
    parser.add_argument("--seed-index", type=int, default=0, help="seed shown in trajectories")


def run(args: argparse.Namespace) -> int:
    paths = build_report(
        list(args.results),
        args.out,
        title=args.title,
        reference=args.reference,
        seed_index=args.seed_index,
    )
    summary = pd.read_csv(paths["summary"])
    print(display_table(summary, args.reference).to_string(index=False))
    print(f"report: {paths['markdown']} and {paths['html']}")
    return 0


__all__ = [
    "ReportSection",
    "build_report",
    "display_table",
    "mean_confidence_interval",
    "merge_results",
    "plot_running_cost",
    "plot_trajectories",
    "plot_turnpike_distance",
    "summarize",
]
