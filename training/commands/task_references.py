"""Make, check and write the reference data of the benchmark's tasks.

    agent-envs tasks --regenerate agent_envs/StiffSwarm-v0 --workers 2   # ~5 min on 2 cores
    agent-envs tasks --verify agent_envs/StiffSwarm-v0 --verify-seeds 2   # re-solve, compare

For each test seed of a task (`agent_envs.tasks.catalog.TaskSpec.test_seeds`) one episode of the
task env (its default interface) is run per reference controller (`TaskSpec.references`, built
with `agent_envs.baselines.make_baseline` and its defaults: beta = 12, delta = 2e-4 for the
turnpike-type laws; the optimal controller solves on 20 Brownian paths of its own, seed 0,
gtol 1e-6; MPC re-solves that problem at every step with 15 iterations); its cost is minus the
sum of the rewards. The `lower_bound` reference is `agent_envs.tasks.bounds.centre_lower_bound`
of the seed's zero-control episode; it is computed for every symmetric-kernel task (a
diagnostic where it is not the yardstick: how tight it is against the optimum).

Seeds run in worker processes (`concurrent.futures`, one BLAS and torch thread each: the seeds
are independent jobs on one machine, which a process pool covers without a Ray dependency);
each seed's record is written to ``WORK/Name-vN/SEED.json`` as soon as it is done, so an
interrupted regeneration resumes where it stopped. The assembled file and its hash go to the
package's data folder (`agent_envs.tasks.references`).
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from agent_envs.tasks.bounds import centre_lower_bound
from agent_envs.tasks.catalog import TaskSpec, get_task
from agent_envs.tasks.references import (
    REFERENCE_FORMAT,
    data_dir,
    load_references,
    sha256_hex,
    write_hash,
)
from agent_envs.training.storage import write_text_atomic

#: Relative tolerance of `verify`: a re-solve must match the shipped cost to this.
VERIFY_RTOL = 1e-5
#: References that solve an optimization (the others are closed-form feedback laws).
SOLVED = ("optimal", "mpc")


def _run_episode(env: Any, policy: Any, seed: int) -> tuple[float, bool, list[np.ndarray]]:
    """(cost, diverged, positions at steps 0..m) of one episode of `policy` on `seed`."""
    obs, info = env.reset(seed=seed)
    positions = [np.array(info["positions"])]
    cost, done, diverged = 0.0, False, False
    while not done:
        action, _ = policy.predict(obs, deterministic=True)
        obs, reward, terminated, truncated, info = env.step(action)
        cost -= float(reward)
        positions.append(np.array(info["positions"]))
        diverged = diverged or bool(info.get("diverged", False))
        done = terminated or truncated
    return cost, diverged, positions


def _solver_record(controller: Any, name: str, seconds: float) -> dict[str, Any]:
    """What the solver did: iterations, gradient, convergence (optimal) or solves (mpc)."""
    res = controller.last_result
    record: dict[str, Any] = {"wall_time_s": round(seconds, 3), "plan_paths": controller.n_paths}
    if name == "optimal":
        record.update(
            objective=float(res.cost),
            converged=bool(res.converged),
            iterations=int(res.iterations),
            evaluations=int(res.evaluations),
            relative_gradient_norm=float(res.relative_gradient_norm),
            gtol=float(controller.gtol),
            plan_seed=int(controller.seed),
            max_abs_control=float(np.abs(res.controls).max()),
        )
    else:
        record.update(
            solves=int(controller.solves), iterations_per_resolve=controller.step_iterations
        )
    return record


def seed_record(task_id: str, seed: int, names: Sequence[str] | None = None) -> dict[str, Any]:
    """The references' costs (and solver records) of one test seed of a task.

    `names` restricts the references run (default: all of the task's).
    """
    import gymnasium as gym

    from agent_envs.baselines import make_baseline

    task = get_task(task_id)
    names = tuple(names or task.references)
    env = gym.make(task.id)
    costs: dict[str, float] = {}
    solver: dict[str, Any] = {}
    diverged: list[str] = []
    for name in names:
        if name == "lower_bound":
            continue
        controller = make_baseline(name, env)
        start = time.perf_counter()
        cost, div, _ = _run_episode(env, controller, seed)
        costs[name] = cost
        if div:
            diverged.append(name)
        if name in SOLVED:
            solver[name] = _solver_record(controller, name, time.perf_counter() - start)
    if task.env_kwargs.get("kernel") == "symmetric":
        _, _, positions = _run_episode(env, make_baseline("zero", env), seed)
        unwrapped = env.unwrapped
        costs["lower_bound"] = centre_lower_bound(
            positions[0][0],
            np.stack(positions),
            unwrapped.params.target_vector,
            unwrapped.dt,
            unwrapped.params.gamma,
        )
    env.close()
    return {"seed": int(seed), "costs": costs, "solver": solver, "diverged": diverged}


def _worker(task_id: str, seed: int, path: str) -> str:
    """One seed in a worker process: one BLAS and torch thread, the record written at once."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        try:
            import torch

            torch.set_num_threads(1)
        except ImportError:
            pass
        record = seed_record(task_id, seed)
    write_text_atomic(Path(path), json.dumps(record, indent=1))
    return path


def _git_commit() -> str | None:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            timeout=10,
            cwd=Path(__file__).resolve().parent,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None if out.returncode == 0 else None


def _provenance(command: str) -> dict[str, Any]:
    import agent_envs

    versions = {"agent_envs": agent_envs.__version__, "numpy": np.__version__}
    try:
        import torch

        versions["torch"] = torch.__version__
    except ImportError:
        pass
    return {
        "command": command,
        "commit": _git_commit(),
        "date": datetime.now(timezone.utc).strftime("%Y-%m-%d"),
        "machine": f"{platform.machine()}, {os.cpu_count()} CPUs, {platform.system()}",
        "versions": versions,
    }


def assemble(task: TaskSpec, records: Sequence[dict[str, Any]], command: str) -> str:
    """The reference file's text from the seeds' records (in the task's seed order)."""
    by_seed = {int(r["seed"]): r for r in records}
    missing = [s for s in task.test_seeds if s not in by_seed]
    if missing:
        raise ValueError(f"{task.id}: no record for seeds {missing}")
    rows = []
    for seed in task.test_seeds:
        r = by_seed[seed]
        if r.get("diverged"):
            raise ValueError(f"{task.id} seed {seed}: {r['diverged']} diverged")
        rows.append(r)
    data = {
        "format": REFERENCE_FORMAT,
        "task": task.id,
        "env_kwargs": json.loads(json.dumps(dict(task.env_kwargs))),
        "yardstick": task.yardstick,
        "references": list(task.references),
        "generated": _provenance(command),
        "seeds": rows,
    }
    return json.dumps(data, indent=1) + "\n"


def regenerate(
    task_id: str,
    work_dir: Path,
    *,
    workers: int = 1,
    out_dir: Path | None = None,
    progress: Callable[[str], None] | None = print,
) -> Path:
    """Compute every test seed's references of a task (resuming from `work_dir`), write the
    file and its hash into `out_dir` (default: the package's data folder). Returns its path."""
    task = get_task(task_id)
    folder = Path(work_dir) / task.file_stem
    folder.mkdir(parents=True, exist_ok=True)
    todo = [s for s in task.test_seeds if not (folder / f"{s}.json").is_file()]
    if progress:
        progress(f"{task.id}: {len(task.test_seeds) - len(todo)} seeds done, {len(todo)} to run")
    if todo:
        with ProcessPoolExecutor(max_workers=max(1, workers)) as pool:
            futures = [pool.submit(_worker, task.id, s, str(folder / f"{s}.json")) for s in todo]
            for done, future in enumerate(as_completed(futures), 1):
                path = future.result()
                if progress:
                    progress(f"{task.id}: {Path(path).stem} done ({done}/{len(todo)})")
    records = [json.loads((folder / f"{s}.json").read_text()) for s in task.test_seeds]
    text = assemble(task, records, f"agent-envs tasks --regenerate {task.id}")
    out_dir = Path(out_dir or data_dir())
    path = out_dir / f"{task.file_stem}.json"
    write_text_atomic(path, text)
    write_hash(path.name, sha256_hex(text.encode()), out_dir)
    return path


def verify(task_id: str, n_seeds: int = 2, rtol: float = VERIFY_RTOL) -> list[dict[str, Any]]:
    """Re-solve the solved references (and recompute the bound) on the first `n_seeds` test
    seeds and compare with the shipped costs. Returns one row per (seed, reference) with
    ``ok = |new - shipped| <= rtol |shipped|``."""
    task = get_task(task_id)
    shipped = load_references(task)
    names = [n for n in task.references if n in SOLVED]
    rows = []
    for seed in task.test_seeds[:n_seeds]:
        record = seed_record(task.id, seed, names or ("zero",))
        for name, value in record["costs"].items():
            if name not in shipped.costs:
                continue
            old = shipped.cost(name, seed)
            rel = abs(value - old) / abs(old)
            rows.append(
                {
                    "seed": seed,
                    "reference": name,
                    "shipped": old,
                    "now": value,
                    "relative_difference": rel,
                    "ok": rel <= rtol,
                }
            )
    return rows


__all__ = ["SOLVED", "VERIFY_RTOL", "assemble", "regenerate", "seed_record", "verify"]
