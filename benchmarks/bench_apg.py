"""The `apg` learner against the optimum: per-seed gaps, training time, other N, contrasts.

Parts (``--parts``, any subset; every result is cached under ``--out`` and reused, so the
script can be stopped and run again, part by part, on a small machine):

- ``paper``: train at the sweep's paper setting (`agent_envs.training.commands.presets.PAPER_ENV`:
  N = 100, m = 50, 20 paths, eps = 0.05, alpha = 0.1, sigma = 0.01, T = 1, xbar = 0.7, SERB,
  max_control = 25) for each training seed; evaluate the best law on the test seeds
  10000..10019 in the env (`agent_envs.training.commands.evaluate.evaluate_policies`, the published
  study's rollouts) next to the references "optimal" (V: the optimal open-loop plan of
  `solve_optimal_control`, solved from each episode's start, the published study's 'gap to
  optimal') and "proportional"; per-seed gap = (cost - V) / V.
- ``quick``: the same at N = 10, m = 20.
- ``across-n``: the laws trained at N = 100 evaluated unchanged at N = 20, 1000 and 10^4
  (N = 10^4 with ``linear_operator = "matrix_free"``): gap to the optimum where it is solved
  (``--optimal-at``; default N = 20 only: at N = 1000 one cost + gradient evaluation of even
  the noise-free problem took 124 s here, and L-BFGS needs hundreds) and the ratio to the
  proportional controller at every N.
- ``eps1``: train and evaluate at eps = 1 (the non-stiff kernel).
- ``em-serb``: train on Euler-Maruyama, evaluate on SERB (the paper env). At eps = 0.05, EM
  is unstable for tau = 1/50 (tau |lambda| > 2): its states stay bounded but its gradient is
  1e15-1e16 (part ``gradient``), so training only raises the EM cost and the best law kept is the
  initial one; the part records what happened.
- ``em-serb-eps1``: the same at eps = 1, where EM is stable and its gradient finite.
- ``paper-linear``: the paper setting with the linear law alone (``hidden = 0``: time-varying
  gains on the centre's offset, the agent's offset and the interaction drift), an ablation.
- ``gradient``: the gradient's norm at the initial law, SERB and EM, eps = 0.05 and 1.

    OPENBLAS_NUM_THREADS=1 nice -n 5 python benchmarks/bench_apg.py --out /tmp/bench-apg \
        --parts paper quick across-n eps1 em-serb --seeds 0 1 2

Prints Markdown tables; writes ``{out}/results.json`` and, one row per test episode of every
evaluated law (its cost, the optimum's and the proportional law's), ``{out}/episodes.csv``
(`agent_envs.training.results.apg_episodes`, whose functions of those rows give the gaps and
ratios of results.json). docs/learners/apg.md's tables: ``--out docs/results/apg --parts paper
quick across-n`` and ``--parts paper-linear --seeds 0`` (about 46 min on the shared 2-core
machine: 89 s, 17, 18 and 10 min, the parts' ``part_wall_time_s`` in results.json).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import sys
import time
import traceback
from pathlib import Path
from typing import Any

import numpy as np
import torch

from agent_envs.training.commands.evaluate import evaluate_policies
from agent_envs.training.commands.presets import PAPER_ENV
from agent_envs.training.defaults import DEFAULT_TEST_SEED
from agent_envs.training.learners.apg import load_apg_policy, train_apg
from agent_envs.training.learners.apg_config import APGConfig
from agent_envs.training.results.apg_episodes import (
    ACROSS_N,
    EPISODES_FILE,
    episode_rows,
    gap_stats,
    law_figures,
)
from agent_envs.training.results.episode_csv import read_rows, write_rows
from agent_envs.training.results.tables import EvaluationResults

QUICK_ENV = {**PAPER_ENV, "n_agents": 10, "n_steps": 20}
PARTS = (
    "paper",
    "quick",
    "across-n",
    "eps1",
    "em-serb",
    "em-serb-eps1",
    "paper-linear",
    "gradient",
)
EPS1_ENV = {**PAPER_ENV, "epsilon": 1.0}


def cached_evaluation(folder: Path, policies: dict[str, Any], env_kwargs, seeds) -> Any:
    """`evaluate_policies` saved in `folder`, or its saved results when they are there."""
    if (folder / "meta.json").is_file():
        return EvaluationResults.load(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    return evaluate_policies(
        policies, env_kwargs=env_kwargs, seeds=seeds, progress=False, out_dir=folder
    )


def reference_folder(out: Path, env_kwargs: dict, n_seeds: int) -> Path:
    """Where the references of one evaluation env are cached (shared by the parts)."""
    key = json.dumps(env_kwargs, sort_keys=True) + f"|{n_seeds}"
    return out / "refs" / hashlib.sha256(key.encode()).hexdigest()[:12]


def costs_by_seed(results: Any, policy: str) -> dict[int, float]:
    df = results.episodes[results.episodes.policy == policy]
    return {int(s): float(c) for s, c in zip(df.seed, df.total_cost, strict=True)}


def train(out: Path, setting: str, env_kwargs: dict, seed: int, args) -> dict[str, Any]:
    """The summary of the run (trained now, resumed, or read from its folder)."""
    run = out / "runs" / setting / f"seed{seed}"
    if (run / "summary.json").is_file():
        return json.loads((run / "summary.json").read_text())
    config = APGConfig(
        env_kwargs=env_kwargs,
        seed=seed,
        iterations=args.iterations,
        train_paths=args.train_paths,
        hidden=0 if setting == "paper-linear" else args.hidden,
        progress=False,
    )
    print(f"[{setting}] training seed {seed} -> {run}", flush=True)
    return train_apg(config, run, resume=run.exists())


def evaluate_law(out: Path, name: str, run: Path, env_kwargs: dict, seeds) -> dict[int, float]:
    policy = load_apg_policy(run)
    results = cached_evaluation(out / "evals" / name, {"apg": policy}, env_kwargs, seeds)
    return costs_by_seed(results, "apg")


def learned_setting(out: Path, setting: str, train_kwargs: dict, eval_kwargs: dict, args) -> dict:
    """Train every seed, evaluate on the test seeds, gaps to optimal and proportional."""
    seeds = list(range(DEFAULT_TEST_SEED, DEFAULT_TEST_SEED + args.test_seeds))
    summaries: dict[int, Any] = {}
    for seed in args.seeds:  # training first: the references' solves can run beside it
        try:
            summaries[seed] = train(out, setting, train_kwargs, seed, args)
        except (FloatingPointError, RuntimeError, ValueError) as exc:
            summaries[seed] = f"{type(exc).__name__}: {exc}"
            print(f"[{setting}] seed {seed} failed: {exc}", flush=True)
    refs = cached_evaluation(
        reference_folder(out, eval_kwargs, len(seeds)),
        ["optimal", "proportional"],
        eval_kwargs,
        seeds,
    )
    optimum, proportional = costs_by_seed(refs, "optimal"), costs_by_seed(refs, "proportional")
    rows, episodes = [], []
    for seed, summary in summaries.items():
        if isinstance(summary, str):
            rows.append({"seed": seed, "failed": summary})
            continue
        run = Path(summary["run_dir"])
        costs = evaluate_law(out, f"{setting}/seed{seed}", run, eval_kwargs, seeds)
        law = episode_rows(setting, eval_kwargs["n_agents"], seed, costs, optimum, proportional)
        episodes += law
        figures = law_figures(law)
        rows.append(
            {
                "seed": seed,
                "gap": figures["gap"],
                "ratio_to_proportional": figures["ratio_to_proportional"],
                "mean_cost": figures["mean_cost"],
                "wall_time_s": summary["wall_time_s"],
                "cpu_time_s": summary.get("cpu_time_s"),
                "best_validation_cost": summary["best_validation_cost"],
            }
        )
    return {
        "train_env": train_kwargs,
        "eval_env": eval_kwargs,
        "optimal_mean_cost": float(np.mean(list(optimum.values()))),
        "proportional_gap": gap_stats(proportional, optimum),
        "runs": rows,
        "episodes": episodes,  # main writes them to episodes.csv, not to results.json
    }


def across_n(out: Path, args) -> dict:
    rows, episodes = [], []
    for n in args.across_n:
        kwargs = {**PAPER_ENV, "n_agents": n}
        if n >= 5000:
            kwargs["linear_operator"] = "matrix_free"
        count = args.test_seeds if n <= 100 else args.across_n_seeds
        seeds = list(range(DEFAULT_TEST_SEED, DEFAULT_TEST_SEED + count))
        refs_wanted = ["proportional"] + (["optimal"] if n in args.optimal_at else [])
        refs = cached_evaluation(
            reference_folder(out, kwargs, len(seeds)), refs_wanted, kwargs, seeds
        )
        proportional = costs_by_seed(refs, "proportional")
        optimum = costs_by_seed(refs, "optimal") if "optimal" in refs_wanted else None
        for seed in args.seeds:
            run = out / "runs" / "paper" / f"seed{seed}"
            if not (run / "summary.json").is_file():
                print(f"[across-n] no trained paper run for seed {seed}; run --parts paper first")
                continue
            start = time.perf_counter()
            costs = evaluate_law(out, f"N{n}-{len(seeds)}seeds/seed{seed}", run, kwargs, seeds)
            law = episode_rows(ACROSS_N, n, seed, costs, optimum, proportional)
            episodes += law
            figures = law_figures(law)
            row = {
                "n_agents": n,
                "seed": seed,
                "test_seeds": len(seeds),
                "ratio_to_proportional": figures["ratio_to_proportional"],
                "eval_wall_time_s": round(time.perf_counter() - start, 1),
            }
            if optimum is not None:
                row["gap"] = figures["gap"]
                row["proportional_gap"] = figures["proportional_gap"]["mean"]
            rows.append(row)
    return {"rows": rows, "episodes": episodes}


def gradient_norms(args) -> dict:
    """|dJ/dtheta| at the initial (proportional) law on one training episode (4 paths), per
    integrator and eps: where the gradient through the integrator is usable."""
    from agent_envs.envs.episode_config import EpisodeConfig
    from agent_envs.training.learners.apg_policy import SwarmFeedbackLaw
    from agent_envs.training.learners.apg_rollout import ClosedLoop, EpisodeNoise

    rows = []
    for eps in (0.05, 1.0):
        for integrator in ("serb", "em"):
            kwargs = {**PAPER_ENV, "epsilon": eps, "integrator": integrator, "n_paths": 4}
            config = EpisodeConfig.from_kwargs(**kwargs)
            law = SwarmFeedbackLaw(APGConfig(env_kwargs=kwargs, progress=False).law_spec())
            for seed in (0, 1):
                noise = EpisodeNoise.draw(np.random.default_rng(seed), config)
                cost, diverged = ClosedLoop(config).cost(law, noise)
                law.zero_grad()
                if not diverged:
                    cost.backward()
                norm = (
                    math.sqrt(
                        sum(
                            float((p.grad**2).sum()) for p in law.parameters() if p.grad is not None
                        )
                    )
                    if not diverged
                    else math.nan
                )
                rows.append(
                    {
                        "epsilon": eps,
                        "integrator": integrator,
                        "seed": seed,
                        "cost": float(cost.detach()),
                        "diverged": bool(diverged),
                        "grad_norm": norm,
                    }
                )
    return {"rows": rows}


def pct(x: float) -> str:
    return f"{100 * x:+.2f}%"


def print_setting(name: str, result: dict) -> None:
    print(
        f"\n### {name}: optimum mean cost {result['optimal_mean_cost']:.5g}, proportional "
        f"gap {pct(result['proportional_gap']['mean'])}"
    )
    print(
        "| training seed | gap to optimal, mean [min, max] over test seeds | ratio to "
        "proportional | training wall / CPU time |"
    )
    print("|---|---|---|---|")
    for row in result["runs"]:
        if "failed" in row:
            print(f"| {row['seed']} | failed: {row['failed']} | | |")
            continue
        g = row["gap"]
        cpu = row.get("cpu_time_s")
        cpu_text = f"{cpu / 60:.1f} min" if cpu is not None else "n/a"
        print(
            f"| {row['seed']} | {pct(g['mean'])} [{pct(g['min'])}, {pct(g['max'])}] | "
            f"{row['ratio_to_proportional']:.4f} | {row['wall_time_s'] / 60:.1f} / {cpu_text} |"
        )


def print_across(result: dict) -> None:
    print("\n### across N (laws trained at N = 100)")
    print(
        "| N | training seed | test seeds | gap to optimal | proportional's gap | ratio to "
        "proportional |"
    )
    print("|---|---|---|---|---|---|")
    for row in result["rows"]:
        gap = pct(row["gap"]["mean"]) if "gap" in row else "not solved"
        prop = pct(row["proportional_gap"]) if "proportional_gap" in row else "n/a"
        print(
            f"| {row['n_agents']} | {row['seed']} | {row['test_seeds']} | {gap} | {prop} | "
            f"{row['ratio_to_proportional']:.4f} |"
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("bench-apg"))
    parser.add_argument("--parts", nargs="+", choices=PARTS, default=["paper"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--iterations", type=int, default=APGConfig.iterations)
    parser.add_argument("--train-paths", type=int, default=APGConfig.train_paths)
    parser.add_argument("--hidden", type=int, default=APGConfig.hidden)
    parser.add_argument("--test-seeds", type=int, default=20)
    parser.add_argument("--across-n", nargs="+", type=int, default=[20, 1000, 10_000])
    parser.add_argument(
        "--across-n-seeds",
        type=int,
        default=20,
        help="test seeds at N > 100 (an N = 10^4 episode took about 10 s here)",
    )
    parser.add_argument(
        "--optimal-at",
        nargs="*",
        type=int,
        default=[20],
        help="the N of the across-N part where the optimum is solved",
    )
    args = parser.parse_args(argv)
    if args.iterations < 1 or args.test_seeds < 1 or args.across_n_seeds < 1:
        parser.error("--iterations, --test-seeds and --across-n-seeds must be >= 1")
    torch.set_num_threads(1)
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "results.json"
    results = json.loads(path.read_text()) if path.is_file() else {}
    episodes_path = args.out / EPISODES_FILE
    episodes = read_rows(episodes_path) if episodes_path.is_file() else []
    jobs = {
        "paper": lambda: learned_setting(args.out, "paper", PAPER_ENV, PAPER_ENV, args),
        "quick": lambda: learned_setting(args.out, "quick", QUICK_ENV, QUICK_ENV, args),
        "eps1": lambda: learned_setting(args.out, "eps1", EPS1_ENV, EPS1_ENV, args),
        "em-serb": lambda: learned_setting(
            args.out, "em-serb", {**PAPER_ENV, "integrator": "em"}, PAPER_ENV, args
        ),
        "paper-linear": lambda: learned_setting(
            args.out, "paper-linear", PAPER_ENV, PAPER_ENV, args
        ),
        "em-serb-eps1": lambda: learned_setting(
            args.out, "em-serb-eps1", {**EPS1_ENV, "integrator": "em"}, EPS1_ENV, args
        ),
        ACROSS_N: lambda: across_n(args.out, args),
        "gradient": lambda: gradient_norms(args),
    }
    for part in args.parts:
        began = time.perf_counter()
        try:
            results[part] = jobs[part]()
        except Exception:
            traceback.print_exc()
            continue
        results[part]["part_wall_time_s"] = round(time.perf_counter() - began, 1)
        if "episodes" in results[part]:  # the part's rows replace its rows of a former run
            rows = results[part].pop("episodes")
            episodes = [r for r in episodes if r["part"] != part] + rows
            if episodes:
                write_rows(episodes_path, episodes)
        path.write_text(json.dumps(results, indent=2))
    for part in PARTS:
        if part not in results:
            continue
        if part == "across-n":
            print_across(results[part])
        elif part == "gradient":
            print("\n### gradient norm at the initial law (N = 100, 4 paths)")
            for row in results[part]["rows"]:
                print(row)
        else:
            print_setting(part, results[part])
    return 0 if all(p in results for p in args.parts) else 1


if __name__ == "__main__":
    sys.exit(main())
