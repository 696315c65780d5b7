"""Job work directories under ``<data>/scratch``: naming, and finding the stale ones.

A worker makes one directory per job it runs, named ``job-<job id[:8]>-<pid>-<random>``, and
removes it when the job ends. A worker that is killed (SIGKILL, out of memory) leaves it
behind. Such a directory is stale when no running job is held by the process that made it;
``matforge store gc`` removes those.
"""

from __future__ import annotations

import os
import re
import shutil
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

_NAME = re.compile(r"job-(?P<job>[0-9a-f]{8})-(?:(?P<pid>[0-9]+)-)?.+")


def scratch_prefix(job_id: str) -> str:
    """The ``mkdtemp`` prefix of this process's work directory for ``job_id``."""
    return f"job-{job_id[:8]}-{os.getpid()}-"


@dataclass(frozen=True)
class ScratchReport:
    """What :func:`collect_scratch` removed (or, in a dry run, would remove)."""

    removed: list[str]
    kept_active: int
    bytes_freed: int
    dry_run: bool


def _tree_size(path: Path) -> int:
    total = 0
    for root, _dirs, files in os.walk(path):
        for f in files:
            try:
                total += (Path(root) / f).lstat().st_size
            except OSError:
                pass
    return total


Running = Callable[[], Iterable[tuple[str, str | None]]]


def stale_dirs(scratch: Path, running: Running) -> tuple[list[Path], int]:
    """``(stale directories, number kept)`` in ``scratch``.

    ``running()`` gives ``(job id, worker)`` of every running job, ``worker`` being
    ``"<host>:<pid>"``. It is called *after* the directory is listed: a job is claimed
    before its directory is made, so a directory seen whose job is still running when the
    jobs are read is kept.
    """
    if not scratch.is_dir():
        return [], 0
    entries = sorted(p for p in scratch.iterdir() if p.is_dir() and not p.is_symlink())
    active: dict[str, set[str | None]] = {}
    for job_id, worker in running():
        pid = worker.rsplit(":", 1)[-1] if worker else None
        active.setdefault(job_id[:8], set()).add(pid)
    stale, kept = [], 0
    for p in entries:
        m = _NAME.fullmatch(p.name)
        if m is None:
            continue  # not a job directory: not ours to remove
        pids = active.get(m["job"])
        if pids is not None and (m["pid"] is None or m["pid"] in pids):
            kept += 1
        else:
            stale.append(p)
    return stale, kept


def collect_scratch(scratch: Path, running: Running, dry_run: bool = True) -> ScratchReport:
    """Remove (unless ``dry_run``) the stale job directories of :func:`stale_dirs`."""
    stale, kept = stale_dirs(scratch, running)
    freed = 0
    for p in stale:
        freed += _tree_size(p)
        if not dry_run:
            shutil.rmtree(p, ignore_errors=True)
    return ScratchReport([p.name for p in stale], kept, freed, dry_run)
