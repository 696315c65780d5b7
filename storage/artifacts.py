"""Content-addressed artifact store on disk.

Objects live at ``<root>/objects/ab/cdef...`` where ``abcdef...`` is the sha256 of their
bytes. Writes are atomic (temp file in the same directory, fsync, rename, fsync of the
directory) and objects are made read-only once written. Every read through
:meth:`ArtifactStore.read` or :meth:`ArtifactStore.open_verified` re-hashes the bytes, so a
corrupted object is reported, never served.

A write of bytes whose object already exists re-hashes the existing file before it skips the
write: a damaged object is replaced (atomically, by rename over it) with the good bytes, so
a re-run or a re-upload repairs it instead of "succeeding" on top of it.
"""

from __future__ import annotations

import hashlib
import logging
import os
import re
import stat
import tempfile
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from storage.errors import IntegrityError, NotFoundError

log = logging.getLogger("matforge.store")

DIGEST_RE = re.compile(r"[0-9a-f]{64}")
_CHUNK = 1 << 20


def check_digest(digest: str) -> str:
    """Return ``digest`` (64 lowercase hex, an optional ``sha256:`` prefix dropped) or raise
    ``ValueError``. Nothing that fails this pattern ever reaches a file-system path."""
    d = digest[7:] if digest.startswith("sha256:") else digest
    if not DIGEST_RE.fullmatch(d):
        raise ValueError(f"not a sha256 digest: {digest!r} (expected 64 lowercase hex digits)")
    return d


@dataclass(frozen=True)
class ObjectInfo:
    """A stored object: its digest (hex, no prefix) and size in bytes."""

    digest: str
    size: int

    @property
    def ref(self) -> str:
        return f"sha256:{self.digest}"


@dataclass(frozen=True)
class VerifyReport:
    """Result of :meth:`ArtifactStore.verify_all`: ``corrupt`` objects (bytes that do not
    hash to their name), ``missing`` ones (referenced but absent from disk) and ``stray``
    files (names that are not digests)."""

    checked: int
    corrupt: list[str]
    stray: list[str]
    missing: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.corrupt and not self.missing


@dataclass(frozen=True)
class GcReport:
    """Result of :meth:`ArtifactStore.gc`: what was (or, in a dry run, would be) removed."""

    removed: list[str]
    kept_recent: int
    kept_referenced: int
    bytes_freed: int
    dry_run: bool


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


class ArtifactStore:
    """A content-addressed object store rooted at ``root``. ``create=False`` opens an
    existing store only (a shard task on another node, which must not make a store of its
    own where the shared one is not mounted): :class:`NotFoundError` if it is not there."""

    def __init__(self, root: str | Path, *, create: bool = True) -> None:
        self.root = Path(root)
        self.objects = self.root / "objects"
        self.tmp = self.root / "tmp"
        if not create:
            if not (self.objects.is_dir() and self.tmp.is_dir()):
                raise NotFoundError(f"no artifact store at {self.root} on this machine")
            return
        self.objects.mkdir(parents=True, exist_ok=True)
        self.tmp.mkdir(parents=True, exist_ok=True)

    # -- paths ---------------------------------------------------------------------------
    def path(self, digest: str) -> Path:
        """The path of an object (it may not exist). ``digest`` is pattern-checked."""
        d = check_digest(digest)
        return self.objects / d[:2] / d[2:]

    def exists(self, digest: str) -> bool:
        return self.path(digest).is_file()

    def size(self, digest: str) -> int:
        p = self.path(digest)
        try:
            return p.stat().st_size
        except FileNotFoundError:
            raise NotFoundError(f"no object sha256:{check_digest(digest)} in the store") from None

    def check_stored(self, info: ObjectInfo) -> None:
        """Check, cheaply, that an object another process wrote (a shard task on another
        node) is in place with ``info.size`` bytes: one ``stat``, no hashing (the full
        check stays on read, :meth:`read` and :meth:`open_verified`). On NFS a name made
        by another client can be hidden for a while by this client's cached lookups:
        listing its directory revalidates them, once, before the object counts as
        missing. Raises :class:`NotFoundError` or, for a wrong size,
        :class:`IntegrityError`."""
        p = self.path(info.digest)
        try:
            st = p.stat()
        except FileNotFoundError:
            for folder in (p.parent.parent, p.parent):  # the fan-out folder may be new too
                try:
                    os.listdir(folder)
                except FileNotFoundError:
                    pass
            try:
                st = p.stat()
            except FileNotFoundError:
                raise NotFoundError(
                    f"no object sha256:{info.digest} in the store at {self.root}"
                ) from None
        if st.st_size != info.size:
            raise IntegrityError(
                f"object sha256:{info.digest} has {st.st_size} bytes in the store, "
                f"expected {info.size}"
            )

    # -- writing -------------------------------------------------------------------------
    def _intact(self, digest: str, size: int) -> bool:
        """Whether an object exists with ``size`` bytes that hash to ``digest``; a damaged
        one is logged (the caller then replaces it)."""
        p = self.path(digest)
        try:
            if p.stat().st_size == size and self.verify(digest):
                return True
        except FileNotFoundError:
            return False
        log.warning("object sha256:%s is corrupt on disk; replacing it with good bytes", digest)
        return False

    def _commit(self, tmp_path: Path, digest: str) -> Path:
        """Move a written temp file into place, unless an intact object is already there.
        A corrupt object is replaced: ``rename`` over it is atomic, so readers see the old
        (detectably corrupt) bytes or the new ones, never a mix."""
        final = self.path(digest)
        if self._intact(digest, tmp_path.stat().st_size):
            tmp_path.unlink(missing_ok=True)
            return final
        final.parent.mkdir(parents=True, exist_ok=True)
        os.chmod(tmp_path, stat.S_IRUSR | stat.S_IRGRP | stat.S_IROTH)
        os.replace(tmp_path, final)
        _fsync_dir(final.parent)
        return final

    def put_bytes(self, data: bytes) -> ObjectInfo:
        """Store ``data`` atomically; returns its digest and size (idempotent)."""
        digest = hashlib.sha256(data).hexdigest()
        if self._intact(digest, len(data)):
            return ObjectInfo(digest, len(data))
        fd, name = tempfile.mkstemp(dir=self.tmp, prefix="put-")
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
            self._commit(Path(name), digest)
        except BaseException:
            Path(name).unlink(missing_ok=True)
            raise
        return ObjectInfo(digest, len(data))

    def put_stream(
        self, stream: BinaryIO | Iterable[bytes], max_bytes: int | None = None
    ) -> ObjectInfo:
        """Store bytes from a file object or an iterable of chunks, hashing as it goes.

        Raises ``TooLargeError`` (and stores nothing) if more than ``max_bytes`` arrive.
        """
        from storage.errors import TooLargeError

        h = hashlib.sha256()
        size = 0
        fd, name = tempfile.mkstemp(dir=self.tmp, prefix="put-")
        chunks: Iterable[bytes]
        if hasattr(stream, "read"):
            reader = stream
            chunks = iter(lambda: reader.read(_CHUNK), b"")
        else:
            chunks = stream
        try:
            with os.fdopen(fd, "wb") as fh:
                for chunk in chunks:
                    size += len(chunk)
                    if max_bytes is not None and size > max_bytes:
                        raise TooLargeError(f"upload exceeds the limit of {max_bytes} bytes")
                    h.update(chunk)
                    fh.write(chunk)
                fh.flush()
                os.fsync(fh.fileno())
            digest = h.hexdigest()
            self._commit(Path(name), digest)
        except BaseException:
            Path(name).unlink(missing_ok=True)
            raise
        return ObjectInfo(digest, size)

    def put_file(self, path: str | Path) -> ObjectInfo:
        """Store a copy of the file at ``path``."""
        with open(path, "rb") as fh:
            return self.put_stream(fh)

    # -- reading -------------------------------------------------------------------------
    def read(self, digest: str) -> bytes:
        """The object's bytes, verified against its digest."""
        d = check_digest(digest)
        p = self.path(d)
        try:
            data = p.read_bytes()
        except FileNotFoundError:
            raise NotFoundError(f"no object sha256:{d} in the store") from None
        if hashlib.sha256(data).hexdigest() != d:
            raise IntegrityError(f"object sha256:{d} is corrupt on disk (digest mismatch)")
        return data

    def verify(self, digest: str) -> bool:
        """Whether the object exists and hashes to its digest (streams the file)."""
        d = check_digest(digest)
        p = self.path(d)
        if not p.is_file():
            return False
        h = hashlib.sha256()
        with open(p, "rb") as fh:
            for chunk in iter(lambda: fh.read(_CHUNK), b""):
                h.update(chunk)
        return h.hexdigest() == d

    def open_verified(self, digest: str) -> Path:
        """The path of an object after verifying it; raises if missing or corrupt."""
        d = check_digest(digest)
        if not self.path(d).is_file():
            raise NotFoundError(f"no object sha256:{d} in the store")
        if not self.verify(d):
            raise IntegrityError(f"object sha256:{d} is corrupt on disk (digest mismatch)")
        return self.path(d)

    # -- maintenance ---------------------------------------------------------------------
    def iter_objects(self) -> Iterator[tuple[str, Path]]:
        """``(digest, path)`` for every object file on disk."""
        if not self.objects.is_dir():
            return
        for sub in sorted(self.objects.iterdir()):
            if not sub.is_dir() or len(sub.name) != 2:
                continue
            for f in sorted(sub.iterdir()):
                yield sub.name + f.name, f

    def verify_all(self, referenced: Iterable[str] = ()) -> VerifyReport:
        """Re-hash every object, and check that every digest in ``referenced`` (the job
        store's references: artifacts, uploads, manifests) has an object at all: a file
        moved or deleted by hand is as lost as a damaged one. ``stray`` lists files whose
        names are not digests."""
        checked, corrupt, stray = 0, [], []
        present: set[str] = set()
        for name, path in self.iter_objects():
            if not DIGEST_RE.fullmatch(name):
                stray.append(str(path))
                continue
            checked += 1
            present.add(name)
            if not self.verify(name):
                corrupt.append(name)
        missing = sorted(d for d in set(referenced) if d not in present)
        return VerifyReport(checked, corrupt, stray, missing)

    def gc(
        self,
        referenced: set[str],
        grace_seconds: float,
        dry_run: bool = True,
        now: float | None = None,
    ) -> GcReport:
        """Remove objects not in ``referenced`` whose files are older than ``grace_seconds``.

        The grace period protects objects written by a job that has not finished yet (its
        manifest does not reference them yet). Stale temp files older than the grace period
        are removed as well.
        """
        t = time.time() if now is None else now
        removed, recent, kept, freed = [], 0, 0, 0
        for name, path in self.iter_objects():
            if name in referenced:
                kept += 1
                continue
            st = path.stat()
            if t - st.st_mtime < grace_seconds:
                recent += 1
                continue
            removed.append(name)
            freed += st.st_size
            if not dry_run:
                path.unlink(missing_ok=True)
        if not dry_run:
            for f in self.tmp.iterdir():
                if t - f.stat().st_mtime >= grace_seconds:
                    f.unlink(missing_ok=True)
        return GcReport(removed, recent, kept, freed, dry_run)
