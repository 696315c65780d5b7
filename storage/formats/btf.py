"""BTF slice shards (``slices-XXXX.npz``) and their index (``btf.json``).

A BTF dataset (``generate.btf`` or ``import.btf``) is a list of shards plus one index:

- ``slices-XXXX.npz`` (``XXXX`` from 0000): ``wi`` ``(N, 3)`` float32 light directions,
  ``wo`` ``(N, 3)`` float32 view directions (unit vectors in the patch's frame, z up,
  pointing away from the surface), ``rgb`` ``(N, H, W, 3)`` float32 (or float16) slices,
  ``[row = y, column = x]``, in UBO2014's convention ``BTF = L_o / E_perp`` (1/sr,
  foreshortening included), and ``stderr`` ``(N,)`` float32: each slice's Monte Carlo
  standard error (RMS over texels and channels; ``NaN``, unknown, for measured slices).
- ``btf.json``: ``{"format": "matforge.btf", "version": 1, "resolution": [H, W], "count":
  N, "shards": [{"name", "count"}, ...], "convention", "units", ...}``; the shards, in
  order, hold the slices ``0 .. N - 1``.

Readers stream one shard at a time: a paper-scale BTF (151 x 151 slices of 400 x 400) is
tens of gigabytes and never sits in memory.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO, NotRequired  # pydantic needs this TypedDict on 3.11

import numpy as np
from pydantic import ConfigDict, with_config
from typing_extensions import TypedDict

from storage.errors import FormatError
from storage.formats.npz import StreamedArray, npz_bytes, read_npz, write_npz

FORMAT = "matforge.btf"
VERSION = 1
CONVENTION = (
    "UBO2014: BTF = L_o / E_perp (radiance over the irradiance perpendicular to the light), "
    "foreshortening included; a flat Lambertian plane gives albedo / pi * cos(theta_i)"
)
UNITS = "1/sr"


def shard_name(index: int) -> str:
    """``slices-0000.npz`` style name of shard ``index``."""
    return f"slices-{index:04d}.npz"


def shard_bytes(
    wi: np.ndarray, wo: np.ndarray, rgb: np.ndarray, stderr: np.ndarray, dtype: str = "float32"
) -> bytes:
    """One shard's deterministic ``.npz`` bytes (see the module docstring)."""
    rgb = np.asarray(rgb)
    n = rgb.shape[0]
    if rgb.ndim != 4 or rgb.shape[3] != 3:
        raise ValueError(f"rgb must be (N, H, W, 3), got {rgb.shape}")
    if np.shape(wi) != (n, 3) or np.shape(wo) != (n, 3) or np.shape(stderr) != (n,):
        raise ValueError("wi, wo must be (N, 3) and stderr (N,) for N slices")
    return npz_bytes(
        {
            "wi": np.asarray(wi, np.float32),
            "wo": np.asarray(wo, np.float32),
            "rgb": rgb.astype(dtype),
            "stderr": np.asarray(stderr, np.float32),
        }
    )


def write_shard(
    fp: BinaryIO,
    wi: np.ndarray,
    wo: np.ndarray,
    slices: Iterable[np.ndarray],
    resolution: tuple[int, int],
    stderr: np.ndarray,
    dtype: str = "float32",
) -> None:
    """Write :func:`shard_bytes`'s bytes to ``fp``, taking the ``(H, W, 3)`` slices one at a
    time from ``slices`` (one per row of ``wi``): a shard of large slices is never whole in
    memory. ``resolution`` is ``(H, W)``."""
    n = len(wi)
    if np.shape(wi) != (n, 3) or np.shape(wo) != (n, 3) or np.shape(stderr) != (n,):
        raise ValueError("wi, wo must be (N, 3) and stderr (N,) for N slices")
    h, w = resolution

    def checked() -> Iterator[np.ndarray]:
        for k, s in enumerate(slices):
            if k >= n or np.shape(s) != (h, w, 3):
                raise ValueError(f"slice {k}: expected {n} slices of shape {(h, w, 3)}")
            yield np.asarray(s)[None]

    write_npz(
        fp,
        {
            "wi": np.asarray(wi, np.float32),
            "wo": np.asarray(wo, np.float32),
            "rgb": StreamedArray((n, h, w, 3), dtype, checked()),
            "stderr": np.asarray(stderr, np.float32),
        },
    )


@dataclass(frozen=True)
class Shard:
    """One shard's arrays (see the module docstring)."""

    wi: np.ndarray
    wo: np.ndarray
    rgb: np.ndarray
    stderr: np.ndarray

    def __len__(self) -> int:
        return int(self.rgb.shape[0])


def _check_dirs(label: str, key: str, w: np.ndarray, n: int) -> None:
    if w.shape != (n, 3):
        raise FormatError(label, f"{key} must be ({n}, 3), got {w.shape}")
    if np.any(np.abs(np.linalg.norm(w, axis=1) - 1.0) > 1e-3):
        raise FormatError(label, f"{key} must hold unit vectors")
    if np.any(w[:, 2] <= 0.0):
        raise FormatError(label, f"{key} must point above the surface (z > 0)")


def read_shard(path: Path, name: str | None = None) -> Shard:
    """The arrays of a shard; ``FormatError`` naming it if anything is missing or wrong
    (shapes, unit directions above the plane, finite non-negative slices)."""
    label = name or str(path)
    arrays = read_npz(path, label, nan_ok=("stderr",))
    for key in ("wi", "wo", "rgb", "stderr"):
        if key not in arrays:
            raise FormatError(label, f"missing array {key!r} (a BTF shard has wi, wo, rgb, stderr)")
    rgb = arrays["rgb"]
    if rgb.ndim != 4 or rgb.shape[3] != 3 or rgb.dtype.kind != "f":
        raise FormatError(label, f"rgb must be float (N, H, W, 3), got {rgb.dtype} {rgb.shape}")
    n = rgb.shape[0]
    _check_dirs(label, "wi", arrays["wi"], n)
    _check_dirs(label, "wo", arrays["wo"], n)
    if arrays["stderr"].shape != (n,):
        raise FormatError(label, f"stderr must be ({n},), got {arrays['stderr'].shape}")
    if np.any(rgb < 0):
        raise FormatError(label, "rgb has negative values")
    return Shard(wi=arrays["wi"], wo=arrays["wo"], rgb=rgb, stderr=arrays["stderr"])


#: ``btf.json`` is open: each source adds its own keys (``surface``, ``spp``, ``ubo``, ...).
_OPEN = ConfigDict(extra="allow", use_attribute_docstrings=True)


@with_config(ConfigDict(extra="forbid", use_attribute_docstrings=True))
class BtfShardEntry(TypedDict):
    """One shard of the index."""

    name: str
    """``slices-XXXX.npz``."""
    count: int
    """Its slices."""


@with_config(_OPEN)
class BtfIndexDocument(TypedDict):
    """``btf.json`` of ``generate.btf`` and ``import.btf``: the index of the slice shards
    (:func:`index_document`; :func:`parse_index` checks the counts add up). Other keys are
    the source's own (``generate.btf``: ``surface``, ``spp``, ``max_depth``, ``jitter``,
    ``patch``, ``mitsuba_variant``; ``import.btf``: ``archive``, ``archive_name``,
    ``scale``, a Bonn file's ``ubo``)."""

    format: str
    """``matforge.btf``."""
    version: int
    """The index's version (1)."""
    resolution: list[int]
    """The slices' ``[H, W]``."""
    count: int
    """Slices, all shards."""
    shards: list[BtfShardEntry]
    """The shards, in slice order."""
    convention: str
    """What a value is (UBO2014's ``L_o / E_perp``, foreshortening included)."""
    units: str
    """``1/sr``."""
    layout: str
    """The arrays' layout."""
    source: NotRequired[str]
    """The kind that wrote it."""
    directions: NotRequired[list[list[float]]]
    """Per slice ``[theta_i, phi_i, theta_o, phi_o]``, degrees."""
    dtype: NotRequired[str]
    """The slices' float type (``float32``, ``float16``)."""
    stderr: NotRequired[dict[str, float] | None]
    """The slices' Monte Carlo standard errors: ``mean``, ``max`` and ``relative`` (to the
    mean BTF value; ``null``: measured slices)."""


@dataclass(frozen=True)
class BtfIndex:
    """A parsed ``btf.json``: ``resolution`` ``(H, W)``, ``count`` slices, ``shards`` as
    ``(name, count)`` in order, and the whole document."""

    resolution: tuple[int, int]
    count: int
    shards: tuple[tuple[str, int], ...]
    doc: dict[str, Any]


def index_document(
    resolution: tuple[int, int], shards: list[tuple[str, int]], **extra: Any
) -> dict[str, Any]:
    """A ``btf.json`` document; ``extra`` keys (surface, directions, spp, ...) are added."""
    doc: dict[str, Any] = {
        "format": FORMAT,
        "version": VERSION,
        "resolution": [int(resolution[0]), int(resolution[1])],
        "count": int(sum(c for _, c in shards)),
        "shards": [{"name": s, "count": int(c)} for s, c in shards],
        "convention": CONVENTION,
        "units": UNITS,
        "layout": "rgb[slice, row = y, column = x, channel]; texel centres at (i + 0.5) / W",
    }
    doc.update(extra)
    return doc


def parse_index(data: bytes | str, name: str = "btf.json") -> BtfIndex:
    """Parse and check a ``btf.json``; ``FormatError`` naming it when malformed."""
    try:
        doc = json.loads(data)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise FormatError(name, f"not JSON: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise FormatError(name, f"not a BTF index (expected format {FORMAT!r})")
    try:
        h, w = (int(v) for v in doc["resolution"])
        shards = tuple((str(s["name"]), int(s["count"])) for s in doc["shards"])
        count = int(doc["count"])
    except (KeyError, TypeError, ValueError) as exc:
        raise FormatError(name, f"malformed BTF index: {exc!r}") from None
    if sum(c for _, c in shards) != count or count < 1 or h < 1 or w < 1:
        raise FormatError(name, "shard counts do not add up to 'count', or sizes are empty")
    return BtfIndex(resolution=(h, w), count=count, shards=shards, doc=doc)


def iter_shards(index: BtfIndex, open_shard: Any) -> Iterator[tuple[int, Shard]]:
    """``(first slice index, shard)`` for each shard in order; ``open_shard(name)`` gives a
    verified path. Checks each shard against the index (count, resolution)."""
    first = 0
    for name, count in index.shards:
        shard = read_shard(Path(open_shard(name)), name)
        if len(shard) != count or shard.rgb.shape[1:3] != index.resolution:
            raise FormatError(
                name,
                f"holds {len(shard)} slices of {shard.rgb.shape[1:3]}, but btf.json says "
                f"{count} of {index.resolution}",
            )
        yield first, shard
        first += count
