"""Image-space error metrics: MSE, MAE, PSNR, SSIM and FLIP.

Pure functions in the manner of ``skimage.metrics``: arrays in, numbers out. Inputs are
``(H, W)`` or ``(H, W, C)`` arrays of the same shape (FLIP: ``(H, W, 3)``); shapes are checked
first, dtypes are promoted once (float64 for the closed forms, float32 for FLIP), options are
keyword-only, and every refusal is an explicit ``ValueError``. Non-finite pixels are refused:
a NaN would silently turn every mean into NaN.

Conventions: ``ref`` is the reference (ground truth), ``test`` the image judged. Errors are
averaged over all pixels and channels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

#: FLIP's default pixels per degree: a 0.7 m wide 3840-pixel monitor seen from 0.7 m.
DEFAULT_PPD = 0.7 * (3840.0 / 0.7) * (math.pi / 180.0)
FlipMode = Literal["hdr", "ldr"]
ToneMapper = Literal["aces", "hable", "reinhard"]

# Rational tone curves (c0 x^2 + c1 x + c2) / (c3 x^2 + c4 x + c5) that HDR-FLIP assumes
# (Andersson et al. 2021, Sec. 4.2; coefficients of NVIDIA's FLIP.h; ACES with its 0.6
# pre-exposure folded in).
_TONE_COEFFS: dict[str, tuple[float, ...]] = {
    "reinhard": (0.0, 1.0, 0.0, 0.0, 1.0, 1.0),
    "aces": (0.6 * 0.6 * 2.51, 0.6 * 0.03, 0.0, 0.6 * 0.6 * 2.43, 0.6 * 0.59, 0.14),
    "hable": (0.231683, 0.013791, 0.0, 0.18, 0.3, 0.018),
}


def _check_pair(
    ref: np.ndarray, test: np.ndarray, dtype: type = np.float64
) -> tuple[np.ndarray, np.ndarray]:
    """Validate two images and return them as arrays of ``dtype`` (copies)."""
    a, b = np.asarray(ref), np.asarray(test)
    if a.shape != b.shape:
        raise ValueError(f"images differ in shape: reference {a.shape}, test {b.shape}")
    if a.ndim not in (2, 3) or a.size == 0:
        raise ValueError(f"images must be non-empty (H, W) or (H, W, C) arrays, got {a.shape}")
    for label, arr in (("reference", a), ("test", b)):
        if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
            raise ValueError(f"{label} image must be numeric, got dtype {arr.dtype}")
    a = np.array(a, dtype=dtype, order="C", copy=True)
    b = np.array(b, dtype=dtype, order="C", copy=True)
    for label, arr in (("reference", a), ("test", b)):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        if bad:
            raise ValueError(f"{label} image has {bad} non-finite values (NaN or infinity)")
    return a, b


def _check_range(data_range: float) -> float:
    r = float(data_range)
    if not (math.isfinite(r) and r > 0.0):
        raise ValueError(f"data_range must be a positive finite number, got {data_range!r}")
    return r


def mse(ref: np.ndarray, test: np.ndarray) -> float:
    """Mean squared error, ``mean((ref - test)**2)`` over all pixels and channels."""
    a, b = _check_pair(ref, test)
    return float(np.mean((a - b) ** 2))


def mae(ref: np.ndarray, test: np.ndarray) -> float:
    """Mean absolute error, ``mean(|ref - test|)`` over all pixels and channels."""
    a, b = _check_pair(ref, test)
    return float(np.mean(np.abs(a - b)))


def psnr(ref: np.ndarray, test: np.ndarray, *, data_range: float) -> float:
    """Peak signal-to-noise ratio in decibels, ``10 log10(data_range**2 / MSE)``.

    Parameters
    ----------
    ref, test
        Images of the same shape.
    data_range
        The peak value ``R`` (1 for images in ``[0, 1]``; for HDR images the caller chooses,
        e.g. the reference's maximum). Required: guessing it from the dtype is how PSNR
        numbers become incomparable.

    Returns
    -------
    float
        PSNR in dB; ``inf`` for identical images (MSE = 0).
    """
    r = _check_range(data_range)
    err = mse(ref, test)
    if err == 0.0:
        return math.inf
    return float(10.0 * np.log10(r * r / err))


def ssim(
    ref: np.ndarray,
    test: np.ndarray,
    *,
    data_range: float,
    win_size: int = 7,
    gaussian_weights: bool = False,
) -> float:
    """Mean structural similarity index (Wang, Bovik, Sheikh and Simoncelli, "Image Quality
    Assessment: From Error Visibility to Structural Similarity", IEEE TIP 13(4), 2004).

    Computed by ``skimage.metrics.structural_similarity`` with ``K1 = 0.01``, ``K2 = 0.03``,
    the given ``data_range`` (``L`` in Eq. 7 of the paper) and, for ``(H, W, C)`` images,
    the mean over channels (``channel_axis=-1``).

    Parameters
    ----------
    data_range
        Dynamic range ``L`` of the images (see :func:`psnr`).
    win_size
        Side of the square window, odd, at most ``min(H, W)``.
    gaussian_weights
        Weight the window with a Gaussian of sigma 1.5 as in the paper (``False``: a uniform
        window, scikit-image's default).

    Returns
    -------
    float
        Mean SSIM in ``[-1, 1]``; 1 for identical images.
    """
    from skimage.metrics import structural_similarity

    r = _check_range(data_range)
    a, b = _check_pair(ref, test)
    if win_size < 3 or win_size % 2 == 0:
        raise ValueError(f"win_size must be odd and at least 3, got {win_size}")
    if min(a.shape[0], a.shape[1]) < win_size:
        raise ValueError(
            f"SSIM with a {win_size}x{win_size} window needs images of at least "
            f"{win_size}x{win_size} pixels, got {a.shape[1]}x{a.shape[0]}"
        )
    return float(
        structural_similarity(
            a,
            b,
            data_range=r,
            win_size=win_size,
            gaussian_weights=gaussian_weights,
            channel_axis=-1 if a.ndim == 3 else None,
        )
    )


def _hdr_reference_luminance(ref: np.ndarray) -> np.ndarray:
    """Rec. 709 luminance of an HDR-FLIP reference, flattened; refuses the references that
    make ``flip_evaluator`` abort the process (non-finite, negative or black)."""
    bad = int(np.count_nonzero(~np.isfinite(ref)))
    if bad:
        raise ValueError(f"reference image has {bad} non-finite values (NaN or infinity)")
    if float(ref.min()) < 0.0:
        raise ValueError(
            "HDR-FLIP needs non-negative linear values; the reference has negative ones"
        )
    lum = (0.2126 * ref[..., 0] + 0.7152 * ref[..., 1] + 0.0722 * ref[..., 2]).ravel()
    if float(lum.max()) <= 0.0:
        raise ValueError("HDR-FLIP cannot score against a black reference (all luminance 0)")
    return lum


@dataclass(frozen=True)
class ExposureRange:
    """The exposures HDR-FLIP tone-maps at, in stops: ``count`` values evenly spaced from
    ``start`` to ``stop`` (inclusive), for the tone curve ``tonemapper``."""

    start: float
    stop: float
    count: int
    tonemapper: ToneMapper = "aces"

    def __post_init__(self) -> None:
        if not (math.isfinite(self.start) and math.isfinite(self.stop)):
            raise ValueError(f"exposures must be finite, got {self.start}..{self.stop}")
        if self.start > self.stop:
            raise ValueError(f"start exposure {self.start} is above stop exposure {self.stop}")
        if int(self.count) != self.count or self.count < 2:
            # FLIP divides by (count - 1): a single exposure yields a zero error map.
            raise ValueError(f"HDR-FLIP needs at least 2 exposures, got {self.count}")
        if self.tonemapper not in _TONE_COEFFS:
            raise ValueError(
                f"unknown tone mapper {self.tonemapper!r}; known: {', '.join(_TONE_COEFFS)}"
            )


def hdr_exposure_range(reference: np.ndarray, *, tonemapper: ToneMapper = "aces") -> ExposureRange:
    """The exposure range HDR-FLIP derives from a reference (Andersson, Nilsson, Shirley and
    Akenine-Möller, "Visualizing Errors in Rendered High Dynamic Range Images",
    Eurographics 2021, Sec. 4.2).

    With ``x_max`` the radiance the tone curve maps to 0.85, ``start = log2(x_max / Y_max)``
    and ``stop = log2(x_max / Y_median)``, where ``Y`` is the reference's luminance
    (Rec. 709 weights) and ``Y_median`` is at least float32 epsilon; ``count`` is
    ``max(2, ceil(stop - start))``. This follows NVIDIA's flip-evaluator, and computing it
    once per reference lets every candidate be scored over the same exposures.

    Raises
    ------
    ValueError
        The reference is not ``(H, W, 3)``, has non-finite or negative values, or is black
        (HDR-FLIP has no exposure at which a black image is visible).
    """
    ref = np.asarray(reference)
    if ref.ndim != 3 or ref.shape[2] != 3 or ref.size == 0:
        raise ValueError(f"HDR-FLIP needs (H, W, 3) RGB images, got {ref.shape}")
    lum = _hdr_reference_luminance(ref.astype(np.float32))
    c = _TONE_COEFFS[tonemapper]
    t = 0.85
    a, b, k = c[0] - t * c[3], c[1] - t * c[4], c[2] - t * c[5]
    x_max = (-b + math.sqrt(b * b - 4.0 * a * k)) / (2.0 * a) if a != 0.0 else -k / b
    y_max = float(lum.max())
    y_median = float(np.partition(lum, lum.size // 2)[lum.size // 2])
    y_median = max(y_median, float(np.finfo(np.float32).eps))
    start, stop = math.log2(x_max / y_max), math.log2(x_max / y_median)
    count = max(2, math.ceil(stop - start))
    return ExposureRange(start=start, stop=stop, count=count, tonemapper=tonemapper)


def flip(
    ref: np.ndarray,
    test: np.ndarray,
    *,
    mode: FlipMode = "hdr",
    exposure_range: ExposureRange | tuple[float, float, int] | None = None,
    ppd: float = DEFAULT_PPD,
) -> tuple[float, np.ndarray]:
    """FLIP perceptual difference, with NVIDIA's ``flip_evaluator``.

    LDR-FLIP: Andersson et al., "FLIP: A Difference Evaluator for Alternating Images",
    HPG 2020. HDR-FLIP: Andersson et al., Eurographics 2021 (the maximum LDR-FLIP error over
    a range of exposures of both images, tone-mapped).

    Parameters
    ----------
    ref, test
        ``(H, W, 3)`` images of the same shape. ``mode="hdr"``: linear RGB, non-negative.
        ``mode="ldr"``: sRGB-encoded values in ``[0, 1]`` (e.g. a PNG divided by 255).
    mode
        ``"hdr"`` or ``"ldr"``.
    exposure_range
        HDR only: the exposures to evaluate, an :class:`ExposureRange` or
        ``(start, stop, count)``. ``None`` derives it from ``ref`` with
        :func:`hdr_exposure_range`. Pass the same range for every candidate scored against
        one reference so that their errors are comparable.
    ppd
        Observer's pixels per degree of visual angle (default: FLIP's 67.0).

    Returns
    -------
    mean : float
        Mean FLIP error in ``[0, 1]``; 0 for identical images.
    error_map : ndarray
        ``(H, W)`` float32 per-pixel FLIP error in ``[0, 1]``.

    Notes
    -----
    The inputs are never modified: ``flip_evaluator`` converts sRGB to linear in place on
    the buffers it is given, so it gets private copies. Its ``sys.exit`` on bad arguments
    is turned into ``ValueError``, and everything that would make it abort the process
    (a black HDR reference, an empty exposure range) is refused beforehand.
    """
    import flip_evaluator

    if mode not in ("hdr", "ldr"):
        raise ValueError(f"mode must be 'hdr' or 'ldr', got {mode!r}")
    a, b = _check_pair(ref, test, np.float32)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"FLIP needs (H, W, 3) RGB images, got {a.shape}")
    if not (math.isfinite(ppd) and ppd > 0.0):
        raise ValueError(f"ppd must be positive, got {ppd}")
    params: dict[str, float | int | str] = {"ppd": float(ppd)}
    if mode == "ldr":
        for label, arr in (("reference", a), ("test", b)):
            if float(arr.min()) < 0.0 or float(arr.max()) > 1.0:
                raise ValueError(
                    f"LDR-FLIP needs values in [0, 1]; the {label} image spans "
                    f"[{float(arr.min()):.4g}, {float(arr.max()):.4g}]"
                )
    else:
        if float(b.min()) < 0.0:
            raise ValueError(
                "HDR-FLIP needs non-negative linear values; the test image has negative ones"
            )
        if exposure_range is None:
            rng = hdr_exposure_range(a)
        else:
            _hdr_reference_luminance(a)  # refuses what would abort flip_evaluator
            rng = (
                exposure_range
                if isinstance(exposure_range, ExposureRange)
                else ExposureRange(
                    float(exposure_range[0]), float(exposure_range[1]), int(exposure_range[2])
                )
            )
        params.update(
            startExposure=rng.start,
            stopExposure=rng.stop,
            numExposures=int(rng.count),
            tonemapper=rng.tonemapper,
        )
    try:
        error_map, mean, _ = flip_evaluator.evaluate(
            a,
            b,
            mode.upper(),
            inputsRGB=(mode == "ldr"),
            applyMagma=False,
            computeMeanError=True,
            parameters=params,
        )
    except SystemExit as exc:
        raise ValueError(f"flip_evaluator refused its arguments (exit {exc.code})") from None
    except RuntimeError as exc:
        raise ValueError(f"flip_evaluator: {exc}") from None
    emap = np.asarray(error_map, dtype=np.float32).reshape(a.shape[0], a.shape[1])
    return float(mean), emap
