"""The documents of ``generate.fabric``, each defined once here: ``materials.json``
(:class:`FabricMaterials`) and ``stats.json`` (:class:`FabricStats`).

:func:`generators.fabric.kind.run_generate_fabric` builds them; ``put_json`` validates them
against these types; its summary and rows, and ``train.fabric``'s dataset loader, read them
with :func:`jobapi.documents.read_typed` (or ``check_typed``); the kinds reference lists
their fields. Here in :mod:`storage.formats` because the generator and the models read
them, and neither may import the other.
"""

from __future__ import annotations

from typing import Any, NotRequired  # pydantic needs this TypedDict on 3.11

from pydantic import ConfigDict, with_config
from typing_extensions import TypedDict

#: The splits of a dataset with held-out sets (``materials.json``'s ``split``), in report
#: order: trained on, an unseen parameter draw of a trained pattern, an unseen pattern.
FABRIC_SPLITS: tuple[str, ...] = ("train", "unseen_material", "unseen_pattern")

#: Unknown keys are refused; each field's docstring is its description in the docs.
document = with_config(ConfigDict(extra="forbid", use_attribute_docstrings=True))


@document
class FabricMaps(TypedDict):
    """A material's two EXR maps over one tile."""

    normal: str
    """``maps/<name>-normal.exr``: the ply normals."""
    orientation: str
    """``maps/<name>-orientation.exr``: the ply orientations."""


@document
class FabricMaterial(TypedDict):
    """One material."""

    name: str
    """The material."""
    pattern: str
    """Its weave pattern."""
    texture_set: int
    """Its texture set (maps)."""
    shading_set: int
    """Its shading set (parameters)."""
    params: dict[str, Any]
    """Every parameter of the material (``pattern``, ``psi_deg``, ``u_max_deg``,
    ``alpha``, ``beta``, ``kd_*``, ``ks_*``, ``w``, ``gap``, ``t_rho``)."""
    design_seed: int
    """The seed its design was drawn with."""
    maps: FabricMaps
    """Its maps."""
    shards: list[str]
    """Its shards, in query order."""
    split: NotRequired[str]
    """``train``, ``unseen_material`` (a parameter draw of a trained pattern that no
    trained material has) or ``unseen_pattern`` (a pattern no trained material has); only
    in datasets of the ``unseen*`` presets. ``train.fabric`` trains on ``train`` alone and
    reports each split apart."""


@document
class FabricPreview(TypedDict):
    """What ``preview.png`` shows."""

    materials: list[str]
    """The materials shown."""
    footprint_size: float
    """The footprint's size, tile units."""
    wi: list[float]
    """The light direction, macro frame."""
    wo: list[float]
    """The view direction, macro frame."""
    samples: int
    """Samples per query."""


@document
class FabricMaterials(TypedDict):
    """``materials.json`` of ``generate.fabric``: every material, its maps and shards."""

    materials: list[FabricMaterial]
    """One per material; a shard's ``material`` indexes this list."""
    components: list[str]
    """The order of a shard's ``value`` columns (C_warp, C_weft, S_warp, S_weft)."""
    preset: str
    """The preset (``small``, ``paper``, ``beta``, ``unseen_small``, ``unseen``,
    ``unseen_paper``)."""
    config: dict[str, Any]
    """The resolved settings (queries, samples, footprint sizes, backend, ...)."""
    preview: FabricPreview
    """What the preview shows."""


@document
class FabricStats(TypedDict):
    """``stats.json`` of ``generate.fabric``: how much was estimated (the seconds are the
    manifest's ``timings.measured.throughput``)."""

    materials: int
    """Materials."""
    queries: int
    """Queries, all materials."""
    samples_per_query: int
    """Monte Carlo samples per query."""
    samples: int
    """Samples, all queries."""
    backend: str
    """The estimator's backend."""
    note: str
    """Where the timings are."""
    seconds: NotRequired[float]
    """Wall seconds of the estimation: only in a job made before timings moved to the
    manifest (``timings.measured.throughput``)."""
    samples_per_second: NotRequired[float]
    """Its throughput: likewise only in such a job."""
