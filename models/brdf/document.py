"""``metrics.json`` of ``train.brdf``: the one definition of the document.

:func:`models.brdf.report.evaluate` builds it (the runner adds ``model``); ``put_json``
validates it against :class:`TrainBrdfMetrics`; the kinds reference lists its fields. Its own
module, without torch, so that registering the kind stays light.
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import Field
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
    """SMAPE (Eq. 6 of the hybrid-BRDF paper): ``2/N sum_k |f_k - g_k| / (|f_k| + |g_k|)``
    over the N pairs, f the table, g the model, mean over R, G, B; 0 (equal) to 2."""
    smape_floor: float
    """SMAPE with each channel's denominator floored at 1 % of the table's mean
    (stable where the table is 0); 0 to 2."""
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


# -- model.json ---------------------------------------------------------------------------------


@document
class BrdfHead(TypedDict):
    """One output head of the MLP."""

    name: str
    """``f_c``, ``f_g`` (hybrid) or ``f`` (neural)."""
    slice: list[int]
    """``[start, stop]`` of the MLP's outputs."""
    activation: str
    """``exp`` or ``sigmoid``."""


@document
class BrdfAnalyticSpec(TypedDict):
    """The analytic part (Eq. 3), in prose."""

    diffuse: str
    """The diffuse term."""
    specular: str
    """The specular term."""
    shadowing: str
    """The shadowing term."""
    fresnel: str
    """The Fresnel term."""


@document
class BrdfModelArchitecture(TypedDict):
    """The model's shape and evaluation."""

    model: str
    """``hybrid``, ``neural`` or ``analytic``."""
    width: int
    """The MLP's width (0: analytic)."""
    depth: int
    """Its hidden layers (0: analytic)."""
    latent_dim: int
    """The per-material code's size (0: analytic)."""
    per_material_params: int
    """Floats per material: 7 + L (hybrid, analytic) or L (neural)."""
    hidden_activation: str | None
    """``relu`` (``null``: analytic)."""
    input_encoding: list[str]
    """The MLP's inputs, in order."""
    output_heads: list[BrdfHead]
    """The MLP's heads."""
    frames: int
    """Learned frames (neural: 3; else 0)."""
    analytic: BrdfAnalyticSpec | None
    """The analytic part (``null``: neural)."""


@document
class BrdfLinear(TypedDict):
    """One linear layer."""

    weight: list[list[float]]
    """``[out][in]``, float32 values written exactly."""
    bias: list[float]
    """``[out]``."""


@document
class BrdfNetwork(TypedDict):
    """The MLP and (neural) the frame module."""

    layers: list[BrdfLinear]
    """Depth + 1 layers, ``relu`` between them, the last linear."""
    frame: BrdfLinear | None
    """The neural model's frame module (``null``: hybrid)."""


class _BrdfMaterialParams(TypedDict):
    """A material's name and analytic parameters, shared by :class:`BrdfModelMaterial` and
    :class:`BrdfFittedMaterial` (their descriptions are ``Field``'s: pydantic reads the
    attribute docstrings of a typed dict's own fields only, not of those it inherits)."""

    name: Annotated[str, Field(description="The material.")]
    family: Annotated[str, Field(description="Its family.")]
    kd: Annotated[list[float] | None, Field(description="Diffuse albedo RGB (``null``: neural).")]
    eta: Annotated[list[float] | None, Field(description="Real IOR RGB (``null``: neural).")]
    alpha: Annotated[float | None, Field(description="GGX roughness (``null``: neural).")]


@document
class BrdfModelMaterial(_BrdfMaterialParams):
    """One material's parameters, constrained."""

    z: list[float]
    """Its latent code (empty: analytic)."""


@document
class BrdfModelDocument(TypedDict):
    """``model.json`` of ``train.brdf`` (``matforge.brdf-model/1``): the portable model."""

    format: str
    """``matforge.brdf-model/1``."""
    model: str
    """``hybrid``, ``neural`` or ``analytic``."""
    architecture: BrdfModelArchitecture
    """The model's shape and evaluation."""
    network: BrdfNetwork | None
    """The weights (``null``: analytic)."""
    materials: list[BrdfModelMaterial]
    """Every material, in training order."""
    training: dict[str, Any]
    """Provenance: params, resolved values, seed, materials; no timings."""


# -- materials.json -----------------------------------------------------------------------------


@document
class BrdfArchitecture(TypedDict):
    """The model's shape (:class:`models.brdf.networks.Architecture`)."""

    model: str
    """``hybrid``, ``neural`` or ``analytic``."""
    width: int
    """The MLP's width (0: analytic)."""
    depth: int
    """Its hidden layers (0: analytic)."""
    latent_dim: int
    """The per-material code's size (0: analytic)."""


@document
class BrdfFittedMaterial(_BrdfMaterialParams):
    """One material's fitted parameters."""

    z: list[float]
    """Its latent code."""
    split: str
    """``train`` or ``heldout``."""


@document
class TrainBrdfMaterials(TypedDict):
    """``materials.json`` of ``train.brdf``: the model's shape and each material's fit."""

    model: str
    """``hybrid``, ``neural`` or ``analytic``."""
    architecture: BrdfArchitecture
    """The model's shape."""
    per_material_params: int
    """Floats per material."""
    materials: list[BrdfFittedMaterial]
    """Per material, in training order."""


# -- report.brdf: spread.json, families.json ----------------------------------------------------


@document
class BrdfSeedScore(TypedDict):
    """One run's mean SMAPE."""

    seed: int
    """Its seed."""
    run: str
    """Its ``job:<id>``."""
    smape: float
    """Its mean SMAPE over materials."""


@document
class BrdfConfigSpread(TypedDict):
    """A configuration's mean SMAPE over seeds (:func:`models.brdf.study.spread`)."""

    n: int
    """Runs (seeds)."""
    smape_mean: float
    """Mean over them."""
    smape_std: float
    """Sample std (ddof 1; 0 for one run)."""
    smape_min: float
    """Least."""
    smape_max: float
    """Largest."""
    per_seed: list[BrdfSeedScore]
    """Each run's."""


@document
class BrdfSpread(TypedDict):
    """``spread.json`` of ``report.brdf``: per configuration the spread over seeds."""

    format: str
    """``matforge.brdf-report/1``."""
    materials: int
    """Materials of the runs' dataset."""
    runs: list[str]
    """The ``job:<id>`` refs reported on."""
    configs: dict[str, BrdfConfigSpread]
    """``{configuration: spread}``."""


@document
class BrdfFamilySpread(TypedDict):
    """A family's mean SMAPE over a configuration's seeds."""

    n: int
    """Runs (seeds) with the family."""
    smape_mean: float
    """Mean over them of the family's mean SMAPE."""
    smape_std: float
    """Sample std (ddof 1; 0 for one run)."""
    smape_min: float
    """Least."""
    smape_max: float
    """Largest."""
    materials: int
    """Materials of the family."""


@document
class BrdfFamilies(TypedDict):
    """``families.json`` of ``report.brdf``: per configuration and family the spread over
    seeds of the family's mean SMAPE."""

    format: str
    """``matforge.brdf-report/1``."""
    materials: int
    """Materials of the runs' dataset."""
    runs: list[str]
    """The ``job:<id>`` refs reported on."""
    families: list[str]
    """The families, the highlighted first."""
    highlight: dict[str, str]
    """``{family: why}``: the families the paper singles out."""
    configs: dict[str, dict[str, BrdfFamilySpread]]
    """``{configuration: {family: spread}}``."""
    worst_family: dict[str, str]
    """``{configuration: family}`` with the largest mean SMAPE."""
