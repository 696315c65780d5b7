"""``stats.json`` of ``generate.glint``: the one definition of the document.

``generate.glint`` writes it (validated against :class:`GlintStats` on ``put_json``); its
summary and rows, and the glint material source's memory figures in render rows, read it
with :func:`jobapi.documents.read_typed`. Here in :mod:`storage.formats` because both the
generator and the renderer read it, and neither may import the other.
"""

from __future__ import annotations

from typing import NotRequired  # pydantic needs this TypedDict on 3.11

from pydantic import ConfigDict, with_config
from typing_extensions import TypedDict

_DOCUMENT = ConfigDict(extra="forbid", use_attribute_docstrings=True)


@with_config(_DOCUMENT)
class GlintExampleStats(TypedDict):
    """The example the NDF maps were made from."""

    size: int
    """Side in texels of the (cropped) example."""
    type: str
    """Its procedural type, or ``normal map`` for an uploaded one."""
    cropped_from: NotRequired[int | None]
    """The side it was cropped from (``null``: not cropped; absent in jobs made before
    crops existed)."""


@with_config(_DOCUMENT)
class GlintBytes(TypedDict):
    """Memory of the tiny example's data."""

    ndf_maps: int
    """Bytes of the NDF images, all levels."""
    lobes: int
    """Bytes of the lobes."""
    total: int
    """``ndf_maps + lobes``: a material's ``bytes_per_material``."""


@with_config(_DOCUMENT)
class GlintReference(TypedDict):
    """Yan et al. 2016's explicit map, the memory the example is compared with."""

    resolution: int
    """Side in texels of the explicit normal map."""
    lobe_rate: int
    """Lobe seeds per texel per axis."""
    lobes: int
    """``resolution^2 x lobe_rate^2`` lobe records."""
    bytes: int
    """Their bytes."""
    note: str
    """What the reference is."""


@with_config(_DOCUMENT)
class GlintStats(TypedDict):
    """``stats.json`` of ``generate.glint``."""

    example: GlintExampleStats
    """The example."""
    levels: int
    """NDF levels (tiles of each level's image count)."""
    ndf_resolution: int
    """R: cells per side of each tile's NDF image."""
    extent: float
    """e: the NDF images cover projected normals in [-e, e]^2."""
    lobes: int
    """4D Gaussian lobes of the example."""
    precompute_seconds: NotRequired[float]
    """Time of the lobes and NDF maps, in jobs made before timings moved to the job's
    manifest (now ``timings.measured.precompute_seconds``, not here: timings vary between
    runs, and artifacts are the same bytes for the same spec)."""
    bytes: GlintBytes
    """Memory of the example's data."""
    reference: GlintReference
    """The explicit reference."""
    memory_ratio: float
    """``bytes.total / reference.bytes``."""
    note: str
    """Where the timing is."""
