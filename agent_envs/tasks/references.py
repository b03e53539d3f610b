"""The reference data shipped with each task: per test seed, what the references cost.

One JSON file per task version in the package (``agent_envs/tasks/data/Name-vN.json``), written
by `agent-envs tasks --regenerate ID` (`agent_envs.training.commands.task_references`), and one line
per file in ``data/SHA256SUMS`` (``sha256sum`` format): the hash recorded in the package. Every
load recomputes the file's SHA-256 and refuses a file that does not match, so a score is never
computed against edited or corrupted references. Scoring reads these numbers and never
re-solves anything (numpy only, no torch).

The file holds, per test seed, the cost of each reference of the task (`TaskSpec.references`)
on that seed's episode of the task env, and for the solved references their solver record
(L-BFGS-B iterations, evaluations, relative projected gradient, converged, the planning
objective on the solver's own paths, wall time).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from agent_envs.tasks.catalog import TaskSpec, get_task

#: Version of the reference file layout.
REFERENCE_FORMAT = 1
#: The file of recorded hashes, beside the data files.
HASH_FILE = "SHA256SUMS"


def data_dir() -> Path:
    """The folder of the shipped reference files (inside the installed package)."""
    return Path(str(resources.files("agent_envs.tasks") / "data"))


def sha256_hex(data: bytes) -> str:
    """The SHA-256 of `data` as 64 hex digits."""
    return hashlib.sha256(data).hexdigest()


def recorded_hashes(folder: Path | None = None) -> dict[str, str]:
    """{file name: hex digest} of ``SHA256SUMS`` (empty if the file is absent)."""
    path = (folder or data_dir()) / HASH_FILE
    if not path.is_file():
        return {}
    out: dict[str, str] = {}
    for line in path.read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        digest, name = line.split(maxsplit=1)
        out[name.lstrip("*")] = digest
    return out


def write_hash(name: str, digest: str, folder: Path | None = None) -> None:
    """Record `digest` for the file `name` in ``SHA256SUMS`` (other lines kept, sorted)."""
    folder = folder or data_dir()
    hashes = recorded_hashes(folder)
    hashes[name] = digest
    lines = [f"{hashes[k]}  {k}" for k in sorted(hashes)]
    (folder / HASH_FILE).write_text("\n".join(lines) + "\n")


@dataclass(frozen=True)
class TaskReferences:
    """The references of one task on its test seeds.

    Attributes:
        task: the task.
        seeds: the test seeds, in the file's order (the task's `test_seeds`).
        costs: reference name -> (n_seeds,) costs, aligned with `seeds`.
        solver: reference name -> one record per seed (the solved references only).
        generated: how the file was made (command, version, commit, date, machine).
        sha256: the file's hash (the recorded one: it was checked).
    """

    task: TaskSpec
    seeds: tuple[int, ...]
    costs: dict[str, np.ndarray]
    solver: dict[str, list[dict[str, Any]]]
    generated: dict[str, Any]
    sha256: str

    @property
    def yardstick(self) -> np.ndarray:
        """V per seed: the cost of the task's yardstick reference."""
        return self.costs[self.task.yardstick]

    @property
    def zero(self) -> np.ndarray:
        """J_zero per seed: the cost of the zero control."""
        return self.costs["zero"]

    def cost(self, name: str, seed: int) -> float:
        """The cost of reference `name` on test seed `seed`."""
        return float(self.costs[name][self.seeds.index(seed)])

    def mean(self, name: str) -> float:
        """The mean cost of reference `name` over the test seeds."""
        return float(np.mean(self.costs[name]))


def parse_references(task: TaskSpec, raw: bytes, digest: str) -> TaskReferences:
    """Check and read a reference file's bytes (`raw`, whose hash is `digest`)."""
    data = json.loads(raw)
    where = f"reference data of {task.id}"
    if data.get("format") != REFERENCE_FORMAT:
        raise ValueError(f"{where}: format {data.get('format')!r}, expected {REFERENCE_FORMAT}")
    if data.get("task") != task.id:
        raise ValueError(f"{where}: the file is for {data.get('task')!r}")
    if data.get("env_kwargs") != json.loads(json.dumps(dict(task.env_kwargs))):
        raise ValueError(f"{where}: its env kwargs differ from the task's")
    rows = data["seeds"]
    seeds = tuple(int(r["seed"]) for r in rows)
    if seeds != task.test_seeds:
        raise ValueError(f"{where}: seeds {seeds} are not the task's test seeds")
    costs: dict[str, np.ndarray] = {}
    solver: dict[str, list[dict[str, Any]]] = {}
    for name in task.references:
        values = np.array([float(r["costs"][name]) for r in rows])
        if not np.all(np.isfinite(values)) or np.any(values < 0):
            raise ValueError(f"{where}: {name} costs must be finite and >= 0")
        costs[name] = values
        if all(name in r.get("solver", {}) for r in rows):
            solver[name] = [dict(r["solver"][name]) for r in rows]
    for name in {k for r in rows for k in r["costs"]} - set(costs):  # extra diagnostics
        costs[name] = np.array([float(r["costs"].get(name, np.nan)) for r in rows])
    if np.any(costs["zero"] <= costs[task.yardstick]):
        raise ValueError(f"{where}: the zero control must cost more than V on every seed")
    return TaskReferences(task, seeds, costs, solver, dict(data.get("generated", {})), digest)


def load_references(task_id: str | TaskSpec, folder: Path | None = None) -> TaskReferences:
    """The shipped references of a task, after checking the file against its recorded hash.

    Args:
        task_id: a task id or `TaskSpec`.
        folder: read from here instead of the package's data folder (with its SHA256SUMS).

    Raises:
        ValueError: unknown task; no reference file for it; a file whose SHA-256 differs from
            the one recorded in ``SHA256SUMS`` (edited or corrupted: regenerate it); a file
            that does not describe the task.
    """
    task = get_task(task_id)
    folder = folder or data_dir()
    name = f"{task.file_stem}.json"
    path = folder / name
    if not path.is_file():
        raise ValueError(
            f"no reference data for {task.id} ({path}); generate it with "
            f"`agent-envs tasks --regenerate {task.id}`"
        )
    raw = path.read_bytes()
    digest = sha256_hex(raw)
    expected = recorded_hashes(folder).get(name)
    if expected is None:
        raise ValueError(f"no hash recorded for {name} in {folder / HASH_FILE}")
    if digest != expected:
        raise ValueError(
            f"reference data of {task.id} does not match the hash recorded in the package "
            f"({digest[:12]}... != {expected[:12]}...): the file was changed or is corrupted; "
            f"reinstall, or regenerate it with `agent-envs tasks --regenerate {task.id}`"
        )
    return parse_references(task, raw, digest)


def has_references(task_id: str | TaskSpec) -> bool:
    """Whether the package ships a reference file for the task."""
    task = get_task(task_id)
    return (data_dir() / f"{task.file_stem}.json").is_file()


__all__ = [
    "HASH_FILE",
    "REFERENCE_FORMAT",
    "TaskReferences",
    "data_dir",
    "has_references",
    "load_references",
    "parse_references",
    "recorded_hashes",
    "sha256_hex",
    "write_hash",
]
