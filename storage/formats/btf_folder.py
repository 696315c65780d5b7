"""A folder of measured BTF slice images, as a user has it after decompressing a UBO2014
archive: one image per (light, view) pair plus a list of each image's angles.

**Layout** (a directory, or the same packed as a ``.btf.zip``; the list may sit in a
sub-folder, and image paths are relative to it):

- ``angles.csv`` with the header ``file,theta_i,phi_i,theta_o,phi_o``, or ``angles.json``:
  a list (or ``{"slices": [...]}``) of ``{"file", "theta_i", "phi_i", "theta_o",
  "phi_o"}``. Angles in degrees: theta from the normal in ``[0, 89]``, phi from the
  texture's +x (columns) towards +y (rows). ``i`` is the light, ``o`` the view.
- the images: OpenEXR (linear RGB) or PNG (8- or 16-bit; sRGB-encoded unless the importer
  is told they are linear), all of one size, ``[row = y, column = x]`` with row 0 at
  ``y = 0`` (flip them first if yours start at the top).

Checks (each refusal names the archive and the file): exactly one angle list; every listed
file present and an image of the common size; no image left unlisted; no pair of angles
listed twice; angles in range; the list at most :data:`MAX_LIST_BYTES` and
:data:`MAX_SLICES` slices (a CSV at most :data:`MAX_LIST_LINES` lines, blank ones
included), checked before it is parsed; every member at most :data:`MAX_MEMBER_BYTES`
inflated, checked from the zip directory before it is extracted. The upload check and the
``import.btf`` job apply them with this one reader. UBO2014's compressed ``.btf`` files
themselves are read by :mod:`storage.formats.ubo_btf`.
"""

from __future__ import annotations

import csv
import io
import json
import math
import shutil
import tempfile
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

import numpy as np

from storage.errors import FormatError, TooLargeError
from storage.formats.exr import MAX_PIXELS, check_exr_size, exr_header_info, read_exr
from storage.formats.png import (
    check_png_size,
    level_table,
    levels_to_float,
    png_size,
    read_png_levels,
)

ANGLE_FILES = ("angles.csv", "angles.json")
IMAGE_SUFFIXES = (".exr", ".png")
COLUMNS = ("file", "theta_i", "phi_i", "theta_o", "phi_o")
#: Largest polar angle accepted, degrees.
MAX_THETA = 89.0
#: Default cap on the pixels an archive's images decode to, all slices together (64
#: megapixels: 768 MB as float32 RGB; 400 slices of 400 x 400, or one 8192 x 4096 image).
#: The service passes its setting (``MATFORGE_ARCHIVE_MPIX``; a whole UBO2014 material,
#: 151 x 151 slices of 400 x 400, is 3650 Mpix); checked from the headers before any pixel
#: is decoded.
MAX_ARCHIVE_PIXELS = 64_000_000
#: The most slices an angle list may list (a whole UBO2014 material is 151 x 151 = 22801).
MAX_SLICES = 1 << 16
#: The most bytes an angle list may hold (about 64 bytes a slice): checked from the zip
#: directory (or the file's size) before it is read, and read no further than that.
MAX_LIST_BYTES = 64 * MAX_SLICES
#: The most lines ``angles.csv`` may have, blank ones included: a list's parsed rows cost
#: about 64 bytes of Python objects a line even when blank (a 20 KB deflated list of blank
#: lines took a worker from 393 to 2,032 MiB when it was read whole).
MAX_LIST_LINES = MAX_SLICES + 1
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)
#: The most bytes one image member of an archive may inflate to: the largest image read
#: (:data:`~storage.formats.exr.MAX_PIXELS`) as uncompressed float32 RGBA, plus 1 MiB of
#: header. Checked from the zip directory before a member is extracted, so a deflate bomb
#: cannot fill the disk.
MAX_MEMBER_BYTES = 16 * MAX_PIXELS + (1 << 20)


@dataclass(frozen=True)
class SliceEntry:
    """One listed image: its path relative to the angle list, and its angles (degrees)."""

    file: str
    theta_i: float
    phi_i: float
    theta_o: float
    phi_o: float

    def angles(self) -> tuple[float, float, float, float]:
        return (self.theta_i, self.phi_i, self.theta_o, self.phi_o)


def _parse_csv(text: str, label: str) -> list[SliceEntry]:
    lines = text.count("\n") + (not text.endswith("\n"))
    if lines > MAX_LIST_LINES:
        raise FormatError(
            label,
            f"has {lines} lines, over the limit of {MAX_LIST_LINES} (a header and at most "
            f"{MAX_SLICES} slices)",
        )
    rows = csv.reader(io.StringIO(text))  # row by row: only the entries are kept
    try:
        header = next(rows, None)
        if header is None or tuple(c.strip() for c in header) != COLUMNS:
            raise FormatError(label, f"the first line must be the header {','.join(COLUMNS)}")
        return _csv_entries(rows, label)
    except csv.Error as exc:
        raise FormatError(label, f"line {rows.line_num}: {exc}") from None


def _csv_entries(rows: Iterator[list[str]], label: str) -> list[SliceEntry]:
    out = []
    for k, row in enumerate(rows, start=2):
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != 5:
            raise FormatError(label, f"line {k}: expected 5 fields, got {len(row)}")
        try:
            values = [float(c) for c in row[1:]]
        except ValueError:
            raise FormatError(label, f"line {k}: angles must be numbers, got {row[1:]}") from None
        out.append(SliceEntry(row[0].strip(), *values))
    return out


def _parse_json(text: str, label: str) -> list[SliceEntry]:
    # Every entry is an object: more brackets than slices can only be a list of other
    # things, each a Python object once parsed (counted before parsing).
    containers = text.count("{") + text.count("[")
    if containers > MAX_SLICES + 2:
        raise FormatError(
            label, f"has {containers} JSON objects and lists, more than a list of at most "
            f"{MAX_SLICES} slices has"
        )  # fmt: skip
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise FormatError(label, f"invalid JSON at line {exc.lineno}: {exc.msg}") from None
    items = doc.get("slices") if isinstance(doc, dict) else doc
    if not isinstance(items, list):
        raise FormatError(label, 'expected a list of slices (or {"slices": [...]})')
    out = []
    for k, item in enumerate(items):
        if not isinstance(item, dict) or set(item) != set(COLUMNS):
            raise FormatError(label, f"entry {k}: needs exactly the keys {', '.join(COLUMNS)}")
        try:
            values = [float(item[c]) for c in COLUMNS[1:]]
        except (TypeError, ValueError):
            raise FormatError(label, f"entry {k}: angles must be numbers") from None
        out.append(SliceEntry(str(item["file"]), *values))
    return out


def _check_entries(entries: list[SliceEntry], label: str) -> None:
    if not entries:
        raise FormatError(label, "lists no slices")
    seen_files: dict[str, int] = {}
    seen_angles: dict[tuple[float, ...], str] = {}
    for k, e in enumerate(entries):
        where = f"{label}: {e.file}"
        if not e.file or PurePosixPath(e.file).is_absolute() or ".." in PurePosixPath(e.file).parts:
            raise FormatError(where, "file paths must be relative, inside the folder")
        if PurePosixPath(e.file).suffix.lower() not in IMAGE_SUFFIXES:
            raise FormatError(where, "slices must be .exr or .png images")
        if e.file in seen_files:
            raise FormatError(where, f"listed twice (entries {seen_files[e.file]} and {k})")
        seen_files[e.file] = k
        a = e.angles()
        if not all(math.isfinite(v) for v in a):
            raise FormatError(where, "angles must be finite")
        if not (0.0 <= a[0] <= MAX_THETA and 0.0 <= a[2] <= MAX_THETA):
            raise FormatError(where, f"theta_i and theta_o must lie in [0, {MAX_THETA:g}] degrees")
        key = _direction_key(a)
        if key in seen_angles:
            raise FormatError(
                where, f"duplicate angles: the same light and view as {seen_angles[key]}"
            )
        seen_angles[key] = e.file


def _direction_key(a: tuple[float, float, float, float]) -> tuple[float, ...]:
    # phi is meaningless at theta = 0: compare unit vectors, not raw angles.
    vec = []
    for theta, phi in ((a[0], a[1]), (a[2], a[3])):
        t, p = math.radians(theta), math.radians(phi)
        vec += [math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)]
    return tuple(round(v, 6) + 0.0 for v in vec)


class SliceFolder:
    """An opened slice folder or ``.btf.zip`` (use as a context manager for archives).

    ``entries`` are checked on opening (see the module docstring); :meth:`check_images`
    reads every header; :meth:`read` gives one slice in linear units.
    """

    def __init__(self, path: Path, name: str | None = None) -> None:
        self.path = Path(path)
        self.label = name or self.path.name
        self._zip: zipfile.ZipFile | None = None
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        if self.path.is_dir():
            members = [
                p.relative_to(self.path).as_posix() for p in self.path.rglob("*") if p.is_file()
            ]
        else:
            if not zipfile.is_zipfile(self.path):
                raise FormatError(self.label, "not a folder or a zip archive")
            try:
                self._zip = zipfile.ZipFile(self.path)
                members = [i.filename for i in self._zip.infolist() if not i.is_dir()]
            except (zipfile.BadZipFile, OSError) as exc:
                raise FormatError(self.label, f"unreadable zip archive: {exc}") from None
        members = [m for m in members if not PurePosixPath(m).name.startswith(".")]
        lists = [m for m in members if PurePosixPath(m).name in ANGLE_FILES]
        if len(lists) != 1:
            found = ", ".join(lists) if lists else "none"
            raise FormatError(
                self.label, f"needs exactly one angles.csv or angles.json (found: {found})"
            )
        self.list_name = lists[0]
        parent = PurePosixPath(self.list_name).parent
        self.root = "" if str(parent) == "." else f"{parent}/"
        text = self._read_list(self.list_name)
        list_label = f"{self.label}: {self.list_name}"
        parse = _parse_csv if self.list_name.endswith(".csv") else _parse_json
        self.entries = parse(text, list_label)
        _check_entries(self.entries, self.label)
        present = {m for m in members if m.startswith(self.root)}
        for e in self.entries:
            if self.root + e.file not in present:
                raise FormatError(
                    f"{self.label}: {e.file}", f"listed in {self.list_name} but missing"
                )
        listed = {self.root + e.file for e in self.entries}
        extra = sorted(
            m for m in present
            if PurePosixPath(m).suffix.lower() in IMAGE_SUFFIXES and m not in listed
        )  # fmt: skip
        if extra:
            raise FormatError(
                f"{self.label}: {extra[0][len(self.root) :]}",
                f"an image with no angles in {self.list_name}"
                + (f" (and {len(extra) - 1} more)" if len(extra) > 1 else ""),
            )
        self.resolution: tuple[int, int] | None = None

    # -- access ----------------------------------------------------------------------------
    def _read_list(self, member: str) -> str:
        """The angle list's text, at most :data:`MAX_LIST_BYTES` (its size is checked from
        the zip directory, or the file, before a byte is read); the upload check and the
        job read it with this one function."""
        label = f"{self.label}: {member}"
        if self._zip is not None:
            size = self._zip.getinfo(member).file_size
        else:
            size = (self.path / member).stat().st_size
        if size > MAX_LIST_BYTES:
            raise FormatError(
                label, f"holds {size} bytes, over the limit of {MAX_LIST_BYTES} bytes for an "
                f"angle list (at most {MAX_SLICES} slices)"
            )  # fmt: skip
        try:
            if self._zip is not None:
                with self._zip.open(member) as fh:
                    data = fh.read(MAX_LIST_BYTES + 1)
            else:
                with open(self.path / member, "rb") as fh:
                    data = fh.read(MAX_LIST_BYTES + 1)
        except (zipfile.BadZipFile, OSError, EOFError, ValueError) as exc:
            raise FormatError(label, f"unreadable: {exc}") from None
        if len(data) > MAX_LIST_BYTES:
            raise FormatError(label, f"holds more than {MAX_LIST_BYTES} bytes")
        try:
            return data.decode("utf-8", errors="strict")
        except UnicodeDecodeError as exc:
            raise FormatError(label, f"is not UTF-8 text (byte {exc.start})") from None

    def _local(self, entry: SliceEntry) -> Path:
        member = self.root + entry.file
        if self._zip is None:
            return self.path / member
        if self._tmp is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="matforge-btf-")
        size = self._zip.getinfo(member).file_size
        if size > MAX_MEMBER_BYTES:
            raise FormatError(
                f"{self.label}: {entry.file}",
                f"inflates to {size} bytes, more than any slice image can be "
                f"({MAX_MEMBER_BYTES} bytes)",
            )
        out = Path(self._tmp.name) / f"slice{PurePosixPath(entry.file).suffix.lower()}"
        with self._zip.open(member) as src, open(out, "wb") as dst:
            shutil.copyfileobj(src, dst, 1 << 20)  # streamed: a member is never all in memory
        return out

    def _size(self, entry: SliceEntry) -> tuple[int, int]:
        path, where = self._local(entry), f"{self.label}: {entry.file}"
        if entry.file.lower().endswith(".exr"):
            info = exr_header_info(path, where, check_limits=False)
            return info.height, info.width
        w, h = png_size(path, where)
        return h, w

    def _check_size(self, entry: SliceEntry, size: tuple[int, int]) -> None:
        """Refuse an image its reader would not decode, from its header's ``(H, W)``."""
        check = check_exr_size if entry.file.lower().endswith(".exr") else check_png_size
        check(size[1], size[0], f"{self.label}: {entry.file}")

    def check_images(self, max_pixels: int | None = None) -> tuple[int, int]:
        """Read every image's header: all must be readable and of one size ``(H, W)``, and,
        when ``max_pixels`` is given, all the images together must not decode to more
        pixels than that (:class:`TooLargeError` naming the member that crosses it)."""
        sizes = [self._size(e) for e in self.entries]
        first = self.entries[0]
        for e, s in zip(self.entries, sizes, strict=True):
            if s != sizes[0]:
                raise FormatError(
                    f"{self.label}: {e.file}",
                    f"is {s[1]}x{s[0]} pixels, but {first.file} is {sizes[0][1]}x{sizes[0][0]}",
                )
        if max_pixels is not None:  # first: over the cap is 413, whatever else is wrong
            check_decoded_pixels(self.label, [e.file for e in self.entries], sizes, max_pixels)
        for e in self.entries:
            self._check_size(e, sizes[0])
        self.resolution = sizes[0]
        return sizes[0]

    def read(self, entry: SliceEntry, *, png_srgb: bool = True) -> np.ndarray:
        """One slice, ``(H, W, 3)`` float32, linear (PNG sRGB decoded unless ``png_srgb``
        is false); ``FormatError`` naming it if unreadable, non-finite or negative.

        Peak memory is the image's integer levels plus one float32 image: PNG levels go
        through a 256 (or 65536) entry table, sRGB decoding included."""
        where = f"{self.label}: {entry.file}"
        path = self._local(entry)
        if entry.file.lower().endswith(".exr"):
            rgb = read_exr(path, where)
            if not np.all(np.isfinite(rgb)):
                raise FormatError(where, "has non-finite pixels (NaN or infinity)")
            if np.any(rgb < 0):
                raise FormatError(where, "has negative pixels")
        else:  # a table of finite values in [0, 1]: nothing to check per pixel
            levels, top = read_png_levels(path, where)
            table = level_table(top)
            rgb = levels_to_float(levels, srgb_to_linear(table) if png_srgb else table)
            del levels
        if self.resolution is not None and rgb.shape[:2] != self.resolution:
            raise FormatError(
                where, f"is {rgb.shape[1]}x{rgb.shape[0]} pixels, not the common size"
            )
        return rgb

    def __iter__(self) -> Iterator[SliceEntry]:
        return iter(self.entries)

    def close(self) -> None:
        if self._zip is not None:
            self._zip.close()
        if self._tmp is not None:
            self._tmp.cleanup()

    def __enter__(self) -> SliceFolder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """The sRGB decoding curve (IEC 61966-2-1), float32."""
    v = np.asarray(v, np.float64)
    out = np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)
    return out.astype(np.float32)


def check_decoded_pixels(
    label: str, files: list[str], sizes: list[tuple[int, int]], max_pixels: int
) -> int:
    """The pixels ``files`` of ``sizes`` ``(H, W)`` decode to, all together; raises
    :class:`TooLargeError` naming the archive, the member at which the sum crosses
    ``max_pixels``, and the sizes, when it is over."""
    total = sum(h * w for h, w in sizes)
    if total <= max_pixels:
        return total
    running = 0
    for f, (h, w) in zip(files, sizes, strict=True):
        running += h * w
        if running > max_pixels:
            raise TooLargeError(
                f"{label}: {f}: the archive's {len(files)} images decode to {total} pixels "
                f"({_gb(total * 12)} as float32 RGB), over the limit of {max_pixels} pixels "
                f"({_gb(max_pixels * 12)}); the limit is crossed at {f} ({w}x{h} pixels). "
                "Send fewer or smaller images"
            )
    return total  # unreachable: the loop crosses the limit


def _gb(n: int) -> str:
    return f"{n / 1e9:.2f} GB"


def archive_pixels(path: Path, name: str | None = None, max_pixels: int | None = None) -> int:
    """The pixels a slice folder or ``.btf.zip``'s images decode to, from their headers
    alone (PNG IHDR, EXR data window), every image checked as :meth:`SliceFolder.check_images`
    does; :class:`TooLargeError` over ``max_pixels`` (naming the member and the sizes)."""
    with SliceFolder(path, name) as folder:
        h, w = folder.check_images(max_pixels)
        return len(folder.entries) * h * w


def validate_btf_archive(
    path: Path, name: str | None = None, max_pixels: int | None = MAX_ARCHIVE_PIXELS
) -> None:
    """Validator for ``*.btf.zip`` uploads: the angle list and every image header, and the
    decoded size of all images together (at most ``max_pixels``)."""
    archive_pixels(path, name, max_pixels)


def pack_folder(folder: Path, out: Path) -> Path:
    """Pack a slice folder into a deterministic ``.btf.zip`` (stored, fixed timestamps,
    sorted members) after checking its angle list; returns ``out``."""
    SliceFolder(folder, folder.name).close()  # refuse a malformed folder before packing
    files = sorted(p for p in folder.rglob("*") if p.is_file() and not p.name.startswith("."))
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_STORED) as zf:
        for p in files:
            info = zipfile.ZipInfo(p.relative_to(folder).as_posix(), date_time=_ZIP_DATE)
            with open(p, "rb") as fh:
                zf.writestr(info, fh.read())
    return out
