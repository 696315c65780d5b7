"""``metrics.json`` of ``evaluate.tss``: the one definition of the document.

:func:`evaluators.tss.kind.metrics_document` builds it; ``put_json`` validates it against
:class:`TssMetrics`; the kinds reference lists its fields.
"""

from __future__ import annotations

from typing import Any

from typing_extensions import TypedDict

from jobapi.documents import document


@document
class TssMetrics(TypedDict):
    """``metrics.json`` of ``evaluate.tss``: everything deterministic of the run."""

    format: str
    """The document's format."""
    model: dict[str, Any]
    """The model evaluated: its job or external source, runtime, type and resolution."""
    rows: list[dict[str, Any]]
    """One per texture resolution and shading interval: ``label``, ``resolution``,
    ``interval``, ``pass``, ``flip_mean``, ``flip_max``, ``psnr_mean``, ``psnr_min``
    (``null`` when a frame equals its reference), ``shading_passes``."""
    per_frame: dict[str, dict[str, list[float | None]]]
    """``{row label: {"flip": [...], "psnr": [...]}}``, one value per frame."""
    motion: dict[str, float]
    """The camera path's motion figures."""
    figure: dict[str, Any]
    """The frame and interval of the figure."""
    settings: dict[str, Any]
    """The run's settings (frames, image, lights, path, texture pass, FLIP)."""
