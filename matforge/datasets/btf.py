"""``BtfSlices``: a ``generate.btf`` or ``import.btf`` dataset, lazy and memory-mapped.

The slices are in UBO2014's convention (``BTF = L_o / E_perp``, 1/sr, foreshortening
included: a flat Lambertian plane gives ``albedo / pi * cos(theta_i)``). Slice ``k`` is the
image ``(H, W, 3)`` ``[row = y, column = x, channel]`` seen from ``wo[k]`` under a light
from ``wi[k]`` (unit vectors in the patch's frame, z up, pointing away from the surface);
texel ``(y, x)`` has its centre at ``uv = ((x + 0.5) / W, (y + 0.5) / H)``. The layout is
:mod:`storage.formats.btf`'s (``btf.json`` and ``slices-XXXX.npz``).

Nothing is read until it is asked for: a paper-scale BTF (151 x 151 slices of 400 x 400
texels) is tens of gigabytes, and each shard is memory-mapped, not loaded.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from matforge.datasets.base import DatasetReader
from matforge.datasets.npz_map import open_npz
from matforge.datasets.source import Source
from storage.errors import FormatError
from storage.formats.btf import parse_index


class BtfSlices(DatasetReader):
    """The slices of a BTF job: ``(wi, wo) -> slice`` and texel queries.

    Attributes
    ----------
    resolution
        ``(H, W)`` texels.
    wi, wo
        ``(N, 3)`` float32 light and view directions of the ``N`` slices, in slice order.
    stderr
        ``(N,)`` float32 Monte Carlo standard error of each slice (``NaN`` when unknown,
        e.g. measured slices).
    index
        ``btf.json`` (directions as angles, surface, spp, convention, units, ...).

    Examples
    --------
    >>> btf = matforge.datasets.open(job_id, data_dir="matforge-data")  # doctest: +SKIP
    >>> btf.slice(0).shape  # (H, W, 3), memory-mapped
    >>> btf.lookup(wi, wo)  # the slice measured at the nearest (wi, wo)
    >>> btf.texels([[0.5, 0.5]], slices=[0, 1])  # (2, 1, 3)
    """

    KINDS = ("generate.btf", "import.btf")

    def __init__(self, source: Source) -> None:
        super().__init__(source)
        idx = parse_index(source.read_bytes("btf.json"))
        self.index: dict[str, Any] = idx.doc
        self.resolution: tuple[int, int] = idx.resolution
        self._shards: list[tuple[str, int, int]] = []
        first = 0
        for name, count in idx.shards:
            self._shards.append((name, first, count))
            first += count
        self._starts = np.array([f for _, f, _ in self._shards], np.int64)
        self._maps: dict[str, dict[str, np.ndarray]] = {}
        wi, wo, err = [], [], []
        for name, _, count in self._shards:
            arrays = self._shard(name)
            if arrays["rgb"].shape[0] != count or tuple(arrays["rgb"].shape[1:3]) != tuple(
                self.resolution
            ):
                raise FormatError(
                    name,
                    f"holds rgb {arrays['rgb'].shape}, but btf.json says {count} slices of "
                    f"{self.resolution}",
                )
            wi.append(np.asarray(arrays["wi"], np.float32))
            wo.append(np.asarray(arrays["wo"], np.float32))
            err.append(np.asarray(arrays["stderr"], np.float32))
        self.wi = np.concatenate(wi)
        self.wo = np.concatenate(wo)
        self.stderr = np.concatenate(err)

    def _shard(self, name: str) -> dict[str, np.ndarray]:
        if name not in self._maps:
            arrays = open_npz(self.source.path(name), name)
            for key in ("wi", "wo", "rgb", "stderr"):
                if key not in arrays:
                    raise FormatError(name, f"missing array {key!r} (a BTF shard has wi, wo, "
                                      "rgb, stderr)")  # fmt: skip
            self._maps[name] = arrays
        return self._maps[name]

    def __len__(self) -> int:
        return int(self.wi.shape[0])

    @property
    def shard_paths(self) -> list[tuple[Path, int, int]]:
        """``(verified local file, first slice, count)`` of each shard, in order."""
        return [(self.source.path(n), first, count) for n, first, count in self._shards]

    def slice(self, k: int) -> np.ndarray:
        """Slice ``k``: ``(H, W, 3)`` (a read-only memory map; ``np.array`` it to copy)."""
        n = len(self)
        if not -n <= k < n:
            raise IndexError(f"slice {k} out of range: the BTF has {n} slices")
        k %= n
        j = int(np.searchsorted(self._starts, k, side="right") - 1)
        name, first, _ = self._shards[j]
        rgb: np.ndarray = self._shard(name)["rgb"][k - first]
        return rgb

    def nearest(self, wi: Any, wo: Any) -> int:
        """The index of the slice whose ``(wi, wo)`` is nearest to the given pair (the sum
        of the two angles between directions, radians); directions need not be unit."""
        a = np.asarray(wi, np.float64).reshape(3)
        b = np.asarray(wo, np.float64).reshape(3)
        a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
        ang = np.arccos(np.clip(self.wi @ a, -1, 1)) + np.arccos(np.clip(self.wo @ b, -1, 1))
        return int(np.argmin(ang))

    def lookup(self, wi: Any, wo: Any) -> np.ndarray:
        """``(wi, wo) -> slice``: the slice at the nearest measured pair (:meth:`nearest`),
        ``(H, W, 3)``. No interpolation between directions."""
        return self.slice(self.nearest(wi, wo))

    def texels(self, uv: Any, slices: Any = None) -> np.ndarray:
        """Values at texture coordinates ``uv`` ``(M, 2)`` in ``[0, 1)`` (nearest texel:
        ``x = floor(u W)``, ``y = floor(v H)``, wrapped) for ``slices`` (indices; default
        all): ``(S, M, 3)`` float32."""
        uv = np.asarray(uv, np.float64).reshape(-1, 2)
        h, w = self.resolution
        x = np.floor(uv[:, 0] * w).astype(np.int64) % w
        y = np.floor(uv[:, 1] * h).astype(np.int64) % h
        ks = range(len(self)) if slices is None else [int(k) for k in np.ravel(slices)]
        return np.stack([np.asarray(self.slice(k)[y, x], np.float32) for k in ks])

    def numpy(self) -> dict[str, np.ndarray]:
        """Everything in memory: ``wi`` (N, 3), ``wo`` (N, 3), ``stderr`` (N,) and ``rgb``
        (N, H, W, 3) (its dtype as stored). Only for BTFs that fit in memory; use
        :meth:`slice` or :meth:`torch_dataset` for large ones."""
        rgb = np.concatenate([np.asarray(self._shard(n)["rgb"]) for n, _, _ in self._shards])
        return {"wi": self.wi.copy(), "wo": self.wo.copy(), "stderr": self.stderr.copy(),
                "rgb": rgb}  # fmt: skip

    def torch_dataset(self, length: int = 65536, *, seed: int = 0, slices: Any = None) -> Any:
        """A ``torch.utils.data.Dataset`` of ``length`` random texels x directions
        (uniform over ``slices``, default all, and over the texels; fixed by ``seed``):
        items ``uv`` (2,), ``wi`` (3,), ``wo`` (3,), ``rgb`` (3,), ``slice``
        (:class:`matforge.datasets.torch_data.BtfTexelDataset`)."""
        from matforge.datasets.torch_data import BtfTexelDataset

        ks = np.arange(len(self)) if slices is None else np.asarray(slices, np.int64).ravel()
        if ks.size == 0 or ks.min() < 0 or ks.max() >= len(self):
            raise ValueError(f"slices must be indices in 0 .. {len(self) - 1}")
        return BtfTexelDataset(
            self.shard_paths, self.wi, self.wo, self.resolution, length, seed, ks
        )
