"""``materials.json`` of ``generate.merl``: the one definition of the document.

:func:`generators.merl.kind.run_generate_merl` builds it; ``put_json`` validates it against
:class:`MerlMaterials`; its summary, ``train.brdf``'s dataset loader and ``score``'s sets of
tables read it with :func:`jobapi.documents.read_typed` (or ``check_typed``); the kinds
reference lists its fields. Here in :mod:`storage.formats` because the generator, the
models and the scorers read it, and none of them may import another.
"""

from __future__ import annotations

from typing import Any, NotRequired  # pydantic needs this TypedDict on 3.11

from pydantic import ConfigDict, with_config
from typing_extensions import TypedDict

#: Unknown keys are refused; each field's docstring is its description in the docs.
document = with_config(ConfigDict(extra="forbid", use_attribute_docstrings=True))


@document
class MerlArtifacts(TypedDict):
    """The material's artifacts."""

    table: str
    """``<name>.binary``: the table (the simulated measurement, with ``measurement``)."""
    picture: str
    """``<name>.png``: its half/diff slice at ``phi_d = 90`` degrees."""
    truth: NotRequired[str]
    """``truth/<name>.binary``: with ``measurement`` only, the noiseless table."""


@document
class MerlMaterial(TypedDict):
    """One tabulated material."""

    name: str
    """The material."""
    family: str
    """Its collection family (``custom`` for a single source)."""
    source: dict[str, Any]
    """The exact source that reproduces the table (``{"mitsuba": ...}``,
    ``{"analytic": ...}``)."""
    params: dict[str, Any]
    """The drawn parameters (a single source: its own)."""
    tabulation: dict[str, Any]
    """The tabulation's report: anisotropy and reciprocity errors, variant; no timings."""
    measurement: dict[str, Any] | None
    """The simulated measurement's settings, its seed and ``missing_bins`` (``null``:
    none)."""
    artifacts: MerlArtifacts
    """Its artifacts."""


@document
class MerlMaterials(TypedDict):
    """``materials.json`` of ``generate.merl``: every table's material and provenance."""

    materials: list[MerlMaterial]
    """One per table, in the collection's order."""
    phi_d_bins: int
    """``phi_d`` bins of each table (180, or 360)."""
    preset: str | None
    """The collection's preset (``null``: a single source)."""
    families: dict[str, int] | None
    """Materials per family (``null``: a single source)."""
    distributions: dict[str, Any] | None
    """The distribution each family was drawn from (``null``: a single source)."""
    allow_anisotropic: bool
    """Whether anisotropic sources were allowed."""
    anisotropy_tol: float
    """The anisotropy error above which a source is refused."""
