"""Measurement simulation: determinism from the Generator, the noise model, the masks.

Oracles: identical seeds give identical bytes; the lognormal factor's mean and spread
follow from its definition (mean 1, log-standard deviation sigma); the grazing mask is
recomputed here from spherical angles of the bin-centre pairs.
"""

from __future__ import annotations

import numpy as np
import pytest

from materials import halfdiff as hd
from materials.analytic import Lambert
from materials.measurement import grazing_mask, simulate_measurement
from materials.tabulate import tabulate_analytic
from storage.formats.merl import MerlTable, merl_bytes


@pytest.fixture(scope="module")
def truth() -> MerlTable:
    return tabulate_analytic(Lambert(albedo=(0.2, 0.5, 0.8)))[0]


def test01_deterministic_per_seed(truth: MerlTable) -> None:
    a = simulate_measurement(truth, np.random.default_rng(7), dropout=0.02)
    b = simulate_measurement(truth, np.random.default_rng(7), dropout=0.02)
    c = simulate_measurement(truth, np.random.default_rng(8), dropout=0.02)
    assert merl_bytes(a) == merl_bytes(b)
    assert merl_bytes(a) != merl_bytes(c)
    assert np.all(truth.rgb[~truth.missing] > 0)  # the input is untouched


def test02_noise_statistics(truth: MerlTable) -> None:
    sigma = 0.1
    out = simulate_measurement(truth, np.random.default_rng(1), noise_sigma=sigma, grazing_deg=90.0)
    ok = ~out.missing
    ratio = out.rgb[ok] / truth.rgb[ok]
    assert np.mean(ratio) == pytest.approx(1.0, abs=2e-3)
    assert np.std(np.log(ratio)) == pytest.approx(sigma, rel=1e-2)
    assert np.array_equal(out.missing, truth.missing)  # 90 degrees and no dropout: no loss
    quiet = simulate_measurement(truth, np.random.default_rng(1), noise_sigma=0.0, grazing_deg=90.0)
    np.testing.assert_array_equal(quiet.rgb, truth.rgb)


def test03_grazing_and_dropout_masks(truth: MerlTable) -> None:
    wi, wo = hd.bin_directions(180)
    theta_i, theta_o = np.degrees(np.arccos(wi[:, 2])), np.degrees(np.arccos(wo[:, 2]))
    expected = ((theta_i > 75.0) | (theta_o > 75.0)).reshape(90, 90, 180)
    np.testing.assert_array_equal(grazing_mask(180, 75.0), expected)
    out = simulate_measurement(truth, np.random.default_rng(2), grazing_deg=75.0, dropout=0.1)
    assert np.all(out.rgb[out.missing] == hd.MISSING)
    assert np.all(out.missing[expected])
    kept = ~expected
    lost = out.missing[kept].mean()
    assert lost == pytest.approx(0.1, abs=0.01)


def test04_validation(truth: MerlTable) -> None:
    with pytest.raises(TypeError, match="Generator"):
        simulate_measurement(truth, 3)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="dropout"):
        simulate_measurement(truth, np.random.default_rng(0), dropout=1.0)
    with pytest.raises(ValueError, match="grazing_deg"):
        simulate_measurement(truth, np.random.default_rng(0), grazing_deg=0.0)
