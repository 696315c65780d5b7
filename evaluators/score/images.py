"""``score`` of images: the ``image-hdr`` (OpenEXR) and ``image-ldr`` (PNG) artifact kinds.

Registered with :func:`evaluators.score.artifacts.register_artifact_kind`; ``score`` imports this
module
from its explicit list :data:`evaluators.score.kind.ARTIFACT_KIND_MODULES` (first, so that images
are identified before BRDF tables). Metrics: ``flip`` (HDR-FLIP for EXR, LDR-FLIP for PNG),
``psnr``, ``ssim``, ``mae``, ``mse``; the choices (data range, FLIP exposures) are described
in :mod:`evaluators.score.kind` and recorded under ``settings`` in ``metrics.json``.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from evaluators.metrics.images import (
    DEFAULT_PPD,
    ExposureRange,
    flip,
    hdr_exposure_range,
    mae,
    mse,
    psnr,
    ssim,
)
from evaluators.metrics.tonemap import magma
from evaluators.score.artifacts import ArtifactKind, Loaded, ScoreResult, register_artifact_kind
from evaluators.score.params import IMAGE_METRICS, ExposureSettings, ScoreParams
from jobapi.errors import JobFailed
from storage.formats.exr import read_exr
from storage.formats.png import read_png, write_png

if TYPE_CHECKING:
    from jobapi.context import JobContext

SSIM_WINDOW = 7


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
        space="image",
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
        space="image",
    )
)
