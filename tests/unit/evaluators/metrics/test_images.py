"""Image metrics against independent references.

Oracles: numpy closed forms (MSE, MAE, PSNR of a constant offset), scikit-image called
directly (SSIM, PSNR), NVIDIA's ``flip_evaluator`` called directly with its own exposure
choice (FLIP and the HDR exposure range), plus invariances and error paths.
"""

from __future__ import annotations

import math

import flip_evaluator
import numpy as np
import pytest
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from evaluators.metrics.images import (
    ExposureRange,
    flip,
    hdr_exposure_range,
    mae,
    mse,
    psnr,
    ssim,
)


@pytest.fixture
def pair() -> tuple[np.ndarray, np.ndarray]:
    """A smooth HDR-ish reference and a noisy, darkened test image, (32, 40, 3) float32."""
    rng = np.random.default_rng(7)
    yy, xx = np.mgrid[0:32, 0:40] / 32.0
    ref = np.stack([0.2 + xx, 0.3 + yy, 0.5 + 0.5 * xx * yy], axis=-1).astype(np.float32)
    test = (ref * 0.9 + rng.normal(0.0, 0.05, ref.shape)).clip(0.0).astype(np.float32)
    return ref, test


def test01_constant_offset_closed_forms() -> None:
    # Reference: for test = ref + c everywhere, MSE = c^2, MAE = |c| and
    # PSNR = 10 log10(R^2 / c^2) = 20 log10(R / |c|).
    ref = np.linspace(0.0, 1.0, 8 * 9 * 3).reshape(8, 9, 3)
    c = 0.125
    assert mse(ref, ref + c) == pytest.approx(c * c, rel=1e-12)
    assert mae(ref, ref - c) == pytest.approx(c, rel=1e-12)
    assert psnr(ref, ref + c, data_range=2.0) == pytest.approx(20 * math.log10(2.0 / c))


def test02_psnr_and_ssim_match_scikit_image(pair) -> None:
    # Reference: scikit-image's own functions with the same explicit options.
    ref, test = pair
    r = float(ref.max())
    assert psnr(ref, test, data_range=r) == pytest.approx(
        peak_signal_noise_ratio(ref.astype(np.float64), test.astype(np.float64), data_range=r)
    )
    expected = structural_similarity(
        ref.astype(np.float64), test.astype(np.float64), data_range=r, channel_axis=-1, win_size=7
    )
    assert ssim(ref, test, data_range=r) == pytest.approx(expected, rel=1e-12)
    grey = structural_similarity(
        ref[..., 0].astype(np.float64), test[..., 0].astype(np.float64), data_range=r
    )
    assert ssim(ref[..., 0], test[..., 0], data_range=r) == pytest.approx(grey, rel=1e-12)


def test03_identical_images(pair) -> None:
    ref, _ = pair
    assert mse(ref, ref) == 0.0 and mae(ref, ref) == 0.0
    assert psnr(ref, ref.copy(), data_range=1.0) == math.inf
    assert ssim(ref, ref.copy(), data_range=float(ref.max())) == pytest.approx(1.0)
    mean, emap = flip(ref, ref.copy(), mode="hdr")
    assert mean == 0.0 and emap.shape == ref.shape[:2] and float(emap.max()) == 0.0
    ldr = ref / ref.max()
    assert flip(ldr, ldr.copy(), mode="ldr")[0] == 0.0


def test04_flip_matches_flip_evaluator(pair) -> None:
    # Reference: flip_evaluator.evaluate with its own defaults (it picks the exposures).
    ref, test = pair
    err_ref, mean_ref, used = flip_evaluator.evaluate(
        ref.copy(), test.copy(), "HDR", applyMagma=False
    )
    mean, emap = flip(ref, test, mode="hdr")
    assert mean == pytest.approx(float(mean_ref), rel=1e-5)
    # Two float32 implementations (numpy here, C++ there) of filters, colour transforms and
    # powers: measured 4e-6 on AMD EPYC, with powers near 0 amplifying ulps; a wrong filter
    # or colour space moves the map by 1e-2 or more.
    np.testing.assert_allclose(emap, np.asarray(err_ref)[..., 0], atol=3e-5)
    ldr_ref, ldr_test = ref / ref.max(), test.clip(0, ref.max()) / ref.max()
    _, mean_ldr, _ = flip_evaluator.evaluate(
        ldr_ref.copy(), ldr_test.copy(), "LDR", applyMagma=False
    )
    assert flip(ldr_ref, ldr_test, mode="ldr")[0] == pytest.approx(float(mean_ldr), rel=1e-5)


def test05_hdr_exposure_range_matches_flip_evaluator() -> None:
    # Reference: the startExposure/stopExposure/numExposures flip_evaluator reports, for
    # odd and even pixel counts and a mostly black image (median clamped to epsilon).
    rng = np.random.default_rng(1)
    for shape in [(16, 16, 3), (15, 17, 3), (24, 24, 3)]:
        ref = (rng.random(shape) ** 3 * 10).astype(np.float32)
        if shape == (24, 24, 3):
            ref[:16] = 0.0
        for tm in ("aces", "hable", "reinhard"):
            _, _, used = flip_evaluator.evaluate(
                ref.copy(), ref.copy(), "HDR", applyMagma=False, parameters={"tonemapper": tm}
            )
            got = hdr_exposure_range(ref, tonemapper=tm)
            assert got.start == pytest.approx(used["startExposure"], abs=1e-5)
            assert got.stop == pytest.approx(used["stopExposure"], abs=1e-5)
            assert got.count == used["numExposures"]


def test06_fixed_exposure_range_per_reference(pair) -> None:
    # Two candidates scored against one reference with its range equal FLIP's own result
    # for that range; passing the range explicitly changes nothing for the first candidate.
    ref, test = pair
    rng = hdr_exposure_range(ref)
    brighter = (test * 2.0).astype(np.float32)
    for cand in (test, brighter):
        params = {"startExposure": rng.start, "stopExposure": rng.stop, "numExposures": rng.count}
        _, expected, used = flip_evaluator.evaluate(
            ref.copy(), cand.copy(), "HDR", applyMagma=False, parameters=params
        )
        assert used["startExposure"] == pytest.approx(rng.start)
        assert flip(ref, cand, mode="hdr", exposure_range=rng)[0] == pytest.approx(expected)
    assert flip(ref, test, mode="hdr", exposure_range=(rng.start, rng.stop, rng.count))[
        0
    ] == pytest.approx(flip(ref, test, mode="hdr")[0])
    wider = ExposureRange(rng.start - 3.0, rng.stop + 3.0, rng.count + 6)
    assert flip(ref, test, mode="hdr", exposure_range=wider)[0] != pytest.approx(
        flip(ref, test, mode="hdr")[0]
    )


def test07_flip_does_not_modify_inputs(pair) -> None:
    ref, test = pair
    ldr_ref = np.ascontiguousarray(ref / ref.max())
    ldr_test = np.ascontiguousarray(test.clip(0, ref.max()) / ref.max())
    before = [a.copy() for a in (ref, test, ldr_ref, ldr_test)]
    flip(ref, test, mode="hdr")
    flip(ldr_ref, ldr_test, mode="ldr")
    for a, b in zip((ref, test, ldr_ref, ldr_test), before, strict=True):
        np.testing.assert_array_equal(a, b)


def test08_error_paths(pair) -> None:
    ref, test = pair
    with pytest.raises(ValueError, match="differ in shape"):
        mse(ref, test[:-1])
    with pytest.raises(ValueError, match="differ in shape"):
        flip(ref, test[:, :-1])
    nan = test.copy()
    nan[3, 4, 1] = np.nan
    with pytest.raises(ValueError, match="test image has 1 non-finite"):
        psnr(ref, nan, data_range=1.0)
    with pytest.raises(ValueError, match="non-finite"):
        flip(ref, nan)
    with pytest.raises(ValueError, match="black reference"):
        flip(np.zeros_like(ref), test, mode="hdr")
    with pytest.raises(ValueError, match="data_range"):
        psnr(ref, test, data_range=0.0)
    with pytest.raises(ValueError, match="at least 7x7"):
        ssim(ref[:5, :5], test[:5, :5], data_range=1.0)
    with pytest.raises(ValueError, match=r"LDR-FLIP needs values in \[0, 1\]"):
        flip(ref, test, mode="ldr")
    with pytest.raises(ValueError, match="non-negative"):
        flip(ref, test - 1.0, mode="hdr")
    with pytest.raises(ValueError, match="at least 2 exposures"):
        flip(ref, test, exposure_range=(0.0, 1.0, 1))
    with pytest.raises(ValueError, match="above stop"):
        ExposureRange(2.0, 1.0, 3)
    with pytest.raises(ValueError, match="mode"):
        flip(ref, test, mode="HDR10")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
        flip(ref[..., 0], test[..., 0])
