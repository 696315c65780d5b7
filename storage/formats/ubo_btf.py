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
from pathlib import Path

import numpy as np

from storage.errors import FormatError, TooLargeError
from storage.formats.btf_folder import MAX_ARCHIVE_PIXELS
from storage.formats.ubo_btf_header import (
    REFUSED,
    SIGNATURES,
    Matrix,
    UboHeader,
    read_header,
)

#: Slices decoded per matrix product, and the float32 bytes of one spatial block.
GROUP = 16
BLOCK_BYTES = 32 << 20
DRR_EPS = 1e-5
_YUV2RGB = np.array([[1.0, 0.0, 1.13983], [1.0, -0.39465, -0.5806], [1.0, 2.03211, 0.0]])
_YCOCG2RGB = np.array([[1.0, 1.0, -1.0], [1.0, 0.0, 1.0], [1.0, -1.0, -1.0]])


def sniff(path: Path) -> bool:
    """Whether ``path`` starts like a Bonn ``.btf`` (any variant, decodable or not)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(10)
    except OSError:
        return False
    return any(head.startswith(s) for s in (*SIGNATURES, *REFUSED))


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


__all__ = ["GROUP", "UboBtf", "UboHeader", "check_pixels", "read_header", "sniff",
           "validate_ubo_btf"]  # fmt: skip
