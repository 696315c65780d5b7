"""``GlintExample``: a ``generate.glint`` dataset (Xing et al. 2024).

- ``example``: ``(n, n, 3)`` float32 tangent-space unit normals, z up, ``[row = y, column
  = x]``, texel centres at ``i + 0.5``, bilinear between centres, tiled.
- ``levels[l]``: ``(r, r, R, R)`` float32 for ``l = 0 .. log2(n) - 1``, ``r = n / 2**(l+1)``,
  indexed ``[ty, tx, iy, ix]``; tile ``(tx, ty)`` covers texels ``[tx n/r, (tx+1) n/r) x
  [ty n/r, (ty+1) n/r)``; each cell the mean P-NDF density over its cell of slope space
  ``s = (n_x, n_y)`` in ``[-e, e]^2`` (edges ``linspace(-e, e, R + 1)``, ``e`` the extent).
- ``lobes``: the 4D Gaussian lobes (``u``, ``s``, ``jacobian``, ``weight``, ``sigma_h``,
  ``sigma_r``, ``size``, ``rate``), as ``lobes.npz`` holds them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from matforge.datasets.base import DatasetReader
from matforge.datasets.npz_map import open_npz
from matforge.datasets.source import Source
from storage.errors import FormatError
from storage.formats.exr import read_exr


class GlintExample(DatasetReader):
    """The example, the lobes and the NDF levels of a ``generate.glint`` job.

    Attributes
    ----------
    example
        ``(n, n, 3)`` float32 unit normals.
    levels
        ``[level_0, level_1, ...]``, each ``(r, r, R, R)`` float32 (see the module docstring).
    sigma_r, extent
        The intrinsic roughness and the slope-space half-width ``e`` of the maps.
    lobes
        The lobe arrays by name.
    stats
        ``stats.json`` (sizes, bytes; the precompute seconds only in a job made before
        timings moved to the manifest, ``timings.measured.precompute_seconds``).
    """

    KINDS = ("generate.glint",)

    def __init__(self, source: Source) -> None:
        super().__init__(source)
        self.example: np.ndarray = read_exr(source.path("example.exr"), "example.exr")
        ndf = open_npz(source.path("ndf.npz"), "ndf.npz")
        keys = sorted((k for k in ndf if k.startswith("level_")), key=lambda k: int(k[6:]))
        if [int(k[6:]) for k in keys] != list(range(len(keys))) or not keys:
            raise FormatError("ndf.npz", f"levels must be level_0 .. level_L, got {keys}")
        for key in ("sigma_r", "extent"):
            if key not in ndf:
                raise FormatError("ndf.npz", f"missing scalar {key!r}")
        self.levels: list[np.ndarray] = [np.asarray(ndf[k]) for k in keys]
        self.sigma_r = float(ndf["sigma_r"])
        self.extent = float(ndf["extent"])
        self.lobes: dict[str, np.ndarray] = {
            k: np.asarray(v) for k, v in open_npz(source.path("lobes.npz"), "lobes.npz").items()
        }
        self.stats: dict[str, Any] = (
            source.read_json("stats.json") if "stats.json" in source.artifacts else {}
        )

    @property
    def size(self) -> int:
        """``n``, the example's side in texels."""
        return int(self.example.shape[0])

    def edges(self, level: int = 0) -> np.ndarray:
        """The slope-space cell edges of the maps, ``linspace(-e, e, R + 1)``."""
        big_r = self.levels[level].shape[2]
        return np.linspace(-self.extent, self.extent, big_r + 1)

    def numpy(self) -> dict[str, Any]:
        """``example``, ``levels`` (list), ``lobes`` (dict), ``sigma_r``, ``extent``."""
        return {"example": self.example, "levels": list(self.levels), "lobes": dict(self.lobes),
                "sigma_r": self.sigma_r, "extent": self.extent}  # fmt: skip

    def torch_dataset(self) -> Any:
        """A ``torch.utils.data.Dataset`` of every NDF cell of every level: ``level``,
        ``uv`` (tile centre in ``[0, 1]^2``), ``footprint`` (tile side), ``s`` (cell centre
        in slope space), ``density``
        (:class:`matforge.datasets.torch_data.GlintNdfDataset`)."""
        from matforge.datasets.torch_data import GlintNdfDataset

        return GlintNdfDataset(self.levels, self.extent)
