"""BTF direction sets and procedural surfaces: counts, unit vectors above the plane, angle
round trips, periodic seeded maps with the requested relief."""

from __future__ import annotations

import numpy as np
import pytest

from materials.btf.directions import (
    check_pairs,
    legacy_ring_directions,
    preset_pairs,
    to_angles,
    to_vector,
    ubo2014_directions,
)
from materials.btf.surfaces import KINDS, procedural_surface


def test01_ubo2014_has_151_distinct_directions_on_the_hemisphere() -> None:
    d = ubo2014_directions()
    assert d.shape == (151, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    assert d[:, 2].min() > 0.0 and len(np.unique(np.round(d, 9), axis=0)) == 151
    wi, wo = preset_pairs("ubo2014")
    assert wi.shape == wo.shape == (151 * 151, 3)
    check_pairs(wi, wo)  # no pair twice


def test01b_ubo2014_is_ubo2014s_dome() -> None:
    """Reference: btflib's ``create_ubo_dome1_sampling`` as listed in the project notes
    (inclinations, azimuth counts, ring offsets), typed here, not read from the module."""
    theta, phi = to_angles(ubo2014_directions())
    rings = [0, 11, 23.5, 30, 37.5, 45, 52.5, 60, 67.5, 75]
    counts = [1, 6, 12, 12, 12, 18, 18, 24, 24, 24]
    offsets = [0, 15, 0, 15, 0, 0, 7.5, 0, 7.5, 0]
    assert sum(counts) == 151 and theta.max() < 75.0 + 1e-9  # nothing beyond UBO's 75
    start = 0
    for t, n, off in zip(rings, counts, offsets, strict=True):
        ring_t, ring_p = theta[start : start + n], phi[start : start + n]
        np.testing.assert_allclose(ring_t, t, atol=1e-9)  # float angle round trip
        if n > 1:  # the pole's azimuth is undefined
            expected = (off + np.arange(n) * 360.0 / n) % 360.0
            np.testing.assert_allclose(np.sort(ring_p), np.sort(expected), atol=1e-7)
        start += n
    # the old 8-ring set is kept under its own name, unchanged
    wi, _ = preset_pairs("rings8_legacy")
    np.testing.assert_allclose(wi[::151], legacy_ring_directions(), atol=0)
    assert to_angles(legacy_ring_directions())[0].max() > 78.0


def test02_small_preset_is_every_pair_of_six() -> None:
    wi, wo = preset_pairs("small")
    assert wi.shape == (36, 3)
    np.testing.assert_allclose(wi[:6], np.repeat(wi[:1], 6, axis=0))  # light-major
    check_pairs(wi, wo)
    with pytest.raises(ValueError, match="unknown direction preset"):
        preset_pairs("big")


def test03_angles_round_trip() -> None:
    rng = np.random.default_rng(0)
    theta, phi = rng.uniform(1, 85, 50), rng.uniform(0, 360, 50)
    t, p = to_angles(to_vector(theta, phi))
    np.testing.assert_allclose(t, theta, atol=1e-9)
    np.testing.assert_allclose(p, phi, atol=1e-9)
    np.testing.assert_allclose(to_vector(30.0, 90.0), [0.0, 0.5, np.sqrt(3) / 2], atol=1e-12)


def test04_check_pairs_refuses_bad_sets() -> None:
    up = np.array([[0.0, 0.0, 1.0]])
    with pytest.raises(ValueError, match="more than once"):
        check_pairs(np.repeat(up, 2, axis=0), np.repeat(up, 2, axis=0))
    with pytest.raises(ValueError, match="at most 85.0 degrees"):
        check_pairs(to_vector([89.0], [0.0]), up)


@pytest.mark.parametrize("kind", KINDS)
def test05_surfaces_are_seeded_and_scaled(kind: str) -> None:
    a = procedural_surface(kind, 32, np.random.default_rng(3), relief=0.03)
    b = procedural_surface(kind, 32, np.random.default_rng(3), relief=0.03)
    np.testing.assert_array_equal(a.height, b.height)
    np.testing.assert_array_equal(a.albedo, b.albedo)
    assert a.height.shape == (32, 32) and a.albedo.shape == (32, 32, 3)
    assert a.height.std() == pytest.approx(0.03, rel=1e-4)
    assert abs(float(a.height.mean())) < 1e-6
    assert 0.0 <= a.albedo.min() and a.albedo.max() <= 1.0
    assert 0.05 <= a.roughness.min() and a.roughness.max() <= 1.0
    c = procedural_surface(kind, 32, np.random.default_rng(4), relief=0.03)
    assert not np.array_equal(a.height, c.height) or kind == "fabric"


def test06_surfaces_refuse_bad_arguments() -> None:
    with pytest.raises(ValueError, match="unknown surface"):
        procedural_surface("marble", 16, np.random.default_rng(0))
    with pytest.raises(ValueError, match="relief"):
        procedural_surface("wood", 16, np.random.default_rng(0), relief=-1)
