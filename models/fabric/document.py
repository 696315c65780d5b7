"""The documents of ``train.fabric``, each defined once here: ``metrics.json``
(:class:`TrainFabricMetrics`), ``model.json`` (:class:`FabricModelDocument`) and
``latents.json`` (:class:`FabricLatents`).

:func:`models.fabric.report.evaluate` builds the metrics,
:func:`models.fabric.portable.to_portable` the model and :mod:`models.fabric.runner` the
latents; ``put_json`` validates them against these types; the kinds reference lists their
fields. Its own module, without
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
    sets: NotRequired[list[dict[str, Any]]]
    """With a dataset that has held-out sets (``generate.fabric``'s ``unseen*`` presets):
    per split (``train``, ``unseen_material``, ``unseen_pattern``), the spread over its
    materials of the RGB relative L1 and of the cloth mean error, overall and per light
    side, and for the splits never trained on the beta response per pattern."""


@document
class FabricLayer(TypedDict):
    """One linear layer of the decoder."""

    weight: list[list[float]]
    """``[out][in]``, float32 values written exactly."""
    bias: list[float]
    """``[out]``."""


@document
class FabricModelMaterial(TypedDict):
    """One training material."""

    name: str
    """The material (``generate.fabric``'s)."""
    pattern: str
    """Its weave pattern."""
    params: dict[str, Any]
    """Its ``materials.json`` params."""
    latent: list[float]
    """Its code (the encoder's latent; with the second-pass options also its params and
    phase grid)."""


@document
class FabricModelDocument(TypedDict):
    """``model.json`` of ``train.fabric`` (``matforge.fabric-model/1``): what rendering
    needs without torch (no encoder: that is ``model.pt``)."""

    format: str
    """``matforge.fabric-model/1``."""
    architecture: dict[str, Any]
    """The network's shape, inputs, activations, encodings and evaluation steps
    (:func:`models.fabric.portable.architecture_doc`)."""
    decoder: dict[str, FabricLayer]
    """``{layer: weights}``, the layers of ``architecture.decoder_layers``."""
    materials: list[FabricModelMaterial]
    """Every training material, in training order."""
    training: dict[str, Any]
    """Provenance: params, resolved values, seed, dataset; no timings."""


@document
class FabricLatent(TypedDict):
    """One material's code."""

    latent: list[float]
    """Its code, as in ``model.json``."""
    params: dict[str, Any]
    """Its ``materials.json`` params."""
    pattern: str
    """Its weave pattern."""


@document
class FabricLatents(TypedDict):
    """``latents.json`` of ``train.fabric``: each training material's code."""

    latent_dim: int
    """The latent's size."""
    materials: dict[str, FabricLatent]
    """``{material: code}``."""
