"""``MerlCollection``: a ``generate.merl`` dataset, tables by name with family and source.

Each table is in the layout of Matusik et al. 2003 (:mod:`storage.formats.merl`), read as
**physical** BRDF values in 1/sr (no cosine): ``rgb`` ``(90, 90, P, 3)`` float64 indexed
``(theta_h, theta_d, phi_d, channel)``, ``P`` 180 (canonical) or 360, negative entries
missing (below the horizon, or dropped by a simulated measurement).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from matforge.datasets.base import DatasetReader
from matforge.datasets.source import Source
from storage.errors import FormatError
from storage.formats.merl import MerlTable, read_merl


@dataclass(frozen=True, eq=False)
class MerlMaterial:
    """One table of the collection.

    Attributes
    ----------
    name, family
        The material's name and its collection family (``"custom"`` for a single source).
    source
        The exact source that reproduces the table (``{"mitsuba": ...}`` or
        ``{"analytic": ...}``); ``params`` the drawn parameters.
    rgb
        ``(90, 90, P, 3)`` float64 physical BRDF values (see the module docstring).
    truth
        With a simulated measurement, the noiseless table (else ``None``).
    record
        The material's whole ``materials.json`` entry (tabulation, measurement, ...).
    """

    name: str
    family: str
    source: dict[str, Any]
    params: dict[str, Any]
    rgb: np.ndarray
    truth: np.ndarray | None
    record: dict[str, Any]

    @property
    def table(self) -> MerlTable:
        """The table as :class:`storage.formats.merl.MerlTable`."""
        return MerlTable(self.rgb, int(self.rgb.shape[2]))


class MerlCollection(DatasetReader):
    """The tables of a ``generate.merl`` job, by name: ``coll["<name>"]`` is a
    :class:`MerlMaterial` (read on first use, then kept).

    Attributes
    ----------
    materials
        ``materials.json``'s list (name, family, source, params, tabulation, measurement,
        artifacts).
    doc
        The whole ``materials.json`` (phi_d_bins, preset, families, distributions, ...).

    Examples
    --------
    >>> coll = matforge.datasets.open(job_id, data_dir="matforge-data")  # doctest: +SKIP
    >>> coll.names, coll[coll.names[0]].family
    >>> ds = coll.torch_dataset(pairs=4096)  # (wi, wo) pairs with the tables' values
    """

    KINDS = ("generate.merl",)

    def __init__(self, source: Source) -> None:
        super().__init__(source)
        self.doc: dict[str, Any] = source.read_json("materials.json")
        try:
            self.materials: list[dict[str, Any]] = list(self.doc["materials"])
            self._by_name = {str(m["name"]): m for m in self.materials}
        except (KeyError, TypeError) as exc:
            raise FormatError("materials.json", f"malformed: {exc!r}") from None
        self._loaded: dict[str, MerlMaterial] = {}

    @property
    def names(self) -> list[str]:
        """The materials' names, in ``materials.json`` order."""
        return [str(m["name"]) for m in self.materials]

    def family(self, name: str) -> str:
        """The family of material ``name``."""
        return str(self._record(name).get("family"))

    def _record(self, name: str) -> dict[str, Any]:
        if name not in self._by_name:
            raise KeyError(f"{self.ref} has no material {name!r} (materials: {self.names})")
        return self._by_name[name]

    def _table(self, artifact: str) -> np.ndarray:
        return read_merl(self.source.path(artifact), artifact).rgb

    def __getitem__(self, name: str) -> MerlMaterial:
        if name not in self._loaded:
            rec = self._record(name)
            arts = dict(rec.get("artifacts") or {})
            table = str(arts.get("table", f"{name}.binary"))
            truth = arts.get("truth")
            self._loaded[name] = MerlMaterial(
                name=name,
                family=str(rec.get("family")),
                source=dict(rec.get("source") or {}),
                params=dict(rec.get("params") or {}),
                rgb=self._table(table),
                truth=self._table(str(truth)) if truth else None,
                record=rec,
            )
        return self._loaded[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self.names)

    def __len__(self) -> int:
        return len(self.materials)

    def __contains__(self, name: object) -> bool:
        return name in self._by_name

    def numpy(self) -> dict[str, np.ndarray]:
        """Every table by name: ``(90, 90, P, 3)`` float64 physical values."""
        return {n: self[n].rgb for n in self.names}

    def torch_dataset(
        self,
        pairs: int = 4096,
        *,
        seed: int = 0,
        materials: list[str] | None = None,
        interpolate: bool = True,
    ) -> Any:
        """A ``torch.utils.data.Dataset`` of ``(wi, wo)`` pairs: ``pairs`` per material
        (of ``materials``, default all), cosine-weighted on the upper hemisphere and fixed
        by ``seed``, with each table's value there (multilinear between bin centres with
        ``interpolate``, the reconstruction ``score`` uses; else the bin's value). Items:
        ``material`` (index into ``materials``), ``wi`` (3,), ``wo`` (3,), ``rgb`` (3,)
        (:class:`matforge.datasets.torch_data.MerlPairDataset`)."""
        from matforge.datasets.torch_data import MerlPairDataset

        names = self.names if materials is None else list(materials)
        return MerlPairDataset([self[n].rgb for n in names], names, pairs, seed, interpolate)
