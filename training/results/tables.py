"""Results of evaluations and their statistics: the one episode record, the per-policy table.

- `Episode`: one episode's path-mean record (positions, controls, running cost, rewards, target,
  turnpike time, divergence) with its summary scalars; `agent_envs.training.results.rollout.rollout`
  records one from an env, the turnpike reproduction records the paper's closed loop in it too.
  (The core's `agent_envs.simulator.Trajectory` is the simulator's raw output, all paths.)
- `EvaluationResults`: the per-episode table, the per-policy trajectories stacked over seeds and
  the metadata of one evaluation; `save` / `load` a folder.
- Statistics: `mean_confidence_interval` (t-interval), `summarize` (one row per policy, ratios to
  a reference policy), `merge_results`.
"""

from __future__ import annotations

import json
import os
import re
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

#: saturation tolerance: |u| >= (1 - SATURATION_TOL) max_control counts as saturated
SATURATION_TOL = 1e-6
#: the policy cost ratios refer to by default
DEFAULT_REFERENCE = "turnpike"
#: the policy whose cost is V in the "gap to optimal" column (skipped when not evaluated)
DEFAULT_OPTIMUM = "optimal"

EPISODE_COLUMNS = (
    "policy",
    "seed",
    "total_cost",
    "final_distance",
    "final_sq_distance",
    "diverged",
    "divergence_step",
    "control_energy",
    "saturated_fraction",
    "turnpike_time",
    "n_steps_run",
    "wall_time_s",
)


@dataclass
class Episode:
    """One episode's per-step record (path means) and its summary scalars.

    The one record of an episode in the training layer: `rollout` fills it from an env, the
    turnpike reproduction from the paper's closed loop.

    Arrays: times (m+1,), mean_positions (m+1, N, d) (NaN after a divergence), controls (m, N, d),
    running_cost (m,), rewards (m,) (zeros after the episode ended), target (d,).
    """

    seed: int | None
    times: np.ndarray
    mean_positions: np.ndarray
    controls: np.ndarray
    running_cost: np.ndarray
    rewards: np.ndarray
    target: np.ndarray
    dt: float
    max_control: float
    diverged: bool
    divergence_step: int | None
    n_steps_run: int
    turnpike_time: float
    wall_time: float
    #: largest |u| entry over the controls applied on each path, when they differ from the
    #: path-mean `controls` (the closed loop's per-path feedback); None: take it from `controls`
    max_abs_control: float | None = None

    @property
    def total_cost(self) -> float:
        """Minus the sum of rewards = tau sum_n c(x^n, u^n) on the env's paths."""
        return float(-np.sum(self.rewards))

    @property
    def last_positions(self) -> np.ndarray:
        return self.mean_positions[self.n_steps_run]

    @property
    def final_sq_distance(self) -> float:
        """||E x^m - xbar||^2 (sum over agents and coordinates); NaN when diverged."""
        if self.diverged:
            return float("nan")
        return float(np.sum((self.last_positions - self.target) ** 2))

    @property
    def final_distance(self) -> float:
        """RMS over agents of |E x_k(T) - xbar|; NaN when diverged."""
        if self.diverged:
            return float("nan")
        return float(np.sqrt(np.mean(np.sum((self.last_positions - self.target) ** 2, -1))))

    @property
    def control_energy(self) -> float:
        """tau sum_n (1/N) sum_k |u_k^n|^2 (the control term of the cost without gamma)."""
        return float(self.dt * np.sum(np.mean(np.sum(self.controls**2, -1), -1)))

    @property
    def saturated_fraction(self) -> float:
        """Fraction of control entries at the bound max_control (clipped actions)."""
        run = self.controls[: self.n_steps_run]
        if run.size == 0:
            return 0.0
        return float(np.mean(np.abs(run) >= (1 - SATURATION_TOL) * self.max_control))

    def turnpike_distance(self) -> np.ndarray:
        """||E x^n - xbar||^2 + ||u^n||^2 for n = 0..m (u^m := 0); shape (m+1,)."""
        from agent_envs.costs import turnpike_distance

        u = np.concatenate([self.controls, np.zeros_like(self.controls[:1])], axis=0)
        return turnpike_distance(self.mean_positions, u, self.target)

    def summary(self) -> dict[str, Any]:
        return {
            "seed": self.seed,
            "total_cost": self.total_cost,
            "final_distance": self.final_distance,
            "final_sq_distance": self.final_sq_distance,
            "diverged": bool(self.diverged),
            "divergence_step": self.divergence_step,
            "control_energy": self.control_energy,
            "saturated_fraction": self.saturated_fraction,
            "turnpike_time": self.turnpike_time,
            "n_steps_run": self.n_steps_run,
            "wall_time_s": self.wall_time,
        }


def _safe_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_") or "policy"


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating, float)):
        v = float(value)
        return v if np.isfinite(v) else None
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (str, int, bool)) or value is None:
        return value
    return repr(value)


@dataclass
class EvaluationResults:
    """Per-episode table, per-policy trajectories and metadata of one evaluation.

    `trajectories[policy]` holds arrays over the seeds: ``seeds`` (S,), ``times`` (m+1,),
    ``mean_positions`` (S, m+1, N, d), ``controls`` (S, m, N, d), ``running_cost`` (S, m),
    ``turnpike_distance`` (S, m+1), ``target`` (S, d), ``turnpike_time`` (S,).
    """

    episodes: pd.DataFrame
    trajectories: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)
    source: Path | None = None

    @property
    def policies(self) -> list[str]:
        return list(dict.fromkeys(self.episodes["policy"]))

    def save(self, out_dir: str | os.PathLike) -> Path:
        """Write episodes.csv, episodes.json, meta.json and trajectories/{policy}.npz."""
        out = Path(out_dir)
        (out / "trajectories").mkdir(parents=True, exist_ok=True)
        self.episodes.to_csv(out / "episodes.csv", index=False)
        records = [_jsonable(r) for r in self.episodes.to_dict(orient="records")]
        (out / "episodes.json").write_text(json.dumps(records, indent=1))
        files = {}
        for policy, arrays in self.trajectories.items():
            fname = f"{_safe_name(policy)}.npz"
            files[policy] = f"trajectories/{fname}"
            np.savez_compressed(out / "trajectories" / fname, **arrays)
        meta = {**self.meta, "trajectory_files": files}
        (out / "meta.json").write_text(json.dumps(_jsonable(meta), indent=1))
        self.source = out
        return out

    @classmethod
    def load(cls, path: str | os.PathLike) -> EvaluationResults:
        """Load what `save` wrote (a folder, or its episodes.csv / meta.json)."""
        p = Path(path)
        if not p.exists():
            raise FileNotFoundError(f"{p} does not exist (expected an evaluation folder)")
        folder = p if p.is_dir() else p.parent
        if not (folder / "episodes.csv").is_file():
            raise FileNotFoundError(f"no episodes.csv in {folder} (not an evaluation folder)")
        try:
            episodes = pd.read_csv(folder / "episodes.csv")
            meta = {}
            if (folder / "meta.json").is_file():
                meta = json.loads((folder / "meta.json").read_text())
            trajectories: dict[str, dict[str, np.ndarray]] = {}
            for policy, rel in dict(meta.get("trajectory_files", {})).items():
                f = folder / rel
                if f.is_file():
                    with np.load(f) as data:
                        trajectories[policy] = {k: data[k] for k in data.files}
        except (ValueError, TypeError, KeyError, EOFError, zipfile.BadZipFile) as exc:
            raise ValueError(f"{folder} holds a damaged evaluation ({exc})") from None
        missing = [c for c in EPISODE_COLUMNS if c not in episodes.columns]
        if missing:
            raise ValueError(f"{folder}/episodes.csv lacks the columns {missing}")
        return cls(episodes=episodes, trajectories=trajectories, meta=meta, source=folder)


def stack_episodes(episodes: Sequence[Episode]) -> dict[str, np.ndarray]:
    return {
        "seeds": np.array([-1 if e.seed is None else e.seed for e in episodes]),
        "times": episodes[0].times,
        "mean_positions": np.stack([e.mean_positions for e in episodes]),
        "controls": np.stack([e.controls for e in episodes]),
        "running_cost": np.stack(
            [
                np.where(np.arange(len(e.running_cost)) < e.n_steps_run, e.running_cost, np.nan)
                for e in episodes
            ]
        ),
        "turnpike_distance": np.stack([e.turnpike_distance() for e in episodes]),
        "target": np.stack([e.target for e in episodes]),
        "turnpike_time": np.array([e.turnpike_time for e in episodes]),
    }


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


def _same_seeds(costs: pd.Series, other: pd.Series) -> tuple[np.ndarray, np.ndarray]:
    """Two policies' costs (indexed by seed) on the seeds both have, as aligned arrays."""
    common = costs.index.intersection(other.index)
    return costs.loc[common].to_numpy(float), other.loc[common].to_numpy(float)


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
    rows = []
    ref = None
    ref_diverged = False
    if reference is not None and reference in set(episodes["policy"]):
        ref_rows = episodes[episodes["policy"] == reference]
        ref = ref_rows.set_index("seed")["total_cost"]
        ref_diverged = bool(ref_rows["diverged"].astype(bool).any())
    best = None
    if optimum is not None and optimum in set(episodes["policy"]):
        best_rows = episodes[episodes["policy"] == optimum]
        best = best_rows.set_index("seed")["total_cost"]
        if bool(best_rows["diverged"].astype(bool).any()):
            best = best * float("nan")
    for policy, group in episodes.groupby("policy", sort=False):
        costs = group.set_index("seed")["total_cost"]
        policy_diverged = bool(group["diverged"].astype(bool).any())
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
            own, theirs = _same_seeds(costs, ref)
            pm, pl, ph = mean_confidence_interval(own / theirs, confidence)
            row.update(paired_ratio=pm, paired_ratio_ci_low=pl, paired_ratio_ci_high=ph)
            if ref_diverged or policy_diverged:
                for key in (
                    "ratio_to_reference",
                    "paired_ratio",
                    "paired_ratio_ci_low",
                    "paired_ratio_ci_high",
                ):
                    row[key] = float("nan")
        if best is not None:
            own, optimal = _same_seeds(costs, best)
            gaps = (own - optimal) / optimal
            if policy_diverged:
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
