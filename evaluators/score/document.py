"""``metrics.json`` of ``score``: the one definition of the document.

``score`` writes it (validated against :class:`ScoreMetrics` on ``put_json``, for every
artifact type it scores: images, BRDF tables and models, sets of tables, BTF slices); its
summary reads it with :func:`jobapi.documents.read_typed`.
"""

from __future__ import annotations

from typing import Any, NotRequired  # pydantic needs this TypedDict on 3.11

from typing_extensions import TypedDict

from jobapi.documents import document


@document
class ScoreMetrics(TypedDict):
    """``metrics.json`` of ``score``."""

    reference: str | dict[str, str]
    """The reference as given: a ref, or for whole models a set of MERL tables
    (``job:<id>`` of a ``generate.merl`` job, or ``{material name: table ref}``)."""
    metrics: dict[str, dict[str, float | None]]
    """``{label: {metric: value}}``; ``null`` where a value is not finite (PSNR of identical
    images); for whole models the plain means over the set's materials."""
    settings: dict[str, Any]
    """How each metric was computed (the scorer's settings)."""
    per_material: NotRequired[dict[str, dict[str, dict[str, float | None]]]]
    """Whole models against a set of tables: ``{label: {material: {metric: value}}}``."""
    cases: NotRequired[dict[str, list[dict[str, Any]]]]
    """BTF slices: ``{label: [per failure case errors]}`` (``models.btf.cases``)."""
