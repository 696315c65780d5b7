"""Half/diff coordinates and the MERL index.

Oracles: closed-form special cases of the Rusinkiewicz transform (normal incidence, wi = wo,
mirror pairs); round trips; and MERL's reference code (``BRDFRead.cpp``:
``std_coords_to_half_diff_coords`` with Rodrigues rotations, ``theta_half_index``,
``theta_diff_index``, ``phi_diff_index``) transcribed below independently of our
implementation, scalar and in spherical coordinates, as the reference does it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from materials import halfdiff as hd


def random_hemisphere(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2])
    return v / np.linalg.norm(v, axis=1, keepdims=True)


# --- MERL reference code, transcribed (scalar, spherical angles in, indices out) ---------


def _ref_rotate(v: list[float], axis: list[float], angle: float) -> list[float]:
    c, s = math.cos(angle), math.sin(angle)
    dot = sum(a * b for a, b in zip(axis, v, strict=True)) * (1.0 - c)
    cross = [
        axis[1] * v[2] - axis[2] * v[1],
        axis[2] * v[0] - axis[0] * v[2],
        axis[0] * v[1] - axis[1] * v[0],
    ]
    return [v[i] * c + axis[i] * dot + cross[i] * s for i in range(3)]


def _ref_half_diff(t_in: float, f_in: float, t_out: float, f_out: float):
    vin = [math.sin(t_in) * math.cos(f_in), math.sin(t_in) * math.sin(f_in), math.cos(t_in)]
    vout = [math.sin(t_out) * math.cos(f_out), math.sin(t_out) * math.sin(f_out), math.cos(t_out)]
    half = [(a + b) / 2.0 for a, b in zip(vin, vout, strict=True)]
    norm = math.sqrt(sum(x * x for x in half))
    half = [x / norm for x in half]
    theta_half = math.acos(half[2])
    fi_half = math.atan2(half[1], half[0])
    temp = _ref_rotate(vin, [0.0, 0.0, 1.0], -fi_half)
    diff = _ref_rotate(temp, [0.0, 1.0, 0.0], -theta_half)
    return theta_half, fi_half, math.acos(diff[2]), math.atan2(diff[1], diff[0])


def _ref_theta_half_index(theta_half: float) -> int:
    if theta_half <= 0.0:
        return 0
    temp = math.sqrt((theta_half / (math.pi / 2.0)) * 90 * 90)
    return min(max(int(temp), 0), 89)


def _ref_theta_diff_index(theta_diff: float) -> int:
    tmp = int(theta_diff / (math.pi * 0.5) * 90)
    return 0 if tmp < 0 else (tmp if tmp < 89 else 89)


def _ref_phi_diff_index(phi_diff: float) -> int:
    if phi_diff < 0.0:
        phi_diff += math.pi
    tmp = int(phi_diff / math.pi * 180)
    return 0 if tmp < 0 else (tmp if tmp < 179 else 179)


# --- tests ----------------------------------------------------------------------------


def test01_normal_incidence_is_origin() -> None:
    n = np.array([[0.0, 0.0, 1.0]])
    theta_h, _, theta_d, _ = hd.to_halfdiff(n, n)
    assert theta_h[0] == pytest.approx(0.0, abs=1e-12)
    assert theta_d[0] == pytest.approx(0.0, abs=1e-12)
    assert [int(i[0]) for i in hd.direction_indices(n, n)] == [0, 0, 0]


def test02_special_pairs() -> None:
    rng = np.random.default_rng(0)
    w = random_hemisphere(rng, 100)
    theta = np.arccos(w[:, 2])
    # wi = wo: the half vector is w itself and the difference angle is zero.
    theta_h, _, theta_d, _ = hd.to_halfdiff(w, w)
    np.testing.assert_allclose(theta_h, theta, atol=1e-9)
    np.testing.assert_allclose(theta_d, 0.0, atol=2e-7)
    # Mirror pair: the half vector is the normal and theta_d is the incidence angle.
    mirror = w * np.array([-1.0, -1.0, 1.0])
    theta_h, _, theta_d, _ = hd.to_halfdiff(w, mirror)
    np.testing.assert_allclose(theta_h, 0.0, atol=2e-7)
    np.testing.assert_allclose(theta_d, theta, atol=1e-9)


def test03_round_trip() -> None:
    rng = np.random.default_rng(1)
    wi, wo = random_hemisphere(rng, 5000), random_hemisphere(rng, 5000)
    wi2, wo2 = hd.from_halfdiff(*hd.to_halfdiff(wi, wo))
    np.testing.assert_allclose(wi2, wi, atol=1e-10)
    np.testing.assert_allclose(wo2, wo, atol=1e-10)


def test04_reciprocity_same_bin() -> None:
    rng = np.random.default_rng(2)
    wi, wo = random_hemisphere(rng, 5000), random_hemisphere(rng, 5000)
    a = hd.direction_indices(wi, wo)
    b = hd.direction_indices(wo, wi)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    # The unfolded variant keeps both: swapping moves phi_d by exactly 180 one-degree bins.
    a = hd.direction_indices(wi, wo, 360)
    b = hd.direction_indices(wo, wi, 360)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal((a[2] + 180) % 360, b[2])


@pytest.mark.parametrize("phi_d_bins", [180, 360])
def test05_bin_centres_map_back_to_their_bins(phi_d_bins: int) -> None:
    th, td, pd = hd.bin_centers(phi_d_bins)
    grid = np.meshgrid(th, td, pd, indexing="ij")
    idx = hd.merl_indices(*grid, phi_d_bins)
    expected = np.meshgrid(np.arange(90), np.arange(90), np.arange(phi_d_bins), indexing="ij")
    for got, want in zip(idx, expected, strict=True):
        np.testing.assert_array_equal(got, want)
    # Through directions as well (the canonical pair at phi_h = 0, and a rotated one).
    for phi_h in (0.0, 1.234):
        wi, wo = hd.bin_directions(phi_d_bins, phi_h=phi_h)
        flat = hd.flat_index(*hd.direction_indices(wi, wo, phi_d_bins), phi_d_bins)
        np.testing.assert_array_equal(flat, np.arange(90 * 90 * phi_d_bins))


def test06_matches_merl_reference_code() -> None:
    rng = np.random.default_rng(3)
    wi, wo = random_hemisphere(rng, 3000), random_hemisphere(rng, 3000)
    theta_h, phi_h, theta_d, phi_d = hd.to_halfdiff(wi, wo)
    i_h, i_d, i_p = hd.direction_indices(wi, wo)
    for n in range(len(wi)):
        t_in, f_in = math.acos(wi[n, 2]), math.atan2(wi[n, 1], wi[n, 0])
        t_out, f_out = math.acos(wo[n, 2]), math.atan2(wo[n, 1], wo[n, 0])
        ref = _ref_half_diff(t_in, f_in, t_out, f_out)
        assert theta_h[n] == pytest.approx(ref[0], abs=1e-9)
        assert theta_d[n] == pytest.approx(ref[2], abs=1e-7)
        assert math.cos(phi_d[n] - ref[3]) == pytest.approx(1.0, abs=1e-9)
        assert (i_h[n], i_d[n], i_p[n]) == (
            _ref_theta_half_index(ref[0]),
            _ref_theta_diff_index(ref[2]),
            _ref_phi_diff_index(ref[3]),
        )


def test07_generic_core_with_other_floats() -> None:
    # The same core formulas on float32 arrays (as a Dr.Jit port would see) agree closely.
    rng = np.random.default_rng(4)
    wi, wo = random_hemisphere(rng, 1000), random_hemisphere(rng, 1000)
    comps = [c.astype(np.float32) for c in (*wi.T, *wo.T)]
    got = hd.halfdiff_components(*comps)
    want = hd.to_halfdiff(wi, wo)
    for g, w in zip(got[:3:2], want[:3:2], strict=True):
        assert g.dtype == np.float32
        np.testing.assert_allclose(g, w, atol=2e-3)


def test07b_trig_free_angles_equal_the_reference() -> None:
    # halfdiff_angles (the table BSDF's hot path) == halfdiff_components in float64,
    # including h along z (wo the mirror of wi about the normal: phi_h undefined, taken 0).
    rng = np.random.default_rng(9)
    wi, wo = random_hemisphere(rng, 5000), random_hemisphere(rng, 5000)
    wo[:100] = wi[:100] * [-1, -1, 1]
    wo[100:200] = wi[100:200]  # theta_d = 0
    comps = (*wi.T, *wo.T)
    theta_h, _, theta_d, phi_d = hd.halfdiff_components(*comps)
    got_h, got_d, got_p = hd.halfdiff_angles(*comps)
    np.testing.assert_allclose(got_h, theta_h, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got_d, theta_d, rtol=0, atol=1e-12)
    # phi_d is undefined where theta_d = 0; elsewhere equal as an angle.
    some = theta_d > 1e-6
    np.testing.assert_allclose(np.cos(got_p - phi_d)[some], 1.0, rtol=0, atol=1e-12)
    assert np.all(np.abs(np.sin(got_p - phi_d)[some]) < 1e-6)


def test08_lookup_nearest_returns_the_bin() -> None:
    table = np.zeros((90, 90, 180, 3))
    table[..., 0] = np.arange(90 * 90 * 180).reshape(90, 90, 180)
    rng = np.random.default_rng(5)
    wi, wo = random_hemisphere(rng, 2000), random_hemisphere(rng, 2000)
    got = hd.lookup(table, wi, wo)[:, 0]
    np.testing.assert_array_equal(got, hd.flat_index(*hd.direction_indices(wi, wo)))
    below = wo * np.array([1.0, 1.0, -1.0])
    np.testing.assert_array_equal(hd.lookup(table, wi, below), 0.0)


def test09_lookup_interpolation() -> None:
    # Values linear in the continuous coordinates are reproduced exactly between centres.
    th, td, pd = hd.bin_centers(180)
    u_h, u_d, _ = hd.merl_coordinates(th, td, pd[:90])
    table = np.empty((90, 90, 180, 3))
    table[..., 0] = (u_h[:, None, None] + 2.0 * u_d[None, :, None]) + np.zeros((1, 1, 180))
    table[..., 1] = 1.0
    table[..., 2] = np.cos(2.0 * pd)[None, None, :] + 2.0  # pi-periodic in phi_d
    rng = np.random.default_rng(6)
    wi, wo = random_hemisphere(rng, 3000), random_hemisphere(rng, 3000)
    theta_h, _, theta_d, phi_d = hd.to_halfdiff(wi, wo)
    uh, ud, _ = hd.merl_coordinates(theta_h, theta_d, phi_d)
    inner = (uh > 0.5) & (uh < 89.5) & (ud > 0.5) & (ud < 89.5)
    got = hd.lookup(table, wi, wo, interpolate=True)
    np.testing.assert_allclose(got[inner, 0], (uh + 2.0 * ud)[inner], rtol=1e-12)
    np.testing.assert_allclose(got[:, 1], 1.0)
    # phi_d wraps around: the periodic cosine is reproduced to interpolation accuracy.
    np.testing.assert_allclose(got[:, 2], np.cos(2.0 * phi_d) + 2.0, atol=2e-3)


def test10_lookup_skips_missing_corners() -> None:
    table = np.full((90, 90, 180, 3), 2.0)
    table[:, :, ::2] = hd.MISSING
    rng = np.random.default_rng(7)
    wi, wo = random_hemisphere(rng, 500), random_hemisphere(rng, 500)
    got = hd.lookup(table, wi, wo, interpolate=True)
    np.testing.assert_allclose(got, 2.0)
    table[...] = hd.MISSING
    np.testing.assert_array_equal(hd.lookup(table, wi, wo, interpolate=True), hd.MISSING)


def test11_errors() -> None:
    with pytest.raises(ValueError, match="phi_d_bins"):
        hd.bin_centers(90)
    with pytest.raises(ValueError, match="shape"):
        hd.lookup(np.zeros((90, 90, 90, 3)), np.zeros((1, 3)), np.zeros((1, 3)))
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        hd.to_halfdiff(np.zeros((2, 3)), np.zeros((3, 3)))


def test12_drjit_twin_of_the_core() -> None:
    # The generic core runs unchanged on Dr.Jit arrays (the future table BSDF's path).
    from materials.backend import load_mitsuba

    mi = load_mitsuba()
    import drjit as dr

    rng = np.random.default_rng(8)
    wi, wo = random_hemisphere(rng, 2000), random_hemisphere(rng, 2000)
    # Include near-specular pairs, where the square-root theta_h bins are narrowest.
    wo[:500] = wi[:500] * [-1, -1, 1] + rng.normal(scale=1e-3, size=(500, 3))
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    ops = hd.drjit_ops(dr)
    comps = [mi.Float(c.astype(np.float32)) for c in (*wi.T, *wo.T)]
    theta_h, _, theta_d, phi_d = hd.halfdiff_components(*comps, ops=ops)
    coords = hd.merl_coordinates(theta_h, theta_d, phi_d, 180, ops=ops)
    want = hd.merl_coordinates(*np.delete(np.array(hd.to_halfdiff(wi, wo)), 1, axis=0))
    np.testing.assert_allclose(np.array(coords[0]), want[0], atol=0.01)
    np.testing.assert_allclose(np.array(coords[1]), want[1], atol=0.01)
    # phi_d is ill-conditioned as theta_h -> 0 (phi_h is undefined there, and an isotropic
    # BRDF does not depend on phi_d at theta_h = 0); compare it away from the peak.
    np.testing.assert_allclose(np.array(coords[2])[500:], want[2][500:], atol=0.01)
