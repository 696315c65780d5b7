"""Where a dataset's artifacts come from: a local data directory, or a server.

A :class:`Source` holds one finished job's artifact list and hands out **verified local
files** for its artifacts, by name:

- :class:`LocalSource` reads the content-addressed store of a data directory; each object
  is re-hashed once when first opened (:meth:`storage.artifacts.ArtifactStore.open_verified`)
  and then read in place (memory-mapped where the format allows).
- :class:`RemoteSource` downloads each object once into a local cache
  (``<cache>/objects/ab/cdef...``, by digest, shared by every job that holds the same
  bytes), hashing it as it arrives (:meth:`service.cli.client.Client.fetch`); an object
  already in the cache is re-hashed once per source before it is used, so a damaged cache
  file is downloaded again rather than read.
"""

from __future__ import annotations

import hashlib
import json
import os
from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from jobapi.params import JOB_REF
from storage.artifacts import ArtifactStore
from storage.job_queries import resolve_job_id
from storage.jobs import JobStore

#: Bytes hashed per read when a cached object is checked.
_CHUNK = 1 << 20


@dataclass(frozen=True)
class Artifact:
    """One artifact of the job: ``digest`` is 64 lowercase hex (no prefix)."""

    name: str
    digest: str
    size: int
    media_type: str


def job_text(ref_or_job: str) -> str:
    """The job id (or unique prefix) of ``job:<id>``, ``job:<id>/<name>`` or a bare id."""
    text = str(ref_or_job).strip()
    m = JOB_REF.match(text)
    if m:
        return str(m["job"])
    text = text.removeprefix("job:").split("/", 1)[0]
    if not text or any(c not in "0123456789abcdef" for c in text) or len(text) > 32:
        raise ValueError(
            f"{ref_or_job!r} is not a job: expected 'job:<id>', a job id or a unique prefix"
        )
    return text


def _hash_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while chunk := fh.read(_CHUNK):
            h.update(chunk)
    return h.hexdigest()


class Source(ABC):
    """A finished job's artifacts, opened as verified local files."""

    job_id: str
    kind: str
    spec: dict[str, Any]
    artifacts: dict[str, Artifact]

    def names(self, pattern_prefix: str = "") -> list[str]:
        """The artifact names starting with ``pattern_prefix``, sorted."""
        return sorted(n for n in self.artifacts if n.startswith(pattern_prefix))

    def artifact(self, name: str) -> Artifact:
        """The record of artifact ``name``; ``KeyError`` naming the job if it has none."""
        try:
            return self.artifacts[name]
        except KeyError:
            have = ", ".join(sorted(self.artifacts)) or "none"
            raise KeyError(
                f"job {self.job_id} ({self.kind}) has no artifact {name!r} (artifacts: {have})"
            ) from None

    @abstractmethod
    def path(self, name: str) -> Path:
        """A local, verified, read-only file holding artifact ``name``'s bytes."""

    def read_bytes(self, name: str) -> bytes:
        """Artifact ``name``'s bytes (verified)."""
        return self.path(name).read_bytes()

    def read_json(self, name: str) -> Any:
        """Artifact ``name`` parsed as JSON."""
        return json.loads(self.read_bytes(name))

    @property
    def ref(self) -> str:
        return f"job:{self.job_id}"


class LocalSource(Source):
    """A job in the data directory ``data_dir`` (its ``jobs.sqlite`` and ``store/``)."""

    def __init__(self, ref_or_job: str, data_dir: str | os.PathLike[str]) -> None:
        from service.settings import Settings

        settings = Settings.from_env({}).with_(data_dir=Path(data_dir))
        if not settings.db_path.is_file():
            raise FileNotFoundError(f"{data_dir}: not a matforge data directory (no job database)")
        jobs = JobStore(settings.db_path)
        try:
            job = jobs.get(resolve_job_id(jobs, job_text(ref_or_job)))
        finally:
            jobs.close()
        if job.state != "succeeded":
            raise ValueError(f"job {job.id} is {job.state}: only a succeeded job has a dataset")
        self.job_id, self.kind, self.spec = job.id, job.kind, dict(job.spec)
        self.artifacts = {
            a.name: Artifact(a.name, a.digest, a.size, a.media_type) for a in job.artifacts
        }
        self.store = ArtifactStore(settings.store_dir)
        self._verified: dict[str, Path] = {}

    def path(self, name: str) -> Path:
        art = self.artifact(name)
        if art.digest not in self._verified:
            self._verified[art.digest] = self.store.open_verified(art.digest)
        return self._verified[art.digest]


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/matforge`` (default ``~/.cache/matforge``)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "matforge"


class RemoteSource(Source):
    """A job on a server, through a :class:`matforge.Client` (or the REST client it holds);
    objects are downloaded once into ``cache_dir`` (default :func:`default_cache_dir`)."""

    def __init__(
        self, ref_or_job: str, client: Any, cache_dir: str | os.PathLike[str] | None = None
    ) -> None:
        got = client.get(job_text(ref_or_job))
        doc = got.raw if hasattr(got, "raw") else got  # a matforge.Client's Job, or a dict
        if doc.get("state") != "succeeded":
            raise ValueError(
                f"job {doc.get('id')} is {doc.get('state')}: only a succeeded job has a dataset"
            )
        self.client = client
        self.job_id, self.kind = str(doc["id"]), str(doc["kind"])
        self.spec = dict(doc.get("spec") or {})
        arts = doc.get("artifacts")
        if arts is None:
            arts = [getattr(a, "raw", a) for a in client.artifacts(self.job_id)]
        self.artifacts = {
            str(a["name"]): Artifact(
                str(a["name"]), str(a["digest"]), int(a["size"]), str(a.get("media_type", ""))
            )
            for a in arts
        }
        self.cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
        self._verified: dict[str, Path] = {}

    def cache_path(self, digest: str) -> Path:
        """Where the object ``digest`` is cached."""
        return self.cache / "objects" / digest[:2] / digest[2:]

    def path(self, name: str) -> Path:
        art = self.artifact(name)
        d = art.digest
        if d in self._verified:
            return self._verified[d]
        dest = self.cache_path(d)
        if not (dest.is_file() and dest.stat().st_size == art.size and _hash_file(dest) == d):
            # fetch hashes the bytes as they arrive and renames into place only on a match
            self.client.fetch(d, dest, 0o444)
        self._verified[d] = dest
        return dest
