"""Writers of Bonn ``.btf`` files (DFMF and FMF), the layout :mod:`storage.formats.ubo_btf`
describes: for tests and for users who want a compact file of their own slices.

:func:`write_dfmf` / :func:`write_fmf` take the factor matrices as they lie in the file
(pairs ``view * n_lights + light``, texels ``row * width + x`` with the file's row 0 the
image's top); :func:`encode_slices` turns slices in our convention into the per-channel
matrices a colour model stores, and :func:`factorize` makes an SVD's ``(U, SxV)``.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from storage.formats.ubo_btf import _YUV2RGB, DRR_EPS

_DTYPES = {2: "<f2", 4: "<f4", 8: "<f8"}


def _meta_block(cosine_flag: bool, xml: str, channels: Sequence[str]) -> bytes:
    body = b"".join([
        struct.pack("<I", 4),  # version 4: cosine flag, XML, channel names
        b"matforge".ljust(80, b"\0"), b"synthetic".ljust(80, b"\0"), b"none".ljust(80, b"\0"),
        struct.pack("<f", 0.0), struct.pack("<3f", 1.0, 1.0, 1.0),
        struct.pack("<I", int(cosine_flag)),
        struct.pack("<I", len(xml.encode())), xml.encode(),
        struct.pack("<I", len(channels)),
        *(struct.pack("<I", len(c.encode())) + c.encode() for c in channels),
    ])  # fmt: skip
    return struct.pack("<I", len(body) + 4) + body


def _common(signature: bytes, lights: np.ndarray, views: np.ndarray, width: int, height: int,
            cosine_flag: bool, channels: Sequence[str]) -> bytes:  # fmt: skip
    lights = np.asarray(lights, "<f4").reshape(-1, 2)
    parts = [signature, _meta_block(cosine_flag, "", channels), struct.pack("<I", len(views))]
    for v in np.asarray(views, "<f4").reshape(-1, 2):
        parts += [v.tobytes(), struct.pack("<I", len(lights)), lights.tobytes()]
    parts.append(struct.pack("<II", width, height))
    if signature.endswith(b"R"):
        parts.append(struct.pack("<I", 0))
    return b"".join(parts)


def factorize(matrix: np.ndarray, components: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(U, SxV)`` of ``matrix`` (rows x cols) by SVD, truncated to ``components``:
    ``matrix ~= U @ SxV.T``."""
    u, s, vt = np.linalg.svd(np.asarray(matrix, np.float64), full_matrices=False)
    k = len(s) if components is None else components
    return u[:, :k], vt[:k].T * s[:k]


def write_dfmf(
    path: Path,
    *,
    lights: np.ndarray,
    views: np.ndarray,
    width: int,
    height: int,
    factors: Sequence[tuple[np.ndarray, np.ndarray]],
    color_model: int = 0,
    color_mean: Sequence[float] = (0.0, 0.0, 0.0),
    color_transform: np.ndarray | None = None,
    cosine_flag: bool = True,
    scalar: int = 4,
) -> Path:
    """A ``!DFMF08FCR`` file. ``lights``, ``views``: ``(n, 2)`` theta, phi in radians;
    ``factors``: per channel ``(U (count, K), SxV (width * height, K))``."""
    out = [_common(b"!DFMF08FCR", lights, views, width, height, cosine_flag, "RGB")]
    transform = np.eye(3) if color_transform is None else np.asarray(color_transform)
    k_max = max(u.shape[1] for u, _ in factors)
    out += [struct.pack("<Ii", k_max, color_model), np.asarray(color_mean, "<f4").tobytes(),
            np.asarray(transform, "<f4").tobytes()]  # fmt: skip
    dt = _DTYPES[scalar]
    for u, sxv in factors:
        k = u.shape[1]
        out += [bytes([scalar]), struct.pack("<III", k, u.shape[0], sxv.shape[0]),
                np.ones(k, dt).tobytes(), np.asarray(u, dt).tobytes(),
                np.asarray(sxv, dt).tobytes()]  # fmt: skip
    Path(path).write_bytes(b"".join(out))
    return Path(path)


def write_fmf(
    path: Path,
    *,
    lights: np.ndarray,
    views: np.ndarray,
    width: int,
    height: int,
    u: np.ndarray,
    sxv: np.ndarray,
    drr: bool = False,
    cosine_flag: bool = True,
    scalar: int = 4,
) -> Path:
    """A ``!FMF12FCER`` file: ``u`` ``(3 * count, K)`` (row ``pair * 3 + channel``),
    ``sxv`` ``(width * height, K)``; ``drr``: the values are ``log(v + eps)``."""
    dt, k = _DTYPES[scalar], u.shape[1]
    out = [_common(b"!FMF12FCER", lights, views, width, height, cosine_flag, "RGB"),
           bytes([1]), struct.pack("<I", int(drr)), struct.pack("<I", k), bytes([scalar]),
           struct.pack("<III", k, u.shape[0], sxv.shape[0]), np.ones(k, dt).tobytes(),
           np.asarray(u, dt).tobytes(), np.asarray(sxv, dt).tobytes()]  # fmt: skip
    Path(path).write_bytes(b"".join(out))
    return Path(path)


def encode_slices(
    rgb: np.ndarray, theta_i: np.ndarray, *, cosine_flag: bool = True, color_model: int = 0
) -> np.ndarray:
    """The ``(3, count, width * height)`` channel matrices a DFMF of colour model
    ``color_model`` (0 RGB, 1 YUV, 11 Ylog U/Y V/Y) stores for slices ``rgb`` ``(count, H,
    W, 3)`` in our convention (row 0 at y = 0) whose lights lie at ``theta_i`` (radians)."""
    rgb = np.asarray(rgb, np.float64)[:, ::-1]  # the file's row 0 is the image's top
    if not cosine_flag:
        rgb = rgb / np.cos(np.asarray(theta_i, np.float64))[:, None, None, None]
    v = rgb.reshape(rgb.shape[0], -1, 3)
    if color_model in (1, 11):
        v = v @ np.linalg.inv(_YUV2RGB).T
    if color_model == 11:
        y = v[..., 0].copy()
        v[..., 1:] /= (y + DRR_EPS)[..., None]
        v[..., 0] = np.log(y + DRR_EPS)
    elif color_model not in (0, 1):
        raise ValueError(f"encode_slices writes colour models 0, 1 and 11, not {color_model}")
    return np.moveaxis(v, 2, 0)
