"""The ``torch.utils.data.Dataset`` classes the readers' ``torch_dataset(...)`` return.

Imported only when a reader's ``torch_dataset`` is called, so ``import matforge`` and the
numpy readers never import torch. Every class is picklable (``DataLoader`` workers): the
BTF dataset re-opens its memory maps in each process instead of pickling the slices.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset

from matforge.datasets.npz_map import open_npz


class FabricQueryDataset(Dataset[dict[str, torch.Tensor]]):
    """Fabric queries, read lazily from the memory-mapped shards ``(path, count)`` (a
    paper-scale set is far larger than memory). Item ``i`` (shard order): ``material``
    (int64), ``center`` (2,), ``size`` (), ``wi`` (3,), ``wo`` (3,), ``value`` (4,),
    ``stderr`` (4,) (float32). The maps are re-opened in each ``DataLoader`` worker."""

    FIELDS = ("material", "center", "size", "wi", "wo", "value", "stderr")

    def __init__(self, shards: list[tuple[Path, int]]) -> None:
        self.shards = shards
        counts = np.array([c for _, c in shards], np.int64)
        self._starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
        self._total = int(counts.sum())
        self._maps: list[dict[str, np.ndarray]] | None = None

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state["_maps"] = None  # memory maps are re-opened in the receiving process
        return state

    def __len__(self) -> int:
        return self._total

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        if not 0 <= i < self._total:
            raise IndexError(i)
        if self._maps is None:
            self._maps = [open_npz(p, p.name) for p, _ in self.shards]
        j = int(np.searchsorted(self._starts, i, side="right") - 1)
        row = i - int(self._starts[j])
        arrays = self._maps[j]
        out = {k: torch.from_numpy(np.array(arrays[k][row], np.float32)) for k in self.FIELDS[1:]}
        out["material"] = torch.tensor(int(arrays["material"][row]), dtype=torch.int64)
        return out


class BtfTexelDataset(Dataset[dict[str, torch.Tensor]]):
    """Random texels x directions of a BTF: ``length`` draws of ``(slice, y, x)``, uniform
    over ``slices`` (default all) and the texels, fixed by ``seed`` (the same seed gives the
    same items in the same order). Item ``i``: ``uv`` (2,) texel centre ``((x + 0.5) / W,
    (y + 0.5) / H)``, ``wi`` (3,), ``wo`` (3,), ``rgb`` (3,) (float32), ``slice`` (int64).

    The slices are memory-mapped from ``shards`` (``(path, first slice, count)``) and
    re-opened in each ``DataLoader`` worker; nothing but the drawn indices sits in memory.
    """

    def __init__(
        self,
        shards: list[tuple[Path, int, int]],
        wi: np.ndarray,
        wo: np.ndarray,
        resolution: tuple[int, int],
        length: int,
        seed: int,
        slices: np.ndarray,
    ) -> None:
        if length < 1:
            raise ValueError(f"length must be at least 1, got {length}")
        self.shards = shards
        self.wi = torch.from_numpy(np.asarray(wi, np.float32))
        self.wo = torch.from_numpy(np.asarray(wo, np.float32))
        self.resolution = resolution
        rng = np.random.default_rng(seed)
        h, w = resolution
        self.slice = np.asarray(slices, np.int64)[rng.integers(0, len(slices), length)]
        self.y = rng.integers(0, h, length)
        self.x = rng.integers(0, w, length)
        self._starts = np.array([first for _, first, _ in shards], np.int64)
        self._maps: list[np.ndarray] | None = None

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state["_maps"] = None  # memory maps are re-opened in the receiving process
        return state

    def _rgb(self, k: int) -> np.ndarray:
        if self._maps is None:
            self._maps = [open_npz(p, p.name)["rgb"] for p, _, _ in self.shards]
        j = int(np.searchsorted(self._starts, k, side="right") - 1)
        rgb: np.ndarray = self._maps[j][k - int(self._starts[j])]
        return rgb

    def __len__(self) -> int:
        return int(self.slice.shape[0])

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        k, y, x = int(self.slice[i]), int(self.y[i]), int(self.x[i])
        h, w = self.resolution
        rgb = np.asarray(self._rgb(k)[y, x], np.float32)
        return {
            "uv": torch.tensor([(x + 0.5) / w, (y + 0.5) / h], dtype=torch.float32),
            "wi": self.wi[k],
            "wo": self.wo[k],
            "rgb": torch.from_numpy(rgb.copy()),
            "slice": torch.tensor(k, dtype=torch.int64),
        }


class MerlPairDataset(Dataset[dict[str, torch.Tensor]]):
    """``(wi, wo)`` pairs of MERL tables: for each material, ``pairs`` pairs drawn
    cosine-weighted on the upper hemisphere (:func:`evaluators.metrics.brdf.direction_pairs`,
    the hybrid-BRDF paper's fitting distribution, Sec. 3.3), and the table's value there
    (:func:`materials.halfdiff.lookup`). Item ``i``: ``material`` (int64, index into
    ``names``), ``wi`` (3,), ``wo`` (3,), ``rgb`` (3,) float32 in 1/sr (no cosine)."""

    def __init__(
        self,
        tables: list[np.ndarray],
        names: list[str],
        pairs: int,
        seed: int,
        interpolate: bool,
    ) -> None:
        from evaluators.metrics.brdf import direction_pairs
        from materials.halfdiff import lookup

        self.names = names
        wis, wos, values, mats = [], [], [], []
        for m, rgb in enumerate(tables):
            wi, wo = direction_pairs(pairs, seed=seed + m)
            wis.append(wi)
            wos.append(wo)
            values.append(lookup(rgb, wi, wo, interpolate=interpolate))
            mats.append(np.full(pairs, m, np.int64))
        self.material = torch.from_numpy(np.concatenate(mats))
        self.wi = torch.from_numpy(np.concatenate(wis).astype(np.float32))
        self.wo = torch.from_numpy(np.concatenate(wos).astype(np.float32))
        self.rgb = torch.from_numpy(np.concatenate(values).astype(np.float32))

    def __len__(self) -> int:
        return int(self.material.shape[0])

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        return {"material": self.material[i], "wi": self.wi[i], "wo": self.wo[i],
                "rgb": self.rgb[i]}  # fmt: skip


class GlintNdfDataset(Dataset[dict[str, torch.Tensor]]):
    """Every cell of every NDF level of a glint example. Item ``i`` (level by level, then
    ``[ty, tx, iy, ix]`` order): ``level`` (int64), ``uv`` (2,) the tile's centre in
    example units (``[0, 1]^2``), ``footprint`` () the tile's side in example units,
    ``s`` (2,) the cell's centre in slope space ``(n_x, n_y)``, ``density`` () the mean
    P-NDF density over the cell (float32)."""

    def __init__(self, levels: list[np.ndarray], extent: float) -> None:
        self.levels = [np.asarray(x, np.float32) for x in levels]
        self.extent = float(extent)
        self._ends = np.cumsum([x.size for x in self.levels])

    def __len__(self) -> int:
        return int(self._ends[-1]) if len(self._ends) else 0

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        if not 0 <= i < len(self):
            raise IndexError(i)
        level = int(np.searchsorted(self._ends, i, side="right"))
        k = i - (int(self._ends[level - 1]) if level else 0)
        arr = self.levels[level]
        ty, tx, iy, ix = np.unravel_index(k, arr.shape)
        r, big_r = arr.shape[0], arr.shape[2]
        cell = 2.0 * self.extent / big_r
        return {
            "level": torch.tensor(level, dtype=torch.int64),
            "uv": torch.tensor([(tx + 0.5) / r, (ty + 0.5) / r], dtype=torch.float32),
            "footprint": torch.tensor(1.0 / r, dtype=torch.float32),
            "s": torch.tensor(
                [-self.extent + (ix + 0.5) * cell, -self.extent + (iy + 0.5) * cell],
                dtype=torch.float32,
            ),
            "density": torch.tensor(float(arr[ty, tx, iy, ix]), dtype=torch.float32),
        }
