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

**A symbolic link is never written through, nor replaced** (fetch replaces only what it
could have made: a regular file). The destination is looked at with ``lstat``: a link to a
FIFO or a terminal (``/dev/stdout``) is written in place, as the FIFO itself would be;
any other link, a dangling one included, is refused with exit 2, naming the link and
where it points, and nothing is written (a link planted at ``/tmp/x.png`` pointing at
``~/.bashrc`` used to have ``~/.bashrc`` replaced, and a dangling one had its target
created). The temporary file is created with ``O_EXCL | O_NOFOLLOW``, the destination is
looked at again just before the rename, and the rename itself replaces a name, never what
a link there points to. A folder named by ``-o`` (or a sub-folder of an artifact's name
under it) is not a destination file: ``-o DIR`` may be a link to a directory, but the
sub-folders fetch creates under it for a whole job must not be links
(:func:`check_subfolders`).
"""

from __future__ import annotations

import errno
import os
import secrets
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


def _lstat_type(path: Path) -> str | None:
    """The type of ``path`` itself (a link is ``symbolic link``), or ``None`` if nothing
    is there."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return None
    return "symbolic link" if stat.S_ISLNK(mode) else file_type(mode)


def _refuse(path: Path, what: str) -> BadInput:
    return BadInput(
        f"{path}: is a {what}; fetch writes regular files, FIFOs, terminals (character "
        "devices) and stdout (-o -) only"
    )


def _refuse_link(path: Path) -> BadInput:
    try:
        points = os.readlink(path)
    except OSError:
        points = "?"
    what = _target_type(path)
    to = f"a {what}" if what is not None else "nothing (a dangling link)"
    return BadInput(
        f"{path}: is a symbolic link to {points} ({to}); fetch never writes a file through a "
        "link or replaces one (only a FIFO or a terminal a link points to is written in "
        "place): remove the link, or give the path it points to"
    )


def check_subfolders(base: Path, rel: Path) -> None:
    """Refuse (:class:`BadInput`) when a folder of ``rel`` (an artifact's name with
    sub-folders) under ``base`` is a symbolic link: fetch creates those folders, and a
    planted link would send the files elsewhere."""
    here = base
    for part in rel.parts[:-1]:
        here = here / part
        if here.is_symlink():
            raise BadInput(
                f"{here}: is a symbolic link; fetch writes a job's artifacts into folders it "
                "creates under the output directory, never through a link"
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


def _write_in_place(path: Path, fill: Fill, *, follow: bool) -> int:
    buf, size = spool(fill)
    with buf:
        # No O_CREAT, no rename: the FIFO or device itself is opened (a FIFO waits here for
        # its reader). O_NOCTTY: a terminal does not become our controlling one. O_NOFOLLOW
        # unless the destination was a link to a FIFO or terminal: a link put in its place
        # meanwhile is not opened.
        flags = os.O_WRONLY | os.O_NOCTTY | (0 if follow else os.O_NOFOLLOW)
        try:
            fd = os.open(path, flags)
        except OSError as exc:
            if exc.errno == errno.ELOOP:  # a link appeared where the FIFO was
                raise _refuse_link(path) from None
            raise
        with os.fdopen(fd, "wb") as out:
            what = file_type(os.fstat(out.fileno()).st_mode)
            if what not in _IN_PLACE:  # replaced since we looked: write nothing
                raise _refuse(path, what)
            shutil.copyfileobj(buf, out, _CHUNK)
    return size


def _private_temp(path: Path) -> tuple[int, Path]:
    """A new file beside ``path`` only this process made: ``O_CREAT | O_EXCL | O_NOFOLLOW``
    (never opened through a link), mode 0600 until it is complete."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC
    for _ in range(100):
        tmp = path.parent / f".{path.name}.{secrets.token_hex(6)}.part"
        try:
            return os.open(tmp, flags, 0o600), tmp
        except FileExistsError:
            continue
    raise FileExistsError(f"{path.parent}: no free temporary name for {path.name}")


def _write_atomic(path: Path, fill: Fill, mode: int) -> int:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = _private_temp(path)
    made = True
    try:
        with os.fdopen(fd, "wb") as out:
            size = fill(out.write)
            os.fchmod(out.fileno(), mode)
        what = _lstat_type(path)  # again: something may have appeared while we downloaded
        if what == "symbolic link":
            raise _refuse_link(path)
        if what not in (None, "regular file"):
            raise _refuse(path, what)
        os.replace(tmp, path)  # replaces the name: never what a link there points to
        made = False
    finally:
        if made:
            tmp.unlink(missing_ok=True)
    return size


def write_verified(path: Path, fill: Fill, *, mode: int) -> int:
    """Write an object's verified bytes to ``path`` (see the module docstring); returns the
    size. ``mode``: the permissions of a new or replaced regular file. A symbolic link at
    ``path`` is written through only to a FIFO or a terminal; any other link is refused
    (:class:`BadInput`) with nothing written."""
    what = _lstat_type(path)
    if what == "symbolic link":
        if _target_type(path) in _IN_PLACE:
            return _write_in_place(path, fill, follow=True)
        raise _refuse_link(path)
    if what in (None, "regular file"):
        return _write_atomic(path, fill, mode)
    if what in _IN_PLACE:
        return _write_in_place(path, fill, follow=False)
    raise _refuse(path, what)
