"""Parsing a Bonn ``.btf`` header (the layout is in :mod:`storage.formats.ubo_btf`'s
docstring): every count and size checked against limits and the file's size before
anything is read, and the factor matrices located (not read).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

import numpy as np

from storage.errors import FormatError

SIGNATURES: dict[bytes, tuple[str, bool]] = {
    b"!DFMF08FCR": ("DFMF", True),
    b"!DFMF08FC": ("DFMF", False),
    b"!FMF12FCER": ("FMF", True),
    b"!FMF12FCE": ("FMF", False),
    b"!FMF06FCR": ("FMF", True),
    b"!FMF06FC": ("FMF", False),
}
#: Recognised but not decoded: prefix -> the variant's name.
REFUSED: dict[bytes, str] = {
    b"!BDIF": "BDI (uncompressed chunked BTF)",
    b"!PVF": "PVF (per-view factorisation)",
    b"!FMF0": "FMF0 (unknown FMF header)",
}
MAX_DIRECTIONS = 4096
MAX_SIDE = 1 << 16
MAX_COMPONENTS = 1 << 16
MAX_XML_BYTES = 64 << 20
MAX_NAME_BYTES = 4096
COLOR_MODELS = {0: "RGB", 1: "YUV", 3: "PCA", 4: "YCoCg", 9: "Ylog_UV", 10: "Ylog_Ulog_Vlog",
                11: "Ylog_UdivY_VdivY", 12: "log RGB"}  # fmt: skip
REFUSED_MODELS = {2: "Lab", 5: "spectral", 6: "spectral linear"}
_SCALARS = {2: "<f2", 4: "<f4", 8: "<f8"}


@dataclass(frozen=True)
class Matrix:
    """A factor matrix inside the file: byte ``offset``, ``rows x cols`` of ``dtype``."""

    offset: int
    rows: int
    cols: int
    dtype: str


@dataclass
class UboHeader:
    """Everything before the factors, and where each factor matrix lies."""

    variant: str
    signature: str
    version: int
    cosine_flag: bool
    channels: list[str]
    views: np.ndarray  # (nV, 2) theta, phi, radians
    lights: np.ndarray  # (nL, 2)
    width: int
    height: int
    rgb_scale: tuple[float, float, float]
    color_model: int = 0
    color_mean: np.ndarray = field(default_factory=lambda: np.zeros(3))
    color_transform: np.ndarray = field(default_factory=lambda: np.eye(3))
    drr: int = 0
    # DFMF: one (U, SxV) per channel; FMF: one pair for all channels.
    factors: list[tuple[Matrix, Matrix]] = field(default_factory=list)
    file_size: int = 0

    @property
    def count(self) -> int:
        return len(self.lights) * len(self.views)

    def pair(self, k: int) -> tuple[int, int]:
        """``(light, view)`` indices of slice ``k`` (the file's order, views outermost)."""
        return k % len(self.lights), k // len(self.lights)

    def angles_deg(self) -> np.ndarray:
        """``(count, 4)`` theta_i, phi_i, theta_o, phi_o in degrees, in slice order."""
        li = np.tile(np.arange(len(self.lights)), len(self.views))
        vi = np.repeat(np.arange(len(self.views)), len(self.lights))
        out = np.concatenate([self.lights[li], self.views[vi]], axis=1)
        return np.degrees(out[:, [0, 1, 2, 3]])


class _Reader:
    def __init__(self, fh: BinaryIO, label: str, size: int) -> None:
        self.fh, self.label, self.size = fh, label, size

    def take(self, n: int, what: str) -> bytes:
        pos = self.fh.tell()
        if n < 0 or pos + n > self.size:
            raise FormatError(self.label, f"truncated: {what} needs {n} bytes at byte {pos}, "
                              f"the file has {self.size}")  # fmt: skip
        return self.fh.read(n)

    def skip(self, n: int, what: str) -> None:
        """Step over ``n`` bytes we do not use, after checking they are there."""
        pos = self.fh.tell()
        if pos + n > self.size:
            raise FormatError(self.label, f"truncated: {what} needs {n} bytes at byte {pos}, "
                              f"the file has {self.size}")  # fmt: skip
        self.fh.seek(pos + n)

    def u8(self, what: str) -> int:
        return self.take(1, what)[0]

    def u32(self, what: str) -> int:
        return int(struct.unpack("<I", self.take(4, what))[0])

    def i32(self, what: str) -> int:
        return int(struct.unpack("<i", self.take(4, what))[0])

    def f32(self, n: int, what: str) -> np.ndarray:
        return np.frombuffer(self.take(4 * n, what), "<f4").astype(np.float64)

    def bounded(self, value: int, top: int, what: str, low: int = 0) -> int:
        if not low <= value <= top:
            raise FormatError(self.label, f"{what} is {value}, outside [{low}, {top}]")
        return value


def _angles(r: _Reader, n: int, what: str) -> np.ndarray:
    a = r.f32(2 * n, what).reshape(n, 2)
    if not np.all(np.isfinite(a)):
        raise FormatError(r.label, f"{what}: non-finite angles")
    if np.any(a[:, 0] < -1e-6) or np.any(a[:, 0] > math.radians(89.0)):
        raise FormatError(r.label, f"{what}: polar angles must lie in [0, 89] degrees "
                          "(radians in the file)")  # fmt: skip
    if np.any(np.abs(a[:, 1]) > 2 * math.pi + 1e-6):
        raise FormatError(r.label, f"{what}: azimuths must lie in [-2 pi, 2 pi] radians")
    return a


def _matrix(r: _Reader, rows: int, cols: int, scalar: int, what: str) -> Matrix:
    nbytes = rows * cols * scalar
    pos = r.fh.tell()
    if pos + nbytes > r.size:
        raise FormatError(r.label, f"truncated: {what} ({rows} x {cols}, {scalar}-byte "
                          f"scalars) needs {nbytes} bytes at byte {pos}, the file has "
                          f"{r.size}")  # fmt: skip
    r.fh.seek(pos + nbytes)
    return Matrix(pos, rows, cols, _SCALARS[scalar])


def _scalar(r: _Reader, what: str) -> int:
    s = r.u8(what)
    if s not in _SCALARS:
        raise FormatError(r.label, f"{what} is {s} bytes; expected 2 (half), 4 or 8")
    return s


def _check_shape(r: _Reader, h: UboHeader, rows: int, cols: int, what: str) -> None:
    if (rows, cols) not in ((h.count, h.width * h.height), (h.width * h.height, h.count)):
        raise FormatError(r.label, f"{what}: a {rows} x {cols} factorisation does not fit "
                          f"{len(h.lights)} lights x {len(h.views)} views of "
                          f"{h.width}x{h.height} texels")  # fmt: skip


def read_header(path: Path, name: str | None = None) -> UboHeader:
    """Parse and check the header and the factor layout (no factor is read); the matrices
    must end exactly at the end of the file. ``FormatError`` naming the file otherwise."""
    label = name or Path(path).name
    size = Path(path).stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(10)
        for prefix, variant in REFUSED.items():
            if head.startswith(prefix):
                raise FormatError(label, f"a Bonn BTF of variant {variant}, which matforge "
                                  "does not decode (supported: DFMF, FMF)")  # fmt: skip
        sig = next((s for s in SIGNATURES if head.startswith(s)), None)
        if sig is None:
            raise FormatError(label, f"not a Bonn BTF: starts with {head!r}, expected a "
                              "signature such as '!DFMF08FCR' or '!FMF06FC'")  # fmt: skip
        variant, rotations = SIGNATURES[sig]
        fh.seek(len(sig))
        r = _Reader(fh, label, size)
        start = fh.tell()
        block = r.u32("meta block size")
        version = r.bounded(r.u32("meta version"), 16, "meta version", 1)
        r.take(240, "setup, sensor and light-source strings")
        r.f32(1, "ppmm")
        rgb_scale = tuple(float(v) for v in r.f32(3, "RGB scale"))
        cosine = bool(r.u32("cosine flag")) if version > 1 else False
        if version > 2:
            r.skip(r.bounded(r.u32("XML length"), MAX_XML_BYTES, "XML length"), "XML text")
        channels = ["R", "G", "B"]
        if version > 3:
            nc = r.u32("channel count")
            if nc != 3:
                raise FormatError(label, f"{nc} colour channels; only 3-channel (RGB or "
                                  "decorrelated RGB) files are decoded")  # fmt: skip
            channels = []
            for c in range(nc):
                n = r.bounded(r.u32("channel name length"), MAX_NAME_BYTES, "name length")
                channels.append(r.take(n, f"channel {c} name").decode("latin-1").strip("\0"))
        if fh.tell() - start != block:
            raise FormatError(label, f"the meta block says {block} bytes, but its fields "
                              f"take {fh.tell() - start}")  # fmt: skip
        n_views = r.bounded(r.u32("view count"), MAX_DIRECTIONS, "view count", 1)
        views, lights = np.zeros((n_views, 2)), None
        for v in range(n_views):
            views[v] = _angles(r, 1, f"view {v}")[0]
            n_l = r.bounded(r.u32("light count"), MAX_DIRECTIONS, f"view {v}'s light count", 1)
            if lights is not None and n_l != len(lights):
                raise FormatError(label, f"view {v} lists {n_l} lights, view 0 {len(lights)}"
                                  " (the same lights must serve every view)")  # fmt: skip
            got = _angles(r, n_l, f"view {v}'s lights")
            lights = got if lights is None else lights
        assert lights is not None
        width = r.bounded(r.u32("width"), MAX_SIDE, "width", 1)
        height = r.bounded(r.u32("height"), MAX_SIDE, "height", 1)
        if rotations:
            n_rot = r.u32("rotation count")
            r.skip(36 * r.bounded(n_rot, size, "rotation count"), "rotations")
        h = UboHeader(variant, sig.decode(), version, cosine, channels, views, lights,
                      width, height, rgb_scale, file_size=size)  # type: ignore[arg-type]  # fmt: skip
        if variant == "DFMF":
            _read_dfmf(r, h)
        else:
            _read_fmf(r, h, sig)
        if fh.tell() != size:
            raise FormatError(label, f"{size - fh.tell()} bytes after the last matrix "
                              f"(it ends at byte {fh.tell()})")  # fmt: skip
    return h


def _read_dfmf(r: _Reader, h: UboHeader) -> None:
    r.bounded(r.u32("component count"), MAX_COMPONENTS, "component count")
    h.color_model = r.i32("colour model")
    if h.color_model in REFUSED_MODELS:
        raise FormatError(r.label, f"DFMF colour model {h.color_model} "
                          f"({REFUSED_MODELS[h.color_model]}) is not supported")  # fmt: skip
    if h.color_model not in COLOR_MODELS:
        raise FormatError(r.label, f"unknown DFMF colour model {h.color_model}")
    h.color_mean = r.f32(3, "colour mean")
    h.color_transform = r.f32(9, "colour transform").reshape(3, 3)
    if not (np.all(np.isfinite(h.color_mean)) and np.all(np.isfinite(h.color_transform))):
        raise FormatError(r.label, "non-finite colour mean or transform")
    for c in range(len(h.channels)):
        scalar = _scalar(r, f"channel {c} scalar size")
        k = r.bounded(r.u32("components"), MAX_COMPONENTS, f"channel {c} components", 1)
        rows, cols = r.u32("rows"), r.u32("columns")
        _check_shape(r, h, rows, cols, f"channel {c}")
        _matrix(r, 1, k, scalar, f"channel {c} singular values")
        u = _matrix(r, rows, k, scalar, f"channel {c} U")
        h.factors.append((u, _matrix(r, cols, k, scalar, f"channel {c} SxV")))


def _read_fmf(r: _Reader, h: UboHeader, sig: bytes) -> None:
    if b"FCE" in sig:
        hv = r.bounded(r.u8("FMF header version"), 2, "FMF header version")
        if hv >= 1:
            h.drr = r.u32("dynamic-range flag")
        if hv >= 2:
            mw, mh = r.u32("height-map width"), r.u32("height-map height")
            if mw * mh:
                r.bounded(mw, MAX_SIDE, "height-map width")
                r.bounded(mh, MAX_SIDE, "height-map height")
                r.skip(2 * mw * mh, "height map")
    r.bounded(r.u32("component count"), MAX_COMPONENTS, "component count")
    scalar = _scalar(r, "scalar size")
    k = r.bounded(r.u32("components"), MAX_COMPONENTS, "components", 1)
    rows, cols = r.u32("rows"), r.u32("columns")
    texels = h.width * h.height
    if (rows, cols) not in ((3 * h.count, texels), (3 * texels, h.count)):
        raise FormatError(r.label, f"FMF: a {rows} x {cols} factorisation does not fit 3 "
                          f"channels x {len(h.lights)} lights x {len(h.views)} views of "
                          f"{h.width}x{h.height} texels")  # fmt: skip
    _matrix(r, 1, k, scalar, "singular values")
    u = _matrix(r, rows, k, scalar, "U")
    h.factors.append((u, _matrix(r, cols, k, scalar, "SxV")))
