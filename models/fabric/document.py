"""``metrics.json`` of ``train.fabric``: the one definition of the document.

:func:`models.fabric.report.evaluate` builds it; ``put_json`` validates it against
:class:`TrainFabricMetrics`; the kinds reference lists its fields. Its own module, without
torch, so that registering the kind stays light. The per-material rows and means are trees
of components and error measures (``models.fabric.report``), typed here as objects.
"""

from __future__ import annotations

from typing import Any, NotRequired

from typing_extensions import TypedDict

from jobapi.documents import document


@document
class TrainFabricMetrics(TypedDict):
    """``metrics.json`` of ``train.fabric``: errors on each material's held-out queries."""

    materials: list[dict[str, Any]]
    """One row per material with held-out queries: its name and error tree."""
    mean: dict[str, Any]
    """``count`` (materials averaged) and the mean of their error trees."""
    footprints: list[dict[str, Any]]
    """Per footprint-size case: queries summed, errors averaged over the materials."""
    settings: dict[str, Any]
    """What each error measure is."""
    beta_response: NotRequired[list[dict[str, Any]]]
    """With ``held_out_beta``: per pattern with two or more held-out betas, each component's
    slope of the mean against beta, the network's beside Monte Carlo's, their standard
    errors, their ratio, whether Monte Carlo's sign is resolved and whether the goal is
    met."""
