"""How many bytes an uploaded archive's members inflate to, from its zip directory alone.

A zip member's directory entry declares its size once inflated, and Python's reader never
gives more than that (it stops at the declared size and checks the CRC), so the sum of the
declared sizes bounds everything reading the archive can ever inflate: to memory, or to the
temporary files a ``.btf.zip``'s images are read from. Entries that share one compressed
stream (an "overlapping" zip bomb) each declare their size and are each counted.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

from storage.errors import TooLargeError


def check_inflated_size(path: Path, label: str, max_bytes: int, budget: str = "") -> int:
    """The bytes the members of the zip archive at ``path`` inflate to, all together;
    :class:`TooLargeError` naming ``label``, the sizes and ``budget`` (what the limit is
    made of) as soon as the running sum passes ``max_bytes``. A file that is not a zip
    archive is left to its format's validator (0)."""
    try:
        if not zipfile.is_zipfile(path):
            return 0
        with zipfile.ZipFile(path) as zf:
            infos = zf.infolist()
    except (zipfile.BadZipFile, OSError, ValueError, EOFError):
        return 0  # the format's validator names what is wrong
    total = 0
    for n, info in enumerate(infos, start=1):
        total += info.file_size
        if total > max_bytes:
            size = path.stat().st_size
            raise TooLargeError(
                f"{label}: over its inflated-bytes budget: its members inflate to more than "
                f"{max_bytes} bytes ({total} bytes by member {n} of {len(infos)}, "
                f"{info.filename!r}) from {size} bytes uploaded"
                + (f"; the budget is {budget}" if budget else "")
                + ". Send it less compressed, or in smaller archives"
            )
    return total
