"""``metrics.json`` of ``train.btf``: the one definition of the document.

:func:`models.btf.runner.train_and_report` builds it; ``put_json`` validates it against
:class:`TrainBtfMetrics`; the kinds reference lists its fields. Its own module, without
torch, so that registering the kind stays light.
"""

from __future__ import annotations

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
