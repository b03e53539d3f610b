"""The local Ray instance of a sweep: recorded while it runs, cleaned up after a killed driver.

A sweep that starts its own Ray instance (no ``--address``) writes ``OUT/ray_session.json``
(the instance's session folder and the driver's pid) and removes it when Ray shuts down. A
driver killed with SIGKILL (an out-of-memory kill, a lost terminal) cannot shut Ray down, and
some of the instance's processes outlive it (with Ray 2.60: ``ray::DashboardAgent`` and
``ray::RuntimeEnvAgent``, for 30 s and more). The next sweep in the same OUT (``--resume``)
finds the record of a driver that is gone and ends every process that still holds a file of
that session folder open (Ray's processes rename themselves, ``ray::...``, so their command
lines do not name the session; their open log files do). Processes of a cluster joined with
``--address`` are never touched: the sweep did not start them.

`psutil` (the `sweep` extra) lists the processes and their open files portably.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

#: the record of the local Ray instance a sweep started, in its OUT
RAY_SESSION_FILE = "ray_session.json"
#: seconds a process gets to end after SIGTERM before it is killed
TERMINATE_GRACE_S = 5.0


def record_session(out: Path, session_dir: str) -> None:
    """Write ``OUT/ray_session.json``: the session folder of the Ray instance this process
    (the driver) started, and its pid."""
    out.mkdir(parents=True, exist_ok=True)
    record = {"session_dir": str(session_dir), "driver_pid": os.getpid()}
    (out / RAY_SESSION_FILE).write_text(json.dumps(record) + "\n")


def forget_session(out: Path) -> None:
    """Remove the record after Ray shut down normally."""
    (out / RAY_SESSION_FILE).unlink(missing_ok=True)


def session_processes(session_dir: str) -> list[Any]:
    """The processes (psutil) other than this one holding a file under `session_dir` open."""
    import psutil

    folder = os.path.realpath(session_dir) + os.sep
    found = []
    for process in psutil.process_iter():
        if process.pid == os.getpid():
            continue
        try:
            if any(os.path.realpath(f.path).startswith(folder) for f in process.open_files()):
                found.append(process)
        except (psutil.AccessDenied, psutil.NoSuchProcess, psutil.ZombieProcess):
            continue
    return found


def clean_up_after_killed_driver(out: Path) -> int:
    """End the processes left by the local Ray instance of a killed sweep driver in `out`.

    Does nothing without a record, or while the recorded driver still runs (another sweep may
    be working in `out`). Returns how many processes were ended; the record is removed.
    """
    import psutil

    path = out / RAY_SESSION_FILE
    try:
        record = json.loads(path.read_text())
        session_dir, driver = str(record["session_dir"]), int(record["driver_pid"])
    except (OSError, ValueError, KeyError, TypeError):
        return 0
    if driver != os.getpid() and psutil.pid_exists(driver):
        try:
            if psutil.Process(driver).status() != psutil.STATUS_ZOMBIE:
                return 0
        except psutil.NoSuchProcess:
            pass
    left = session_processes(session_dir)
    end_processes(left)
    path.unlink(missing_ok=True)
    return len(left)


def end_processes(processes: list[Any]) -> None:
    """SIGTERM each process (psutil), then SIGKILL those still alive after
    `TERMINATE_GRACE_S`. Ending exactly these (and not every Ray process of the machine, as
    ``ray stop`` does) leaves other Ray instances alone."""
    import psutil

    for process in processes:
        try:
            process.terminate()
        except psutil.NoSuchProcess:
            pass
    _, alive = psutil.wait_procs(processes, timeout=TERMINATE_GRACE_S)
    for process in alive:
        try:
            process.kill()
        except psutil.NoSuchProcess:
            pass
    psutil.wait_procs(alive, timeout=TERMINATE_GRACE_S)
