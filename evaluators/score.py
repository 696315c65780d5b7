"""The ``score`` job kind: score candidate artifacts against a reference.

The reference's *artifact kind* picks the scorer, through :data:`ARTIFACT_KINDS`:

=============  ===================  ====================================  =================
kind           files                metrics                               values compared
=============  ===================  ====================================  =================
``image-hdr``  OpenEXR (``.exr``)   ``flip`` (HDR-FLIP), ``psnr``,         linear RGB
                                    ``ssim``, ``mae``, ``mse``
``image-ldr``  PNG (``.png``)       ``flip`` (LDR-FLIP), ``psnr``,         sRGB-encoded
                                    ``ssim``, ``mae``, ``mse``             values in [0, 1]
``merl``       MERL table            ``smape`` (Eq. 6 of the hybrid-BRDF   plain RGB BRDF in
               (``.binary``)         paper), ``mae``                       1/sr at 10^6 pairs
=============  ===================  ====================================  =================

Other artifact kinds plug in with :func:`register_artifact_kind` (a loader, a scorer, the
metrics it supports) from modules in :data:`ARTIFACT_KIND_MODULES`; ``merl``:
:mod:`evaluators.score_brdf`. ``metrics`` left out means all that the reference's kind
supports; one it does not support fails the job, listing those it does.

Candidates are of the reference's kind, or of a kind it lists in ``candidate_kinds``. A
*model* kind (one with ``bind``) is a file holding several materials, scored one material
at a time: such a candidate is given as ``{"model": REF, "material": NAME}``. The model kind
``brdf-model`` (a ``train.brdf`` ``model.json``, recognised by its ``format`` field) is
scored against ``merl`` references, evaluated for that material with the portable
evaluator at the same pairs as tables; a model cannot be the reference.

Choices for images, recorded in ``metrics.json`` under ``settings``:

- ``data_range`` of PSNR and SSIM: 1 for PNG; for EXR the reference's largest pixel value
  (over all channels), so that PSNR is the error relative to the brightest reference value;
- HDR-FLIP's exposure range is computed once from the reference (unless given in
  ``exposure``) and used for every candidate, so their FLIP values are comparable;
- PSNR of an identical candidate is infinite and is written as ``null``.
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

import numpy as np
from pydantic import Field, StringConstraints, field_validator, model_validator

from evaluators.metrics import (
    DEFAULT_PPD,
    ExposureRange,
    flip,
    hdr_exposure_range,
    mae,
    mse,
    psnr,
    ssim,
)
from evaluators.tonemap import magma
from service.errors import FormatError, JobFailed
from service.registry import Kind, register
from service.specs import Ref, StrictModel
from storage.formats.exr import read_exr
from storage.formats.png import read_png, write_png

if TYPE_CHECKING:
    from service.context import JobContext

MetricName = Literal["flip", "psnr", "ssim", "mae", "mse", "smape"]
IMAGE_METRICS: tuple[MetricName, ...] = ("flip", "psnr", "ssim", "mae", "mse")
Label = Annotated[str, StringConstraints(pattern=r"^[A-Za-z0-9_.-]{1,64}$")]
SSIM_WINDOW = 7


class ExposureSettings(StrictModel):
    """HDR-FLIP exposures; unset fields are derived from the reference (HDR-FLIP rule)."""

    start: float | None = Field(
        default=None,
        ge=-64.0,
        le=64.0,
        allow_inf_nan=False,
        description="First exposure, in stops.",
    )
    stop: float | None = Field(
        default=None,
        ge=-64.0,
        le=64.0,
        allow_inf_nan=False,
        description="Last exposure, in stops (>= start).",
    )
    count: int | None = Field(
        default=None, ge=2, le=64, description="Number of exposures from start to stop."
    )
    tonemapper: Literal["aces", "hable", "reinhard"] = Field(
        default="aces", description="Tone curve HDR-FLIP assumes."
    )

    @model_validator(mode="after")
    def _check_order(self) -> ExposureSettings:
        if self.start is not None and self.stop is not None and self.start > self.stop:
            raise ValueError(f"start ({self.start}) must not be above stop ({self.stop})")
        return self


MaterialName = Annotated[str, StringConstraints(min_length=1, max_length=256)]


class ModelCandidate(StrictModel):
    """One material of a trained model as a candidate: ``{"model": REF, "material": NAME}``."""

    model: Ref = Field(
        description="The trained model: a train.brdf model.json (job:<id>/model.json or "
        "sha256: ref)."
    )
    material: MaterialName = Field(
        description="Name of the model's material to score (one of its materials[].name)."
    )


class ScoreParams(StrictModel):
    """Parameters of ``score``.

    Example::

        {"kind": "score", "params": {"reference": "job:<id>/image.exr",
         "candidates": {"fit": "job:<id2>/image.exr", "baseline": "sha256:<hex>"},
         "metrics": ["flip", "psnr"]}}

    Against a MERL table, a trained model's material::

        {"kind": "score", "params": {"reference": "sha256:<table>",
         "candidates": {"hybrid": {"model": "job:<train>/model.json", "material": "gold"}}}}
    """

    reference: Ref = Field(description="The reference artifact (job: or sha256: ref).")
    candidates: dict[Label, Ref | ModelCandidate] = Field(
        min_length=1,
        max_length=64,
        description="Candidates to score, by label (1-64 characters of A-Z a-z 0-9 _ . -): "
        "a ref, or {model, material} for one material of a trained model (model.json; "
        "against MERL table references).",
    )
    metrics: list[MetricName] | None = Field(
        default=None,
        min_length=1,
        description="Metrics to compute (default: all that apply to the reference's kind). "
        "Images: flip, psnr, ssim, mae, mse; BRDF tables: smape, mae.",
    )
    exposure: ExposureSettings | None = Field(
        default=None,
        description="HDR-FLIP exposure range {start, stop, count, tonemapper}; "
        "default: derived once from the reference.",
    )

    @field_validator("metrics")
    @classmethod
    def _unique(cls, value: list[str] | None) -> list[str] | None:
        if value is None:
            return None
        dupes = sorted({m for m in value if value.count(m) > 1})
        if dupes:
            raise ValueError(f"metrics listed more than once: {', '.join(dupes)}")
        return value


# -- artifact kinds --------------------------------------------------------------------------


@dataclass(frozen=True)
class Loaded:
    """An input artifact: its ref, artifact kind and decoded data."""

    ref: str
    kind: str
    data: Any


@dataclass(frozen=True)
class ScoreResult:
    """What a scorer returns: ``{label: {metric: value}}`` and the settings it used."""

    metrics: dict[str, dict[str, float | None]]
    settings: dict[str, Any]


Scorer = Callable[[Loaded, dict[str, Loaded], ScoreParams, "JobContext"], ScoreResult]


@dataclass(frozen=True)
class ArtifactKind:
    """A kind of artifact ``score`` understands.

    ``media_types``, ``extensions`` and ``magic`` (leading bytes) identify it, in that
    order, then ``detect(path)`` where given; ``load(path, name)`` decodes it (raising
    ``FormatError``); ``scorer`` scores candidates of the same kind and of the kinds named in
    ``candidate_kinds``; ``metrics`` lists the metric names it supports. ``bind(data,
    material)`` marks a *model* kind: it returns the loaded data of one material (raising
    ``FormatError`` for an unknown one); model kinds are candidates only.
    """

    name: str
    description: str
    media_types: tuple[str, ...]
    extensions: tuple[str, ...]
    magic: bytes
    load: Callable[[Path, str], Any]
    scorer: Scorer
    metrics: tuple[str, ...]
    candidate_kinds: tuple[str, ...] = ()
    detect: Callable[[Path], bool] | None = None
    bind: Callable[[Any, str], Any] | None = None


ARTIFACT_KINDS: dict[str, ArtifactKind] = {}


def register_artifact_kind(kind: ArtifactKind) -> ArtifactKind:
    """Teach ``score`` a new kind of artifact (re-registering a name replaces it)."""
    ARTIFACT_KINDS[kind.name] = kind
    return kind


def identify(name: str, media_type: str, path: Path) -> ArtifactKind | None:
    """The artifact kind of a stored object, from its media type, name or first bytes."""
    for kind in ARTIFACT_KINDS.values():
        if media_type in kind.media_types:
            return kind
    suffix = Path(name).suffix.lower()
    for kind in ARTIFACT_KINDS.values():
        if suffix and suffix in kind.extensions:
            return kind
    with open(path, "rb") as fh:
        head = fh.read(16)
    for kind in ARTIFACT_KINDS.values():
        if kind.magic and head.startswith(kind.magic):
            return kind
    for kind in ARTIFACT_KINDS.values():
        if kind.detect is not None and kind.detect(path):
            return kind
    return None


def _load(ref: str, role: str, ctx: JobContext, material: str | None = None) -> Loaded:
    """Load ``ref``; ``material`` picks one material of a model kind (and requires one)."""
    record = ctx.ref_record(ref)
    path = ctx.resolve(ref)
    kind = identify(record.name, record.media_type, path)
    if kind is None:
        known = ", ".join(f"{k.description}" for k in ARTIFACT_KINDS.values())
        raise JobFailed(
            f"{role} {ref}: cannot score {record.name} ({record.media_type}); known kinds: {known}"
        )
    if kind.bind is None and material is not None:
        raise JobFailed(
            f"{role}: {{model, material}} needs a trained model, but {ref} is {kind.description}"
        )
    if kind.bind is not None and material is None:
        if role == "reference":
            raise JobFailed(
                f"reference {ref} is {kind.description}; a model can only be a candidate"
            )
        raise JobFailed(
            f"{role}: {ref} is {kind.description}; name one of its materials with "
            f'{{"model": "{ref}", "material": NAME}}'
        )
    try:
        data = kind.load(path, ref)
        if kind.bind is not None and material is not None:
            data = kind.bind(data, material)
    except FormatError as exc:
        raise JobFailed(f"{role}: {exc}") from None
    shown = ref if material is None else f"{ref}#{material}"
    return Loaded(ref=shown, kind=kind.name, data=data)


# -- images ----------------------------------------------------------------------------------


def _check_image(role: str, img: np.ndarray, ref_shape: tuple[int, ...] | None, hdr: bool) -> None:
    if ref_shape is not None and img.shape != ref_shape:
        raise JobFailed(
            f"{role}: size {img.shape[1]}x{img.shape[0]} differs from the "
            f"reference's {ref_shape[1]}x{ref_shape[0]}"
        )
    bad = int(np.count_nonzero(~np.isfinite(img)))
    if bad:
        raise JobFailed(f"{role}: {bad} non-finite pixel values (NaN or infinity)")
    if hdr and float(img.min()) < 0.0:
        raise JobFailed(
            f"{role}: negative pixel values; HDR images must hold non-negative linear radiance"
        )


def _exposure(reference: np.ndarray, settings: ExposureSettings | None) -> ExposureRange:
    settings = settings or ExposureSettings()
    auto = hdr_exposure_range(reference, tonemapper=settings.tonemapper)
    start = auto.start if settings.start is None else settings.start
    stop = auto.stop if settings.stop is None else settings.stop
    if start > stop:
        raise JobFailed(
            f"exposure: start {start:.4g} is above stop {stop:.4g} (one of them "
            f"was derived from the reference; give both)"
        )
    count = settings.count or max(2, math.ceil(stop - start))
    return ExposureRange(start=start, stop=stop, count=count, tonemapper=settings.tonemapper)


def score_images(
    reference: Loaded, candidates: dict[str, Loaded], params: ScoreParams, ctx: JobContext
) -> ScoreResult:
    """Score images of one kind (all EXR or all PNG); writes ``flip_<label>.png`` maps."""
    hdr = reference.kind == "image-hdr"
    ref_img: np.ndarray = reference.data
    _check_image("reference", ref_img, None, hdr)
    for label, cand in candidates.items():
        _check_image(f"candidate {label!r}", cand.data, ref_img.shape, hdr)
    data_range = float(ref_img.max()) if hdr else 1.0
    if data_range <= 0.0:
        raise JobFailed(
            "reference: the image is black; PSNR, SSIM and HDR-FLIP need a "
            "reference with some light"
        )
    wanted = set(params.metrics or IMAGE_METRICS)
    if params.exposure is not None and not hdr:
        raise JobFailed("exposure: applies to HDR-FLIP only; the reference is a PNG (LDR) image")
    exposure = _exposure(ref_img, params.exposure) if hdr and "flip" in wanted else None

    results: dict[str, dict[str, float | None]] = {}
    for i, (label, cand) in enumerate(sorted(candidates.items())):
        ctx.check_cancelled()
        row: dict[str, float | None] = {}
        try:
            if "mse" in wanted:
                row["mse"] = mse(ref_img, cand.data)
            if "mae" in wanted:
                row["mae"] = mae(ref_img, cand.data)
            if "psnr" in wanted:
                value = psnr(ref_img, cand.data, data_range=data_range)
                row["psnr"] = None if math.isinf(value) else value
            if "ssim" in wanted:
                row["ssim"] = ssim(ref_img, cand.data, data_range=data_range, win_size=SSIM_WINDOW)
            if "flip" in wanted:
                mean, error_map = flip(
                    ref_img, cand.data, mode="hdr" if hdr else "ldr", exposure_range=exposure
                )
                row["flip"] = mean
                ctx.put_bytes(f"flip_{label}.png", write_png(None, magma(error_map)), "image/png")
        except ValueError as exc:
            raise JobFailed(f"candidate {label!r}: {exc}") from None
        results[label] = row
        ctx.progress(
            0.1 + 0.85 * (i + 1) / len(candidates), f"scored {i + 1}/{len(candidates)}: {label}"
        )

    settings: dict[str, Any] = {
        "artifact_kind": reference.kind,
        "values": "linear RGB" if hdr else "sRGB-encoded values in [0, 1]",
        "data_range": data_range,
        "data_range_rule": "max of the reference" if hdr else "1 (8-bit PNG scaled to [0, 1])",
        "psnr_identical": "null (infinite PSNR)",
        "ssim": {"win_size": SSIM_WINDOW, "gaussian_weights": False, "K1": 0.01, "K2": 0.03},
    }
    if "flip" in wanted:
        flip_settings: dict[str, Any] = {
            "mode": "hdr" if hdr else "ldr",
            "ppd": DEFAULT_PPD,
            "error_maps": "flip_<label>.png (magma)",
        }
        if exposure is not None:
            flip_settings.update(
                start_exposure=exposure.start,
                stop_exposure=exposure.stop,
                num_exposures=exposure.count,
                tonemapper=exposure.tonemapper,
            )
        settings["flip"] = flip_settings
    return ScoreResult(metrics=results, settings=settings)


register_artifact_kind(
    ArtifactKind(
        name="image-hdr",
        description="an EXR (HDR) image",
        media_types=("image/x-exr",),
        extensions=(".exr",),
        magic=b"\x76\x2f\x31\x01",
        load=read_exr,
        scorer=score_images,
        metrics=IMAGE_METRICS,
    )
)
register_artifact_kind(
    ArtifactKind(
        name="image-ldr",
        description="a PNG (LDR) image",
        media_types=("image/png",),
        extensions=(".png",),
        magic=b"\x89PNG\r\n\x1a\n",
        load=read_png,
        scorer=score_images,
        metrics=IMAGE_METRICS,
    )
)

#: Modules that register further artifact kinds, imported once this module is complete.
ARTIFACT_KIND_MODULES: tuple[str, ...] = ("evaluators.score_brdf",)
for _module in ARTIFACT_KIND_MODULES:
    importlib.import_module(_module)


# -- the runner ------------------------------------------------------------------------------


def run_score(params: ScoreParams, ctx: JobContext) -> None:
    """Load the reference and candidates, score them, and store ``metrics.json``."""
    ctx.progress(0.0, "loading inputs")
    reference = _load(params.reference, "reference", ctx)
    kind = ARTIFACT_KINDS[reference.kind]
    metrics = list(params.metrics or kind.metrics)
    unsupported = [m for m in metrics if m not in kind.metrics]
    if unsupported:
        names = ", ".join(repr(m) for m in unsupported)
        verb = "metric " + names + " does" if len(unsupported) == 1 else f"metrics {names} do"
        raise JobFailed(
            f"metrics: {verb} not apply to {kind.description}; use {', '.join(kind.metrics)}"
        )
    params = params.model_copy(update={"metrics": metrics})  # scorers see the concrete list
    candidates: dict[str, Loaded] = {}
    for label, spec in params.candidates.items():
        role = f"candidate {label!r}"
        if isinstance(spec, ModelCandidate):
            cand = _load(spec.model, role, ctx, material=spec.material)
        else:
            cand = _load(spec, role, ctx)
        if cand.kind != reference.kind and cand.kind not in kind.candidate_kinds:
            raise JobFailed(
                f"candidate {label!r} is {ARTIFACT_KINDS[cand.kind].description} "
                f"but the reference is {kind.description}; score artifacts of "
                f"one kind against each other"
            )
        candidates[label] = cand
    ctx.progress(0.1, f"scoring {len(candidates)} candidates")
    result = kind.scorer(reference, candidates, params, ctx)
    ctx.put_json(
        "metrics.json",
        {"reference": params.reference, "metrics": result.metrics, "settings": result.settings},
    )
    ctx.progress(1.0, f"scored {len(candidates)} candidates with {', '.join(metrics)}")


register(
    Kind(
        name="score",
        params=ScoreParams,
        runner=run_score,
        summary="Scores candidate artifacts against a reference (images: FLIP, PSNR, "
        "SSIM, MAE, MSE; MERL BRDF tables, and trained models' materials against them: "
        "SMAPE, MAE in BRDF space).",
        artifacts=("metrics.json", "flip_<label>.png"),
        smoke={},
    )
)
