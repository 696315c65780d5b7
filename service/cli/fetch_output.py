"""Where ``matforge fetch`` puts verified bytes: a regular file, a FIFO, a terminal or stdout.

Every byte is checked against its digest before any reaches the destination:

- a regular file (or a path that does not exist yet) is written through a private temporary
  file beside it, renamed over the file once the digest matched (atomic);
- a FIFO or a character device (a terminal, ``/dev/null``) is never renamed over: as root, a
  rename replaced ``/dev/null`` with a regular file for every process on the machine (issue
  21, item 4). The bytes are first collected and verified (in memory up to
  :data:`SPOOL_BYTES`, then in an anonymous temporary file), then written in place;
- stdout likewise gets only verified bytes (issue 21, item 12: a corrupt object used to reach
  stdout before the error);
- a block device, a socket or anything else is refused (:class:`BadInput`, exit 2).

A symbolic link is followed: the file it names is what gets written (or replaced).
"""

from __future__ import annotations

import os
import shutil
import stat
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

from service.cli.client import BadInput

#: A writer that is given every byte of an object, chunk by chunk.
Write = Callable[[bytes], object]
#: Streams an object's bytes into a writer; returns the size and raises (after the last
#: chunk) when they do not match the digest.
Fill = Callable[[Write], int]
#: Verified bytes bound for stdout or a FIFO stay in memory up to this size, then spill to
#: an anonymous temporary file (``$TMPDIR``).
SPOOL_BYTES = 16 * 1024 * 1024
_CHUNK = 1 << 20
_IN_PLACE = ("FIFO", "character device")


def file_type(mode: int) -> str:
    """What a ``st_mode`` is, in words: ``regular file``, ``FIFO``, ``character device``, ..."""
    checks = (
        (stat.S_ISREG, "regular file"),
        (stat.S_ISDIR, "directory"),
        (stat.S_ISFIFO, "FIFO"),
        (stat.S_ISCHR, "character device"),
        (stat.S_ISBLK, "block device"),
        (stat.S_ISSOCK, "socket"),
    )
    return next((name for test, name in checks if test(mode)), "special file")


def _target_type(path: Path) -> str | None:
    """The type of what ``path`` names (links followed), or ``None`` if nothing is there."""
    try:
        return file_type(os.stat(path).st_mode)
    except FileNotFoundError:
        return None


def _refuse(path: Path, what: str) -> BadInput:
    return BadInput(
        f"{path}: is a {what}; fetch writes regular files, FIFOs, terminals (character "
        "devices) and stdout (-o -) only"
    )


def spool(fill: Fill) -> tuple[BinaryIO, int]:
    """Collect and verify an object's bytes; returns the spool (rewound) and the size.
    Raises what ``fill`` raises, with nothing written anywhere but the spool."""
    buf = tempfile.SpooledTemporaryFile(max_size=SPOOL_BYTES, prefix="matforge-fetch-")
    try:
        size = fill(buf.write)
    except BaseException:
        buf.close()
        raise
    buf.seek(0)
    return buf, size  # type: ignore[return-value]


def write_stream(fill: Fill, out: BinaryIO) -> int:
    """Write an object's verified bytes to an open stream (stdout); returns the size."""
    buf, size = spool(fill)
    with buf:
        shutil.copyfileobj(buf, out, _CHUNK)
    out.flush()
    return size


def _write_in_place(path: Path, fill: Fill) -> int:
    buf, size = spool(fill)
    with buf:
        # No O_CREAT, no rename: the FIFO or device itself is opened (a FIFO waits here for
        # its reader). O_NOCTTY: a terminal does not become our controlling one.
        fd = os.open(path, os.O_WRONLY | os.O_NOCTTY)
        with os.fdopen(fd, "wb") as out:
            what = file_type(os.fstat(out.fileno()).st_mode)
            if what not in _IN_PLACE:  # replaced since we looked: write nothing
                raise _refuse(path, what)
            shutil.copyfileobj(buf, out, _CHUNK)
    return size


def _write_atomic(path: Path, fill: Fill, mode: int) -> int:
    real = Path(os.path.realpath(path))
    real.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(dir=real.parent, prefix=f".{real.name}.", suffix=".part")
    tmp = Path(tmp_name)
    try:
        with os.fdopen(fd, "wb") as out:
            size = fill(out.write)
        os.chmod(tmp, mode)
        what = _target_type(real)
        if what not in (None, "regular file"):  # appeared while we downloaded
            raise _refuse(path, what)
        os.replace(tmp, real)
    finally:
        tmp.unlink(missing_ok=True)
    return size


def write_verified(path: Path, fill: Fill, *, mode: int) -> int:
    """Write an object's verified bytes to ``path`` (see the module docstring); returns the
    size. ``mode``: the permissions of a new or replaced regular file."""
    what = _target_type(path)
    if what in (None, "regular file"):
        return _write_atomic(path, fill, mode)
    if what in _IN_PLACE:
        return _write_in_place(path, fill)
    raise _refuse(path, what)
