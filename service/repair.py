"""``matforge store verify --repair``: make corrupt or missing objects whole again where that
is possible.

For each corrupt object, and each object the job store refers to that is gone from disk
(moved or deleted by hand), in order:

1. a good copy among the files under ``--source`` paths (e.g. the user's originals of an
   upload): a file whose bytes hash to the digest is stored again, which replaces the
   damaged object atomically (:meth:`storage.artifacts.ArtifactStore.put_file`);
2. the job that produced it: its spec is run again in this process with ``force`` (the same
   spec gives the same bytes), whose writes replace the damaged object or put the missing
   one back;
3. otherwise it is reported with what the user can do (re-upload the file, or nothing for a
   manifest, which records timings and cannot be made again).

Every repair is checked by re-hashing the object.
"""

from __future__ import annotations

import hashlib
import logging
import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from service.settings import Settings
from storage.artifacts import ArtifactStore
from storage.jobs import JobStore

log = logging.getLogger("matforge.repair")
_CHUNK = 1 << 20


@dataclass(frozen=True)
class Repair:
    """The outcome for one corrupt object: ``repaired``, and ``how`` (or why not), one line."""

    digest: str
    repaired: bool
    how: str


def _files(sources: Iterable[Path]) -> Iterator[Path]:
    for src in sources:
        if src.is_file():
            yield src
        elif src.is_dir():
            for root, _dirs, files in os.walk(src):
                for f in sorted(files):
                    yield Path(root) / f


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(_CHUNK), b""):
            h.update(chunk)
    return h.hexdigest()


def find_copies(wanted: set[str], sources: Iterable[Path]) -> dict[str, Path]:
    """digest → a file under ``sources`` whose bytes hash to it (for the ``wanted`` ones)."""
    found: dict[str, Path] = {}
    for f in _files(sources):
        if len(found) == len(wanted):
            break
        try:
            d = _sha256(f)
        except OSError:
            continue
        if d in wanted and d not in found:
            found[d] = f
    return found


def _rerun(job_id: str, jobs: JobStore, settings: Settings) -> str:
    """Run job ``job_id``'s spec again with force; returns a one-line account."""
    from service.submission import run_in_process

    spec = dict(jobs.get(job_id).spec)
    spec["force"] = True
    try:
        again = run_in_process(spec, settings)
    except Exception as exc:  # a spec that no longer validates, a missing input, ...
        return f"re-running job {job_id} failed: {' '.join(str(exc).split())}"
    if again.state != "succeeded":
        return f"re-ran job {job_id} as {again.id}, which {again.state}: {again.error or ''}"
    return f"re-ran job {job_id} as {again.id}"


def repair(
    corrupt: Iterable[str],
    jobs: JobStore,
    store: ArtifactStore,
    settings: Settings,
    sources: Iterable[Path] = (),
) -> list[Repair]:
    """Try to repair each corrupt digest (see the module docstring); one :class:`Repair`
    each, in the given order."""
    digests = list(corrupt)
    copies = find_copies(set(digests), sources) if digests else {}
    out = []
    for d in digests:
        notes = []
        if d in copies:
            store.put_file(copies[d])
            if store.verify(d):
                out.append(Repair(d, True, f"replaced from a good copy at {copies[d]}"))
                continue
            notes.append(f"the copy at {copies[d]} did not take")
        producers = jobs.producers(d)
        for job_id in producers:
            notes.append(_rerun(job_id, jobs, settings))
            if store.verify(d):
                out.append(Repair(d, True, notes[-1]))
                break
        else:
            if producers:
                notes.append("the re-run wrote different bytes (not reproducible here)")
            else:
                rec = jobs.find_digest(d)
                if rec is not None:
                    notes.append(
                        f"an upload ({rec.name}): re-import a good copy with "
                        f"'matforge import', or pass it with --source"
                    )
                elif d in jobs.referenced_digests():
                    notes.append("a job manifest; it records timings and cannot be made again")
                else:
                    notes.append("referenced by nothing; 'matforge store gc' will remove it")
            out.append(Repair(d, False, "; ".join(notes)))
    return out
