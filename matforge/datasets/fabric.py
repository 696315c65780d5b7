"""``FabricQueries``: a ``generate.fabric`` dataset (Chen et al. 2024, Sec. 5.1).

Each query is a footprint on the fabric (``center`` ``(2,)`` and ``size``, in tile units), a
light ``wi`` and a view ``wo`` ``(3,)`` (unit vectors in the macro frame, z up), and the four
aggregated components ``value`` ``(4,)`` with their Monte Carlo standard errors ``stderr``
``(4,)``, in the order of :attr:`FabricQueries.components` (C_warp, C_weft, S_warp, S_weft:
Eq. 7, unit albedos, incident cosine included). ``material`` is the index into
:attr:`FabricQueries.materials`, whose entries hold each material's parameters.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from matforge.datasets.base import DatasetReader
from matforge.datasets.npz_map import open_npz
from matforge.datasets.source import Source
from storage.errors import FormatError

#: The arrays of every query (see the module docstring), in shard order.
FIELDS = ("material", "center", "size", "wi", "wo", "value", "stderr")


class FabricQueries(DatasetReader):
    """The queries of a ``generate.fabric`` job, per material, with the parameters.

    Attributes
    ----------
    materials
        ``materials.json``'s list: each material's ``name``, ``pattern``, ``texture_set``,
        ``shading_set``, ``params`` (pairs are ``[warp, weft]``), ``design_seed``, ``maps``
        and ``shards``.
    components
        The names of the four components of ``value`` and ``stderr``.
    config
        The resolved generation settings (queries, samples, sampler, ...).

    Examples
    --------
    >>> ds = matforge.datasets.open("job:1a2b", data_dir="matforge-data")  # doctest: +SKIP
    >>> q = ds.material("plain-t00-s00")  # dict of arrays, one row per query
    >>> q["value"].shape, q["stderr"].shape
    ((256, 4), (256, 4))
    """

    KINDS = ("generate.fabric",)

    def __init__(self, source: Source) -> None:
        super().__init__(source)
        doc = source.read_json("materials.json")
        try:
            self.materials: list[dict[str, Any]] = list(doc["materials"])
            self.components: list[str] = [str(c) for c in doc["components"]]
            self.config: dict[str, Any] = dict(doc.get("config") or {})
            self._shards = [list(m["shards"]) for m in self.materials]
        except (KeyError, TypeError) as exc:
            raise FormatError("materials.json", f"malformed: {exc!r}") from None
        self._index = {str(m["name"]): i for i, m in enumerate(self.materials)}
        self._cache: dict[str, dict[str, np.ndarray]] = {}

    @property
    def names(self) -> list[str]:
        """The materials' names, in ``materials.json`` order (``material`` indexes it)."""
        return [str(m["name"]) for m in self.materials]

    def params(self, name: str) -> dict[str, Any]:
        """The parameters of material ``name`` (``materials.json``'s ``params``)."""
        return dict(self.materials[self._material_index(name)]["params"])

    def _material_index(self, name: str) -> int:
        if name not in self._index:
            raise KeyError(f"{self.ref} has no material {name!r} (materials: {self.names})")
        return self._index[name]

    def shard(self, name: str) -> dict[str, np.ndarray]:
        """The arrays of shard ``name`` (``shard-XXXX.npz``), memory-mapped."""
        if name not in self._cache:
            arrays = open_npz(self.source.path(name), name)
            missing = [k for k in FIELDS if k not in arrays]
            if missing:
                raise FormatError(name, f"missing arrays {missing} (a fabric shard has {FIELDS})")
            self._cache[name] = arrays
        return self._cache[name]

    def _concat(self, shards: list[str]) -> dict[str, np.ndarray]:
        parts = [self.shard(s) for s in shards]
        return {k: np.concatenate([np.asarray(p[k]) for p in parts]) for k in FIELDS}

    def material(self, name: str) -> dict[str, np.ndarray]:
        """Every query of material ``name``: the arrays of :data:`FIELDS`, one row each."""
        return self._concat(self._shards[self._material_index(name)])

    def numpy(self) -> dict[str, np.ndarray]:
        """Every query of every material in memory, concatenated in shard order
        (``material`` says whose; for sets that fit in memory, else :meth:`material`,
        :meth:`shard` or :meth:`torch_dataset`): ``material`` (N,) int32, ``center``
        (N, 2), ``size`` (N,), ``wi`` (N, 3), ``wo`` (N, 3), ``value`` (N, 4), ``stderr``
        (N, 4), float32."""
        return self._concat([s for shards in self._shards for s in shards])

    def __len__(self) -> int:
        return int(sum(len(self.shard(s)["material"]) for sh in self._shards for s in sh))

    def torch_dataset(self, materials: list[str] | None = None) -> Any:
        """A ``torch.utils.data.Dataset`` of queries (of ``materials``, default all), read
        lazily from the memory-mapped shards: item ``i`` is a dict of tensors ``material``
        (int64), ``center`` (2,), ``size`` (), ``wi`` (3,), ``wo`` (3,), ``value`` (4,) and
        ``stderr`` (4,) (:class:`matforge.datasets.torch_data.FabricQueryDataset`).
        Shuffle with the ``DataLoader``."""
        from matforge.datasets.torch_data import FabricQueryDataset

        names = self.names if materials is None else list(materials)
        shards = [s for n in names for s in self._shards[self._material_index(n)]]
        return FabricQueryDataset(
            [(self.source.path(s), len(self.shard(s)["material"])) for s in shards]
        )
