"""Thin-film iridescence (Belcour & Barla 2017).

Oracles: the limits where the film vanishes (thickness 0, film IOR 1) must give the bare
conductor's Fresnel term, computed by the independent real-arithmetic formula that matches
Mitsuba; the Fresnel identity that a zero-thickness film is the direct interface; and a
brute-force spectral integration of Airy's exact single-wavelength reflectance against the
tabulated CIE 1931 colour matching functions (from ``colour-science``), which the
closed-form Gaussian-fit integration must reproduce.
"""

from __future__ import annotations

import colour
import numpy as np
import pytest

from materials import microfacet as mf
from materials.analytic import GGXConductor, ThinFilmGGX
from materials.thinfilm import (
    XYZ_TO_SRGB,
    airy_reflectance,
    fresnel_amplitudes,
    iridescence_fresnel,
    xyz_sensitivity,
)

COS = np.linspace(0.0, 1.0, 41)


@pytest.mark.parametrize("material", ["Au", "Cr", "Al"])
def test01_vanishing_film_is_the_base(material: str) -> None:
    eta, k = mf.named_conductor(material)
    base = mf.fresnel_conductor(COS[:, None], eta, k)
    np.testing.assert_allclose(iridescence_fresnel(COS, 0.0, 1.6, eta, k), base, atol=1e-12)
    np.testing.assert_allclose(iridescence_fresnel(COS, 450.0, 1.0, eta, k), base, atol=1e-12)
    # Approaching zero thickness is continuous (the paper's IOR fade below 30 nm).
    near = iridescence_fresnel(COS, 0.5, 1.6, eta, k)
    assert np.max(np.abs(near - base)) < 2e-3


def test02_amplitudes_and_airy_identities() -> None:
    eta, k = mf.named_conductor("Cu")
    r_s, r_p = fresnel_amplitudes(COS[:, None], 1.0, eta + 1j * k)
    np.testing.assert_allclose(
        0.5 * (np.abs(r_s) ** 2 + np.abs(r_p) ** 2),
        mf.fresnel_conductor(COS[:, None], eta, k),
        atol=1e-12,
    )
    # A film of zero thickness is the direct air/base interface, whatever its IOR.
    direct = mf.fresnel_conductor(COS, 0.3, 3.5)
    np.testing.assert_allclose(
        airy_reflectance(COS, 0.0, 1.45, 0.3, 3.5, 550.0), direct, atol=1e-12
    )
    # Lossless film on a lossless base: reflectance stays in [0, 1] at every wavelength.
    lam = np.linspace(380, 780, 200)
    r = airy_reflectance(0.7, 400.0, 1.8, 1.3, 0.0, lam)
    assert np.all((r >= 0) & (r <= 1))


def test03_normal_incidence_in_range_across_thicknesses() -> None:
    for material in ("Au", "Cr", "Al", "Ag"):
        eta, k = mf.named_conductor(material)
        for ior in (1.33, 1.5, 2.0, 2.5):
            raw = np.array(
                [
                    iridescence_fresnel(np.array([1.0]), d, ior, eta, k, clamp=False)[0]
                    for d in np.linspace(0.0, 2000.0, 101)
                ]
            )
            # The truncated series and the CMF fits overshoot [0, 1] by well under 1 %.
            assert raw.min() > -0.01 and raw.max() < 1.01, (material, ior)
            clamped = iridescence_fresnel(np.array([1.0]), 300.0, ior, eta, k)
            assert np.all((clamped >= 0) & (clamped <= 1))


def test04_thickness_shifts_colour() -> None:
    eta, k = np.full(3, 1.8), np.full(3, 2.5)  # a grey base: any colour comes from the film

    def chroma(d: float) -> np.ndarray:
        rgb = iridescence_fresnel(np.array([1.0]), d, 1.5, eta, k)[0]
        return rgb / rgb.sum()

    grey = chroma(0.0)
    np.testing.assert_allclose(grey, 1 / 3, atol=1e-12)
    shifted = [chroma(d) for d in (250.0, 350.0, 500.0)]  # first to third order colours
    for i, c in enumerate(shifted):
        assert np.max(np.abs(c - grey)) > 0.05
        assert np.max(np.abs(c - shifted[i - 1])) > 0.05


@pytest.mark.parametrize("thickness", [80.0, 250.0, 600.0])
@pytest.mark.parametrize("cos_i", [1.0, 0.4])
def test05_closed_form_matches_spectral_integration(thickness: float, cos_i: float) -> None:
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    lam, cmf = cmfs.wavelengths, cmfs.values  # 1 nm steps
    eta, k = mf.named_conductor("Au")
    white = XYZ_TO_SRGB @ (cmf.sum(axis=0) / cmf[:, 1].sum())
    brute = np.empty(3)
    for ch in range(3):
        refl = airy_reflectance(cos_i, thickness, 1.5, eta[ch], k[ch], lam)
        xyz = (refl[:, None] * cmf).sum(axis=0) / cmf[:, 1].sum()
        brute[ch] = (XYZ_TO_SRGB[ch] @ xyz) / white[ch]
    fast = iridescence_fresnel(np.array([cos_i]), thickness, 1.5, eta, k, clamp=False)[0]
    np.testing.assert_allclose(fast, brute, atol=1.5e-2)


def test06_sensitivity_normalisation() -> None:
    np.testing.assert_allclose(xyz_sensitivity(0.0, 0.0), 1.0, atol=2e-3)
    # Very long path differences average out (incoherent limit).
    assert np.all(np.abs(xyz_sensitivity(1e5, 0.3)) < 1e-6)


def test07_thin_film_ggx_source() -> None:
    rng = np.random.default_rng(0)
    wi = rng.normal(size=(500, 3))
    wo = rng.normal(size=(500, 3))
    wi[:, 2], wo[:, 2] = np.abs(wi[:, 2]), np.abs(wo[:, 2])
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    bare = GGXConductor(alpha=0.2, material="Au").eval(wi, wo)
    no_film = ThinFilmGGX(alpha=0.2, thickness_nm=300.0, film_ior=1.0, material="Au")
    # The exact film Fresnel reduces to the bare conductor's; eval interpolates it from a
    # 4096-point table in cos_d, so agrees to the interpolation error.
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=1, keepdims=True)
    cos_d = np.sum(wi * h, axis=1)
    from materials import microfacet as mf

    base = GGXConductor(alpha=0.2, material="Au")
    np.testing.assert_allclose(
        no_film.fresnel_exact(cos_d),
        mf.fresnel_conductor(cos_d[:, None], np.asarray(base.eta), np.asarray(base.k)),
        rtol=1e-12,
        atol=1e-15,
    )
    np.testing.assert_allclose(no_film.eval(wi, wo), bare, rtol=1e-4, atol=1e-12)
    film = ThinFilmGGX(alpha=0.2, thickness_nm=300.0, film_ior=1.5, material="Au")
    assert not np.allclose(film.eval(wi, wo), bare)
    with pytest.raises(ValueError, match="film_ior"):
        ThinFilmGGX(film_ior=0.9, material="Au")
    with pytest.raises(ValueError, match="thickness"):
        ThinFilmGGX(thickness_nm=-1.0, material="Au")


def test08_interpolated_fresnel_matches_the_spectral_sum() -> None:
    """The cos_d table behind ThinFilmGGX.fresnel against the exact spectral Airy sum."""
    c = np.random.default_rng(1).uniform(0.0, 1.0, 5000)
    for thickness in (50.0, 250.0, 800.0, 3000.0):
        m = ThinFilmGGX(alpha=0.2, thickness_nm=thickness, film_ior=1.45, material="Cu")
        assert np.abs(m.fresnel(c) - m.fresnel_exact(c)).max() < 1e-4
