"""Per-job logs under ``<data>/logs``: one text file per job, appended by whoever runs it.

A job's log holds what its runs said: each attempt's start (worker, attempt, kind), the
progress messages as the heartbeat publishes them, the log records of the process while it
runs the job (warnings, and whatever the process logs at its level), and the end (state,
error). Every attempt appends, so a job re-queued after its worker died shows both runs.

A log is for the users of the service, not only its operator: the server's file system
paths are written without their folders (:func:`scrub_paths`). A traceback keeps its frames,
each named relative to the package root (``service/workers/execution.py``, line 123), to
its ``site-packages`` or standard-library folder (``numpy/...``, ``json/decoder.py``);
the data directory reads ``<data-dir>``, the temporary folder ``<tmp>``.

Lines are appended with ``O_APPEND`` (one ``write`` each, so lines of two writers never
interleave within a line) and a log stops growing at :data:`MAX_LOG_BYTES` with one last
line saying so: a chatty runner cannot fill the disk. Reading never fails for a job that
has not logged yet: the log is then empty.
"""

from __future__ import annotations

import functools
import os
import re
import sys
import sysconfig
import tempfile
import time
from pathlib import Path

#: The most bytes one job's log may hold; past it one line says the rest was dropped.
MAX_LOG_BYTES = 1 << 20
_ID = re.compile(r"^[0-9a-f]{32}$")
_DROPPED = "[log truncated: over {limit} bytes; later lines were dropped]\n"


#: The folder our top-level packages (``service``, ``storage``, ...) sit in.
PACKAGE_ROOT = Path(__file__).resolve().parents[1]


@functools.lru_cache(maxsize=16)
def _prefixes(data_dir: str | None) -> tuple[tuple[str, str], ...]:
    """``(folder + "/", what it is written as)``, longest first: the package root and the
    import folders (standard library, ``site-packages``, ``sys.path``) as nothing, the data
    directory as ``<data-dir>/``, the temporary folder as ``<tmp>/``; each as given and
    resolved."""
    pairs: dict[str, str] = {}

    def add(folder: str | Path, shown: str) -> None:
        for form in {str(folder), str(Path(folder).resolve())}:
            if os.path.isabs(form) and len(form) > 1:
                pairs.setdefault(form.rstrip("/") + "/", shown)

    add(PACKAGE_ROOT, "")
    if data_dir is not None:
        add(data_dir, "<data-dir>/")
    add(tempfile.gettempdir(), "<tmp>/")
    for folder in (*sysconfig.get_paths().values(), *sys.path, sys.prefix, sys.base_prefix):
        if folder and os.path.isabs(folder):
            add(folder, "")
    return tuple(sorted(pairs.items(), key=lambda kv: -len(kv[0])))


def scrub_paths(text: str, data_dir: Path | None = None) -> str:
    """``text`` with the server's folders taken out of every path in it (a traceback's
    ``File "/srv/matforge/service/workers/execution.py"`` reads
    ``File "service/workers/execution.py"``; see the module docstring). Longer folders are
    replaced first, so a data directory inside the package root reads ``<data-dir>``."""
    for folder, shown in _prefixes(None if data_dir is None else str(data_dir)):
        if folder in text:
            text = text.replace(folder, shown)
    return text


def log_dir(data_dir: Path) -> Path:
    """Where the job logs of a data directory live."""
    return Path(data_dir) / "logs"


class JobLog:
    """The log of one job (``job_id``: the full 32-hex id) in ``directory``."""

    def __init__(self, directory: Path, job_id: str, max_bytes: int = MAX_LOG_BYTES) -> None:
        if not _ID.match(job_id):
            raise ValueError(f"not a full job id: {job_id!r}")
        self.path = Path(directory) / f"{job_id}.log"
        self.max_bytes = max_bytes

    def write(self, text: str) -> None:
        """Append ``text`` as lines, each stamped with the UTC time, without the server's
        folders (:func:`scrub_paths`; the data directory is the log folder's parent).
        Never raises: a log that cannot be written must not fail the job it describes."""
        stamp = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        text = scrub_paths(text, self.path.parent.parent)
        lines = "".join(f"{stamp} {line}\n" for line in text.rstrip("\n").split("\n"))
        data = lines.encode("utf-8", "replace")
        if len(data) > self.max_bytes // 4:  # one huge message: keep its start
            data = data[: self.max_bytes // 4 - 32] + b" [... cut]\n"
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
            try:
                size = os.fstat(fd).st_size
                dropped = _DROPPED.format(limit=self.max_bytes).encode()
                if self._full(dropped, size):
                    return
                if size + len(data) + len(dropped) <= self.max_bytes:
                    os.write(fd, data)
                else:
                    os.write(fd, dropped)  # once: the log is full from here on
            finally:
                os.close(fd)
        except OSError:
            return

    def _full(self, marker: bytes, size: int) -> bool:
        """Whether the marker was written. It is written only past 3/4 of the limit (a write
        holds at most a quarter of it) and nothing follows it, so it ends the log."""
        if size < self.max_bytes // 2:
            return False
        with open(self.path, "rb") as f:
            f.seek(max(0, size - 4096))
            return marker in f.read()

    def read(self, tail: int | None = None) -> str:
        """The log's text (``""`` if the job has not logged), or its last ``tail`` lines."""
        try:
            data = self.path.read_bytes()
        except FileNotFoundError:
            return ""
        text = data.decode("utf-8", "replace")
        if tail is not None:
            lines = text.splitlines(keepends=True)
            text = "".join(lines[-tail:]) if tail > 0 else ""
        return text
