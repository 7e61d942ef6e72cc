"""Kill a batch run with SIGKILL halfway (for the test and the benchmark)."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import time
from pathlib import Path


def finished(db: Path) -> int:
    """Rows committed in a results database (0 before it exists)."""
    if not db.exists():
        return 0
    try:
        with sqlite3.connect(db, timeout=5) as con:
            return con.execute("SELECT count(*) FROM results").fetchone()[0]
    except sqlite3.OperationalError:  # the schema is not there yet
        return 0


def kill_halfway(command: list[str], db: Path, count: int, timeout: float = 600) -> int:
    """Run ``command`` (a ``kanagen batch`` writing to ``db``) and SIGKILL it — the parent,
    the one writer — once ``count // 2`` datasets are in ``db``; its worker processes are
    killed after it. Returns the rows committed at the kill."""
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + timeout
        while finished(db) < count // 2:
            if proc.poll() is not None:
                raise RuntimeError("the batch ended before halfway:\n"
                                   + proc.stdout.read().decode())
            if time.monotonic() > deadline:
                raise RuntimeError("the batch did not get halfway in time")
            time.sleep(0.02)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=60)
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)  # its workers, if they outlive it
        except ProcessLookupError:
            pass
        proc.stdout.close()
    return finished(db)
