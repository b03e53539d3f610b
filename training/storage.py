"""Where the training layer writes, and how: output folders, run directories, atomic files and
the run manifest of SHA-256 hashes.

- `check_output_dir`: an output option (``--out``) must name a folder that exists or can be
  created and written; checked before any work starts.
- `create_run_directory`: a run directory is created with an exclusive ``os.mkdir``, so two
  processes never share one; `RunLock` (an ``fcntl.flock`` on ``RUN/.lock``, released by the
  kernel when the process dies, even on SIGKILL) keeps a second ``--resume`` of the same run out.
- `atomic_path` / `write_text_atomic` / `write_json_atomic`: a file appears whole or not at all
  (written to a temporary file in the same folder, flushed to disk, then ``os.replace``\\ d).
- `RunManifest`: ``RUN/manifest.json`` records the SHA-256 and size of every model, statistics
  and replay-buffer file the run saves (`save_recorded`). Pickles are code: a statistics file is
  unpickled only when the user named it, or when the manifest of the run that wrote it records
  its hash (`agent_envs.training.learners.policies`), and ``--resume`` uses only checkpoints whose
  files match their hashes (`agent_envs.training.learners.checkpoints`).

Standard library only: the core-only subcommands use it without the ``train`` extra.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

#: The manifest file of a run directory.
MANIFEST = "manifest.json"
#: The lock file of a run directory (held while a process trains in it).
LOCK = ".lock"
#: Part of the name of every temporary file of `atomic_path` (``.NAME.tmp-RANDOM.SUFFIX``).
TEMPORARY_MARK = ".tmp-"
_MANIFEST_FORMAT = "agent-envs run manifest"
_MANIFEST_VERSION = 1


class RunDirectoryBusy(ValueError):
    """The run directory exists already or another process holds its lock."""


# ------------------------------------------------------------------------------ output folders


def check_output_dir(path: str | os.PathLike, option: str = "--out") -> Path:
    """`path` if it is a folder, or can be created as one, that this process may write.

    Walks up to the nearest existing ancestor: it must be a folder with write and search
    permission, and nothing on the way may be a file. Raises ValueError naming `option`.
    Creates nothing.
    """
    target = Path(path)
    if str(path) == "":
        raise ValueError(f"{option} must name a folder, got an empty path")
    if target.exists() and not target.is_dir():
        raise ValueError(f"{option} {target}: exists and is not a folder")
    probe = target
    while not probe.exists():
        if probe.parent == probe:
            break
        probe = probe.parent
    if probe.exists() and not probe.is_dir():
        raise ValueError(f"{option} {target}: {probe} is a file, so the folder cannot be created")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise ValueError(f"{option} {target}: no permission to write in {probe}")
    return target


def create_run_directory(path: str | os.PathLike) -> Path:
    """Create the run directory `path` exclusively (its parents as needed); return it.

    Raises `RunDirectoryBusy` when it exists already: another run (maybe running now) owns it.
    """
    run_dir = Path(path)
    run_dir.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.mkdir(run_dir)
    except FileExistsError:
        raise RunDirectoryBusy(
            f"run directory {run_dir} exists already (another `agent-envs train` may be writing "
            f"it); continue it with --resume {run_dir}, or choose another --run-name or --seed"
        ) from None
    return run_dir


class RunLock:
    """An exclusive lock on a run directory for the life of one training process.

    ``fcntl.flock`` on ``RUN/.lock``: the kernel releases it when the process exits or is killed,
    so a crashed run never leaves a stale lock. Where ``fcntl`` is missing (Windows) the lock
    file is created with ``O_EXCL`` and removed on release.
    """

    def __init__(self, run_dir: str | os.PathLike) -> None:
        self.path = Path(run_dir) / LOCK
        self._fd: int | None = None

    def acquire(self) -> RunLock:
        busy = RunDirectoryBusy(
            f"run directory {self.path.parent} is in use by another `agent-envs train` process; "
            "wait for it to finish (or stop it) before resuming"
        )
        try:
            import fcntl
        except ImportError:  # pragma: no cover - Windows
            try:
                self._fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            except FileExistsError:
                raise busy from None
            return self
        fd = os.open(self.path, os.O_CREAT | os.O_RDWR, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise busy from None
        self._fd = fd  # the file stays empty: taking the lock changes nothing in the run
        return self

    def release(self) -> None:
        if self._fd is None:
            return
        os.close(self._fd)  # closing the descriptor drops the flock
        self._fd = None
        try:
            import fcntl  # noqa: F401
        except ImportError:  # pragma: no cover - Windows
            self.path.unlink(missing_ok=True)

    def __enter__(self) -> RunLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


# -------------------------------------------------------------------------------- atomic files


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path next to `path` (same suffix); on success it replaces `path`.

    The temporary file is flushed to disk before ``os.replace`` (atomic on POSIX and Windows
    within one folder), so readers see the old file or the new one, never a part. On an
    exception the temporary file is removed and `path` is left as it was.
    """
    final = Path(path)
    fd, name = tempfile.mkstemp(
        dir=final.parent, prefix=f".{final.name}{TEMPORARY_MARK}", suffix=final.suffix
    )
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        with open(tmp, "rb+") as handle:
            os.fsync(handle.fileno())
        os.replace(tmp, final)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def remove_stale_temporaries(folder: str | os.PathLike) -> list[Path]:
    """Delete the temporary files `atomic_path` left in `folder` when its process was killed.

    Call it only while holding the folder's run lock (no other process is writing there).
    Returns the deleted paths.
    """
    stale = sorted(Path(folder).glob(f".*{TEMPORARY_MARK}*"))
    for path in stale:
        if path.is_file():
            path.unlink()
    return stale


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write `text` to `path` atomically (`atomic_path`)."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def write_json_atomic(path: str | os.PathLike, data: Any) -> None:
    """Write `data` as indented JSON to `path` atomically."""
    write_text_atomic(path, json.dumps(data, indent=2, default=str) + "\n")


# ------------------------------------------------------------------------------------ manifest


def sha256_file(path: str | os.PathLike) -> str:
    """The SHA-256 hex digest of a file (read in 1 MiB blocks)."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


class RunManifest:
    """``RUN/manifest.json``: {relative path: {"sha256", "bytes"}} of the files a run saved.

    Only the process holding the run's lock writes it; every write is atomic.
    """

    def __init__(self, run_dir: str | os.PathLike) -> None:
        self.run_dir = Path(run_dir)
        self.path = self.run_dir / MANIFEST

    def exists(self) -> bool:
        return self.path.is_file()

    def files(self) -> dict[str, dict[str, Any]]:
        """The recorded entries ({} when there is no manifest or it is unreadable)."""
        try:
            data = json.loads(self.path.read_text())
        except (OSError, ValueError):
            return {}
        if not isinstance(data, dict) or data.get("format") != _MANIFEST_FORMAT:
            return {}
        files = data.get("files")
        return files if isinstance(files, dict) else {}

    def relative(self, path: str | os.PathLike) -> str | None:
        """`path` relative to the run directory (posix), or None if it lies outside."""
        try:
            rel = Path(path).resolve().relative_to(self.run_dir.resolve())
        except ValueError:
            return None
        return rel.as_posix()

    def _write(self, files: dict[str, dict[str, Any]]) -> None:
        data = {"format": _MANIFEST_FORMAT, "version": _MANIFEST_VERSION, "files": files}
        write_json_atomic(self.path, data)

    def record(self, path: str | os.PathLike, sha256: str, size: int) -> None:
        """Record the hash and size of a file inside the run directory."""
        rel = self.relative(path)
        if rel is None:
            raise ValueError(f"{path} is not inside the run directory {self.run_dir}")
        files = self.files()
        files[rel] = {"sha256": sha256, "bytes": int(size)}
        self._write(files)

    def forget(self, paths: list[Path]) -> None:
        """Drop the entries of deleted files."""
        files = self.files()
        rels = {self.relative(p) for p in paths}
        kept = {k: v for k, v in files.items() if k not in rels}
        if len(kept) != len(files):
            self._write(kept)

    def problem(self, path: str | os.PathLike) -> str | None:
        """Why `path` does not match its record (None: it matches)."""
        rel = self.relative(path)
        entry = self.files().get(rel) if rel is not None else None
        if entry is None:
            return f"{Path(path).name} is not recorded in {self.path}"
        file = Path(path)
        if not file.is_file():
            return f"{file.name} is missing"
        size = file.stat().st_size
        if size != entry.get("bytes"):
            return f"{file.name} has {size} bytes, the manifest recorded {entry.get('bytes')}"
        if sha256_file(file) != entry.get("sha256"):
            return f"the SHA-256 of {file.name} differs from the one in the manifest"
        return None


def find_manifest(path: str | os.PathLike, levels: int = 2) -> RunManifest | None:
    """The manifest of the run directory holding `path` (its folder or up to `levels` above)."""
    folder = Path(path).resolve().parent
    for _ in range(levels + 1):
        manifest = RunManifest(folder)
        if manifest.exists():
            return manifest
        if folder.parent == folder:
            break
        folder = folder.parent
    return None


def save_recorded(
    run_dir: str | os.PathLike, path: str | os.PathLike, write: Callable[[Path], None]
) -> Path:
    """Save a run file atomically with `write(temporary path)` and record its hash."""
    final = Path(path)
    with atomic_path(final) as tmp:
        write(tmp)
        digest, size = sha256_file(tmp), tmp.stat().st_size
    RunManifest(run_dir).record(final, digest, size)
    return final
