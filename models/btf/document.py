"""The documents of ``train.btf``, each defined once here: ``metrics.json``
(:class:`TrainBtfMetrics`) and ``model.json`` (:class:`BtfModelDocument`).

:func:`models.btf.runner.train_and_report` builds the metrics and
:func:`models.btf.portable.model_document` the model; ``put_json`` validates them against
these types; the summary and the result rows read the metrics with
:func:`jobapi.documents.read_typed`; the kinds reference lists their fields. Its own module,
without torch, so that registering the kind stays light. ``model.json`` is also published as
a JSON Schema (``storage/formats/schemas/matforge.btf-model-1.schema.json``) for readers
outside Python.
"""

from __future__ import annotations

from typing import Any, NotRequired

from typing_extensions import TypedDict

from jobapi.documents import document


@document
class BtfCaseError(TypedDict):
    """The error over the slices of one failure case (:mod:`models.btf.cases`)."""

    case: str
    """The case (``shadowing``, ``specular``, ``rest``, ``fine_detail``)."""
    slices: int
    """Slices in the case."""
    l1: float | None
    """Mean absolute error over them, 1/sr (``null``: no slice)."""
    relative_l1: float | None
    """``l1`` over the case's own mean ``|BTF|`` (``null``: none, or no detail)."""
    definition: str
    """What the case is."""


@document
class BtfSlices(TypedDict):
    """Slices of the BTF."""

    total: int
    """All slices."""
    train: int
    """Slices trained on."""
    heldout: int
    """Slices held out."""


@document
class BtfStorage(TypedDict):
    """Bytes of the model, counted at float32 (as the paper's Table 1)."""

    texture_bytes: int
    """Its textures."""
    network_bytes: int
    """Its network."""
    total_bytes: int
    """Both."""


@document
class TrainBtfMetrics(TypedDict):
    """``metrics.json`` of ``train.btf``: the trained model's errors over the whole BTF."""

    model: str
    """The model type."""
    label: str
    """Its label (the model, ``+distill`` when distilled)."""
    l1: float
    """Mean absolute error over every slice, texel and channel, 1/sr (Table 1)."""
    l1_train: float
    """The same over the training slices."""
    l1_heldout: float | None
    """The same over the held-out slices (``null``: none held out)."""
    relative_l1: float
    """``l1`` over ``mean_abs_btf``."""
    mean_abs_btf: float
    """The BTF's mean ``|value|``."""
    slices: BtfSlices
    """Slices of the BTF."""
    storage: BtfStorage
    """Bytes at the trained resolution."""
    storage_at_400: BtfStorage
    """Bytes the same model needs at 400 x 400 texels (Table 1's resolution)."""
    cases: list[BtfCaseError]
    """Per failure case, then ``fine_detail``."""
    definition: str
    """What each figure is."""


@document
class BtfArchitecture(TypedDict):
    """The model's shape (:class:`models.btf.networks.Architecture`, or the Lafortune fit's)."""

    model: str
    """``neumip``, ``c2f`` or ``lafortune``."""
    width: int
    """The MLP's width (0: Lafortune)."""
    resolution: list[int]
    """The textures' ``[H, W]``."""
    channels: NotRequired[int]
    """NeuMIP's texture channels."""
    coarse_channels: NotRequired[int]
    """The student's coarse texture channels."""
    fine_channels: NotRequired[int]
    """The student's fine texture channels."""
    lobes: NotRequired[int]
    """Lafortune: lobes per texel."""
    params_per_texel: NotRequired[int]
    """Lafortune: parameters per texel in ``textures.npz``'s ``params``."""
    fit_slices: NotRequired[int]
    """Lafortune: slices the fit used."""
    evaluation: list[str]
    """The evaluation's steps, in prose."""


@document
class BtfLayer(TypedDict):
    """One linear layer."""

    weight: list[list[float]]
    """``[out][in]``, float32 values written exactly."""
    bias: list[float]
    """``[out]``."""
    activation: str
    """Applied after it (``relu``, ``identity``)."""


@document
class BtfModelStorage(TypedDict):
    """Bytes of the model, counted at float32."""

    texture_bytes: int
    """Its textures."""
    network_bytes: int
    """Its network."""
    total_bytes: int
    """Both."""
    note: NotRequired[str]
    """How they are counted."""


@document
class BtfModelDocument(TypedDict):
    """``model.json`` of ``train.btf`` (``matforge.btf-model/1``): the portable model; its
    textures are ``textures.npz`` beside it."""

    format: str
    """``matforge.btf-model/1``."""
    model: str
    """``neumip``, ``neumip_max``, ``c2f`` or ``lafortune``."""
    architecture: BtfArchitecture
    """The model's shape."""
    layers: dict[str, BtfLayer]
    """``{name: layer}`` (``hidden0..2``, ``out``; ``coarse1``, ``coarse2``, ``fine1``,
    ``fine2``; none for Lafortune)."""
    storage: BtfModelStorage
    """Bytes, float32."""
    training: dict[str, Any]
    """Provenance: params, resolved values, seed, data; no timings."""
