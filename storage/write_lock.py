"""One writer at a time on a SQLite database, across threads and processes.

SQLite serialises writers itself, but a writer that finds the database locked waits in its
busy handler, whose sleeps grow to 100 ms: under 20 concurrent submissions that made the tail
latency ten times the median (BENCHMARKS.md, "Job submission latency"). So writers queue
here instead, where the lock is handed over as soon as it is released: first on a
re-entrant thread lock (the threads of one process), then, by the outermost holder only, on
an advisory ``flock`` of ``<database>.writelock`` (the processes: several web processes,
the job workers, the CLI). SQLite's own locking stays underneath as the guarantee; this
only removes the sleeping.

The lock file descriptor is opened per process (keyed by pid), so a forked child never
shares its parent's open file description, with which ``flock`` would not exclude it.
"""

from __future__ import annotations

import fcntl
import os
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

_GUARD = threading.Lock()
_LOCKS: dict[tuple[str, int], WriteLock] = {}


class WriteLock:
    """The write lock of one database file in this process (see the module docstring)."""

    def __init__(self, db_path: Path) -> None:
        self.path = Path(f"{db_path}.writelock")
        self._thread_lock = threading.RLock()
        self._depth = 0
        self._fd: int | None = None

    @contextmanager
    def hold(self) -> Iterator[None]:
        """Hold the lock; re-entrant within a thread."""
        with self._thread_lock:
            self._depth += 1
            try:
                if self._depth == 1:
                    if self._fd is None:
                        self._fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
                    fcntl.flock(self._fd, fcntl.LOCK_EX)
                try:
                    yield
                finally:
                    if self._depth == 1 and self._fd is not None:
                        fcntl.flock(self._fd, fcntl.LOCK_UN)
            finally:
                self._depth -= 1


def write_lock(db_path: Path) -> WriteLock:
    """This process's write lock of ``db_path`` (one per resolved path and process)."""
    key = (str(Path(db_path).resolve()), os.getpid())
    with _GUARD:
        lock = _LOCKS.get(key)
        if lock is None:
            lock = _LOCKS[key] = WriteLock(Path(key[0]))
        return lock
