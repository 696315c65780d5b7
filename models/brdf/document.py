"""``metrics.json`` of ``train.brdf``: the one definition of the document.

:func:`models.brdf.report.evaluate` builds it (the runner adds ``model``); ``put_json``
validates it against :class:`TrainBrdfMetrics`; the kinds reference lists its fields. Its own
module, without torch, so that registering the kind stays light.
"""

from __future__ import annotations

from typing import Any

from typing_extensions import TypedDict

from jobapi.documents import document


@document
class BrdfMaterialScores(TypedDict):
    """One material's scores in ``train.brdf``'s ``metrics.json``."""

    name: str
    """The material."""
    family: str
    """Its family (a failure case of the report kinds)."""
    split: str
    """``train`` or ``heldout``."""
    pairs: int
    """Scoring pairs where the table has data."""
    smape: float
    """Eq. 6, eps 0, mean over R, G, B."""
    smape_floor: float
    """Eq. 6 with each channel's denominator floored (stable where the table is 0)."""
    mae: float
    """Mean absolute BRDF error, 1/sr."""
    smape_analytic: float | None
    """``smape`` of the analytic part alone (``null``: the neural model has none)."""
    smape_floor_analytic: float | None
    """``smape_floor`` of the analytic part alone."""
    mae_analytic: float | None
    """``mae`` of the analytic part alone."""


@document
class BrdfScoreMeans(TypedDict):
    """Plain means over materials (``null`` where no material has the score)."""

    count: int
    """Materials averaged."""
    smape: float | None
    """Mean ``smape``."""
    smape_floor: float | None
    """Mean ``smape_floor``."""
    mae: float | None
    """Mean ``mae``."""
    smape_analytic: float | None
    """Mean ``smape_analytic``."""
    smape_floor_analytic: float | None
    """Mean ``smape_floor_analytic``."""
    mae_analytic: float | None
    """Mean ``mae_analytic``."""


@document
class TrainBrdfMetrics(TypedDict):
    """``metrics.json`` of ``train.brdf``: the trained model's BRDF-space errors."""

    model: str
    """The model type (``neural``, ``analytic``, ``hybrid``)."""
    materials: list[BrdfMaterialScores]
    """Per material, in the model's order."""
    mean: BrdfScoreMeans
    """Over every material."""
    families: dict[str, BrdfScoreMeans]
    """Per family."""
    splits: dict[str, BrdfScoreMeans]
    """Per split present (``train``, ``heldout``)."""
    settings: dict[str, Any]
    """How the scores were computed (pairs, seed, distribution, definitions)."""
