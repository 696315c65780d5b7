"""Each side of the supervisor–worker pair notices when the other one is gone.

- **Worker → supervisor:** a worker touches its beat file
  (``<data>/workers/<host>-<pid>.beat``) from a thread every ``lease/3`` seconds, job or no
  job. A worker that is stopped (SIGSTOP), frozen or wedged stops beating; the supervisor
  kills it (its whole process group: pool processes too) once its beat is older than the
  lease, and starts another (:func:`stalled_for`). Its job's lease has run out by then, so the
  job is queued again and the new worker claims it.
- **Supervisor → worker:** a worker watches its parent pid from a thread. When the supervisor
  dies without stopping it (``kill -9`` or an out-of-memory kill of ``matforge serve``), the
  worker is re-parented; it then kills its own process group at once, rather than running
  queued jobs with no server, and competing with the workers of the next server.
"""

from __future__ import annotations

import logging
import os
import signal
import socket
import threading
import time
from pathlib import Path

log = logging.getLogger("matforge.worker")

#: A worker with no beat yet gets this long (beyond the lease) to start beating.
START_GRACE_SECONDS = 30.0


def beat_path(data_dir: Path, pid: int, host: str | None = None) -> Path:
    """The beat file of worker ``pid`` on ``host`` (default: this host)."""
    return data_dir / "workers" / f"{host or socket.gethostname()}-{pid}.beat"


def beat_interval(lease_seconds: float) -> float:
    """Seconds between beats: a third of the lease, at most 5 s, at least 50 ms."""
    return min(5.0, max(0.05, lease_seconds / 3))


class Beat:
    """Touches this process's beat file every :func:`beat_interval` seconds (a thread)."""

    def __init__(self, data_dir: Path, lease_seconds: float) -> None:
        self.path = beat_path(data_dir, os.getpid())
        self.interval = beat_interval(lease_seconds)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="worker-beat", daemon=True)

    def touch(self) -> None:
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.path.touch()
        except OSError:  # a full disk must not kill the worker; a stalled beat will
            log.exception("cannot write the beat file %s", self.path)

    def _loop(self) -> None:
        while not self._stop.wait(self.interval):
            self.touch()

    def start(self) -> None:
        self.touch()
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.path.unlink(missing_ok=True)


def stalled_for(
    data_dir: Path, pid: int, started: float, lease_seconds: float, now: float | None = None
) -> float | None:
    """Seconds since worker ``pid`` (spawned at wall time ``started``) last beat, when that
    is past its lease (plus :data:`START_GRACE_SECONDS` before its first beat); else ``None``.
    """
    t = time.time() if now is None else now
    try:
        last = beat_path(data_dir, pid).stat().st_mtime
        allowed = lease_seconds
    except FileNotFoundError:
        last, allowed = started, lease_seconds + START_GRACE_SECONDS
    age = t - max(last, started)
    return age if age > allowed else None


def end_worker() -> None:
    """End this worker now, with its pool processes: it leads its own session, so its
    process group is the worker and its pool. Its supervisor sees it exit and starts
    another. Used when its supervisor is gone, and when a stopped job's runner does not
    return (:class:`~service.workers.execution.Heartbeat`): a wedged thread cannot be
    interrupted, the process can."""
    for handler in logging.getLogger().handlers:
        handler.flush()
    try:
        if os.getpgid(0) == os.getpid():
            os.killpg(0, signal.SIGKILL)
    finally:
        os._exit(1)


def watch_parent(parent_pid: int, poll_seconds: float = 0.5) -> threading.Thread:
    """Start a thread that kills this process's group when ``parent_pid`` is no longer our
    parent (it died, and we were re-parented). The worker leads its own session, so the
    group is the worker and its pool processes."""

    def loop() -> None:
        while True:
            if os.getppid() != parent_pid:
                log.warning(
                    "worker %d: its supervisor (pid %d) is gone; stopping", os.getpid(), parent_pid
                )
                end_worker()
            time.sleep(poll_seconds)

    thread = threading.Thread(target=loop, name="parent-watch", daemon=True)
    thread.start()
    return thread
