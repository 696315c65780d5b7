"""UBO2014's own ``.btf`` files (the Bonn BTF database's binary formats), read streaming.

Written from the format as Bonn's btflib (``read_meta_data.m``, ``read_common_header.m``,
``read_bidir_sampling.m``, ``read_ubo_dfmf.m``, ``read_ubo_fmf.m``, ``undecorrelate.m``)
and Velinov's ``btf.hh`` read it; no code of theirs is used. All numbers little-endian.

**Layout.** A signature, then the common header, then the variant's factors:

- signature: ``!DFMF08FC`` (DFMF, decorrelated full matrix factorisation: one SVD per
  decorrelated colour channel; UBO2014's files), ``!FMF06FC`` / ``!FMF12FCE`` (FMF, one
  SVD of all channels), each optionally followed by ``R`` (rotations stored). ``!BDIF``
  (uncompressed chunks) and ``!PVF`` (per-view factorisation) are recognised and refused.
- meta block: ``uint32 size`` (bytes of the block, itself included), ``uint32 version``,
  three ``char[80]`` (setup, sensor, light source), ``float32 ppmm``, ``float32[3]`` RGB
  scale (recorded, not applied: btflib does not apply it); version > 1: ``uint32`` cosine
  flag; > 2: ``uint32`` length + XML text; > 3: ``uint32`` channel count, each name as
  ``uint32`` length + text.
- sampling: ``uint32 n_views``; per view ``float32 theta, phi`` (radians) and ``uint32
  n_lights`` + ``n_lights x float32 theta, phi``; every view lists the same lights.
- ``uint32 width, height``; with ``R``: ``uint32 n`` + ``n x float32[3][3]``.
- DFMF: ``uint32 K_max``, ``int32 colour model``, ``float32[3]`` mean, ``float32[3][3]``
  transform (row-major); then per channel ``uint8`` scalar size (2 half, 4 float, 8 double),
  ``uint32 K``, ``uint32 rows``, ``uint32 cols``, ``K`` singular values, ``U`` (rows x K,
  row-major), ``SxV`` (cols x K, the right vectors already times the singular values).
- FMF (``!FMF12FCE``: ``uint8`` header version; >= 1 ``uint32`` dynamic-range flag; >= 2
  ``uint32 w, h`` + ``uint16`` half height map): ``uint32 K``, ``uint8`` scalar size,
  ``uint32 K``, ``rows``, ``cols``, then ``S``, ``U``, ``SxV`` as above, one matrix for all
  channels.
- nothing after the last matrix.

**Decoding** (one slice = one (light, view) pair). Pair ``p = view * n_lights + light``
(btflib's ``sub2ind([nL, nV], l, v)``); texel ``t = row * width + x`` with the file's row 0
the image's top. A DFMF channel ``c`` is ``U_c[p] . SxV_c[t]`` (or ``SxV_c[p] . U_c[t]`` when
U has ``width * height`` rows: btflib accepts both orientations); an FMF value is
``U[p * C + c] . SxV[t]`` (or ``SxV[p] . U[t * C + c]``). Then, as btflib's
``undecorrelate``: colour model 0 RGB, 1 YUV (RGB = M (Y, U, V) with btflib's YUV->RGB
matrix), 3 PCA (``rgb = v @ T + mean``), 4 YCoCg, 9 ``Y = exp(y) - eps``, 10 also
``U, V = sign * exp(|u| + log eps)``, 11 ``Y = exp(y) - eps``, ``U, V = u, v * (Y + eps)``,
12 ``rgb = exp(v) - eps``, with ``eps = 1e-5``; 2 (Lab) and 5, 6 (spectral) are refused.
FMF's dynamic-range flag: ``rgb = exp(v) - eps``.

**Our convention** (:mod:`storage.formats.btf`): ``BTF = L_o / E_perp`` with the cosine
included. btflib divides by ``cos theta_i`` when the cosine flag says the data carries it,
to give the cosine-free value, so ours is the stored value when the flag is set and the
stored value times ``cos theta_i`` when it is not. Rows are flipped (row 0 at ``y = 0``, as
``btf.hh`` flips them), directions are ``(sin t cos p, sin t sin p, cos t)`` in the patch
frame, z up, ``i`` the light. Negative reconstructions (truncation ringing of the SVD)
are set to 0 (counted in :attr:`UboBtf.negatives`).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

import numpy as np

from storage.errors import FormatError, TooLargeError
from storage.formats.btf_folder import MAX_ARCHIVE_PIXELS

#: Signatures we decode (longest first: a trailing ``R`` means rotations are stored).
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
#: Slices decoded per matrix product, and the float32 bytes of one spatial block.
GROUP = 16
BLOCK_BYTES = 32 << 20
DRR_EPS = 1e-5
COLOR_MODELS = {0: "RGB", 1: "YUV", 3: "PCA", 4: "YCoCg", 9: "Ylog_UV", 10: "Ylog_Ulog_Vlog",
                11: "Ylog_UdivY_VdivY", 12: "log RGB"}  # fmt: skip
REFUSED_MODELS = {2: "Lab", 5: "spectral", 6: "spectral linear"}
_YUV2RGB = np.array([[1.0, 0.0, 1.13983], [1.0, -0.39465, -0.5806], [1.0, 2.03211, 0.0]])
_YCOCG2RGB = np.array([[1.0, 1.0, -1.0], [1.0, 0.0, 1.0], [1.0, -1.0, -1.0]])
_SCALARS = {2: "<f2", 4: "<f4", 8: "<f8"}


def sniff(path: Path) -> bool:
    """Whether ``path`` starts like a Bonn ``.btf`` (any variant, decodable or not)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(10)
    except OSError:
        return False
    return any(head.startswith(s) for s in (*SIGNATURES, *REFUSED))


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


def validate_ubo_btf(
    path: Path, name: str | None = None, max_pixels: int | None = MAX_ARCHIVE_PIXELS
) -> None:
    """Validator for ``.btf`` uploads: the header and the factor layout (exact file size);
    with ``max_pixels``, the slices together must decode to at most that many pixels."""
    h = read_header(Path(path), name)
    check_pixels(h, name or Path(path).name, max_pixels)


def check_pixels(h: UboHeader, label: str, max_pixels: int | None) -> int:
    total = h.count * h.width * h.height
    if max_pixels is not None and total > max_pixels:
        raise TooLargeError(
            f"{label}: {h.count} slices of {h.width}x{h.height} decode to {total} pixels "
            f"({total * 12 / 1e9:.2f} GB as float32 RGB), over the limit of {max_pixels}"
        )
    return total


class UboBtf:
    """An opened Bonn ``.btf``: :attr:`header`, and :meth:`decode` of slices in our
    convention. The factors are memory-mapped; a decode holds ``GROUP`` slices and one
    spatial block of at most ``BLOCK_BYTES`` in memory, never the whole BTF."""

    def __init__(self, path: Path, name: str | None = None) -> None:
        self.path = Path(path)
        self.label = name or self.path.name
        self.header = read_header(self.path, self.label)
        self.negatives = 0

    def _map(self, m: Matrix) -> np.ndarray:
        return np.memmap(self.path, dtype=m.dtype, mode="r", offset=m.offset,
                         shape=(m.rows, m.cols))  # fmt: skip

    def _channel(self, c: int) -> tuple[np.ndarray, np.ndarray]:
        """``(angular (count, K), spatial (texels, K))`` factors of channel ``c``."""
        # btflib tries the ABRDF-major orientation (U over light-view pairs) first.
        h = self.header
        if h.variant == "DFMF":
            u, sxv = (self._map(m) for m in h.factors[c])
            return (u, sxv) if u.shape[0] == h.count else (sxv, u)
        u, sxv = (self._map(m) for m in h.factors[0])
        return (u[c::3], sxv) if u.shape[0] == 3 * h.count else (sxv, u[c::3])

    def decode(
        self, indices: list[int] | range, *, cosine_in_data: bool | None = None
    ) -> np.ndarray:
        """Slices ``indices`` (file order, :meth:`UboHeader.pair`) as ``(n, H, W, 3)``
        float32 in our convention (see the module docstring). ``cosine_in_data`` overrides
        the file's cosine flag (``None``: trust the flag)."""
        h = self.header
        idx = np.asarray(list(indices), np.int64)
        if idx.size and (idx.min() < 0 or idx.max() >= h.count):
            raise IndexError(f"slice indices must lie in [0, {h.count})")
        texels = h.width * h.height
        raw = np.empty((3, len(idx), texels), np.float64)  # channel-major: contiguous writes
        for c in range(3):
            a, b = self._channel(c)
            rows = np.asarray(a[idx], np.float64)  # (n, K)
            step = max(1, BLOCK_BYTES // (8 * b.shape[1]))
            for t0 in range(0, texels, step):
                block = np.asarray(b[t0 : t0 + step], np.float64)  # (B, K)
                np.matmul(rows, block.T, out=raw[c, :, t0 : t0 + step])
        rgb = self._to_rgb(np.moveaxis(raw, 0, -1))
        if not np.all(np.isfinite(rgb)):
            raise FormatError(self.label, "decodes to non-finite values (corrupt factors)")
        in_data = h.cosine_flag if cosine_in_data is None else cosine_in_data
        if not in_data:  # stored without the cosine: our convention includes it
            rgb *= np.cos(h.lights[idx % len(h.lights), 0])[:, None, None]
        neg = rgb < 0
        self.negatives += int(neg.sum())
        rgb[neg] = 0.0
        out = rgb.reshape(len(idx), h.height, h.width, 3)[:, ::-1]  # file row 0 = image top
        return np.ascontiguousarray(out, dtype=np.float32)

    def _to_rgb(self, v: np.ndarray) -> np.ndarray:
        h, eps = self.header, DRR_EPS
        m = h.color_model if h.variant == "DFMF" else 0
        if m == 1:
            v = _mix(v, _YUV2RGB.T)
        elif m == 3:
            v = _mix(v, h.color_transform) + h.color_mean
        elif m == 4:
            v = _mix(v, _YCOCG2RGB.T)
        elif m in (9, 10, 11):
            y = np.exp(v[..., 0]) - eps
            if m == 10:
                v[..., 1:] = np.sign(v[..., 1:]) * np.exp(np.abs(v[..., 1:]) + math.log(eps))
            elif m == 11:
                v[..., 1:] *= (y + eps)[..., None]
            v[..., 0] = y
            v = _mix(v, _YUV2RGB.T)
        elif m == 12:
            v = np.exp(v) - eps
        if h.variant == "FMF" and h.drr:
            v = np.exp(v) - eps
        return v


def _mix(v: np.ndarray, m: np.ndarray) -> np.ndarray:
    """``v @ m`` over the last axis (``einsum``: a stacked ``@`` of 1 x 3 rows, or BLAS on
    an ``(N, 3)`` matrix, was several times slower here)."""
    return np.einsum("...j,jk->...k", v, m)
