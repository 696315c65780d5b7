"""The 4-lobe Lafortune model of Xu et al. Sec. 5.3 (times ``wi.z``, see the module
docstring): each test compares with a reference written independently of the model: the
UBO2014 Lambertian value, the mirror vector, Helmholtz reciprocity, the paper's storage."""

from __future__ import annotations

import numpy as np
import pytest

from materials.btf.directions import to_angles, to_vector
from materials.btf.lafortune import (
    LOBES,
    PARAMS_PER_TEXEL,
    initial_params,
    join_params,
    lafortune_eval,
    lobe_offset,
    split_params,
)


def _directions(rng: np.random.Generator, n: int, max_theta: float = 85.0) -> np.ndarray:
    return to_vector(rng.uniform(0.0, max_theta, n), rng.uniform(0.0, 360.0, n))


def test01_diffuse_only_is_a_lambertian_plane() -> None:
    """Reference: the BTF convention (UBO2014, ``L_o / E_perp``): a flat Lambertian plane of
    albedo ``a`` gives ``a / pi * cos(theta_i)``, whatever the view."""
    rng = np.random.default_rng(1)
    wi, wo = _directions(rng, 200), _directions(rng, 200)
    albedo = np.array([[0.8, 0.5, 0.2], [0.1, 0.3, 0.9]])
    params = np.zeros((2, PARAMS_PER_TEXEL))
    params[:, 0:3] = albedo / np.pi
    for j in range(LOBES):  # lobes with a shape but no colour contribute nothing
        params[:, lobe_offset(j) : lobe_offset(j) + 9] = np.eye(3).reshape(-1)
        params[:, lobe_offset(j) + 9] = 5.0
    got = lafortune_eval(params, wi, wo)
    theta_i, _ = to_angles(wi)
    want = albedo[:, None, :] / np.pi * np.cos(np.radians(theta_i))[None, :, None]
    assert got.shape == (2, 200, 3) and got.dtype == np.float64
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=0.0)


def test02_mirror_lobe_is_cosine_to_the_mirror_direction_to_the_n() -> None:
    """Reference: the mirror vector ``2 (N . wi) N - wi`` about the normal ``N = z``; the
    lobe ``M = diag(-1, -1, 1)`` is ``max(cos(wo, mirror(wi)), 0) ** n`` (times ``wi.z``
    and its colour), zero when the angle exceeds 90 degrees."""
    rng = np.random.default_rng(2)
    wi, wo = _directions(rng, 300), _directions(rng, 300)
    normal = np.array([0.0, 0.0, 1.0])
    mirror = 2.0 * (wi @ normal)[:, None] * normal - wi
    cosine = np.sum(wo * mirror, axis=1)
    assert (cosine < 0).any() and (cosine > 0.9).any()
    exponent, colour = 7.5, np.array([1.0, 0.5, 0.25])
    m = np.zeros((LOBES, 3, 3))
    m[2] = np.diag([-1.0, -1.0, 1.0])
    n = np.ones(LOBES)
    n[2] = exponent
    rho_s = np.zeros((LOBES, 3))
    rho_s[2] = colour
    params = join_params(np.zeros((1, 3)), m[None], n[None], rho_s[None])
    want = wi[:, 2, None] * colour * (np.clip(cosine, 0.0, None) ** exponent)[:, None]
    np.testing.assert_allclose(lafortune_eval(params, wi, wo)[0], want, rtol=1e-12, atol=1e-15)


def test03_symmetric_matrices_give_a_reciprocal_brdf() -> None:
    """Reference: Helmholtz reciprocity. ``model / wi.z`` is the BRDF part; with every
    ``M_j`` symmetric, ``wo^T M wi = wi^T M wo``, so swapping light and view changes
    nothing."""
    rng = np.random.default_rng(3)
    wi, wo = _directions(rng, 150), _directions(rng, 150)
    a = rng.normal(size=(5, LOBES, 3, 3))
    m = a + np.swapaxes(a, -1, -2)
    params = join_params(
        rng.uniform(0, 0.3, (5, 3)), m, rng.uniform(1, 30, (5, LOBES)), rng.uniform(0, 1, (5, 4, 3))
    )
    forward = lafortune_eval(params, wi, wo) / wi[None, :, 2, None]
    backward = lafortune_eval(params, wo, wi) / wo[None, :, 2, None]
    np.testing.assert_allclose(forward, backward, rtol=1e-10, atol=1e-14)
    assert np.abs(forward).max() > 0.1  # the lobes are not all clipped away
    m[:, 0, 0, 1] += 1.0  # an asymmetric M breaks it
    bent = join_params(*split_params(params)[:1], m, *split_params(params)[2:])
    assert not np.allclose(
        lafortune_eval(bent, wi, wo) / wi[None, :, 2, None],
        lafortune_eval(bent, wo, wi) / wo[None, :, 2, None],
    )


def test04_layout_and_shapes() -> None:
    """Reference: the paper's storage, 35.2 MB at 400 x 400 texels = 55 float32 per texel =
    3 + 4 x (9 + 1 + 3); and the documented offsets (lobe ``j`` at ``3 + 13 j``: ``M``
    row-major, ``n``, ``rho_s``)."""
    assert PARAMS_PER_TEXEL == 55 == 3 + LOBES * (9 + 1 + 3) and LOBES == 4
    assert PARAMS_PER_TEXEL * 4 * 400 * 400 == 35_200_000
    assert [lobe_offset(j) for j in range(LOBES)] == [3, 16, 29, 42]
    with pytest.raises(ValueError, match="lobe index"):
        lobe_offset(4)
    p = np.arange(2 * 55, dtype=np.float64).reshape(2, 55)
    rho_d, m, n, rho_s = split_params(p)
    assert rho_d.shape == (2, 3) and m.shape == (2, 4, 3, 3)
    assert n.shape == (2, 4) and rho_s.shape == (2, 4, 3)
    np.testing.assert_array_equal(rho_d[1], [55, 56, 57])
    assert m[0, 1, 2, 0] == 3 + 13 + 3 * 2 + 0  # M[a, b] at o + 3 a + b
    np.testing.assert_array_equal(n[0], [12, 25, 38, 51])
    np.testing.assert_array_equal(rho_s[0, 3], [52, 53, 54])
    np.testing.assert_array_equal(join_params(rho_d, m, n, rho_s), p)
    wi = _directions(np.random.default_rng(4), 7)
    assert lafortune_eval(initial_params(np.ones((3, 3))), wi, wi[::-1]).shape == (3, 7, 3)
    with pytest.raises(ValueError, match=r"\(S, 3\)"):
        lafortune_eval(p, wi, wi[:3])
    with pytest.raises(ValueError, match="params"):
        lafortune_eval(p[:, :54], wi, wi)


def test05_initial_params_and_the_exponent_clamp() -> None:
    """Reference: the starting point the task specifies (diffuse 0.7 of the mean; mirror
    n = 20 and 4, retro n = 8, diag(0, 0, 1) n = 2; lobes coloured 0.05 of the mean) and the
    clamp ``n >= 1`` (``n = 0.2`` evaluates as ``n = 1``)."""
    mean = np.array([[0.2, 0.4, 0.6], [0.0, 0.0, 0.0]])
    rho_d, m, n, rho_s = split_params(initial_params(mean))
    np.testing.assert_allclose(rho_d, 0.7 * mean)
    np.testing.assert_allclose(rho_s, 0.05 * np.repeat(mean[:, None], 4, axis=1))
    diagonals = [[-1, -1, 1], [-1, -1, 1], [1, 1, 1], [0, 0, 1]]
    np.testing.assert_array_equal(m[0], [np.diag(d) for d in diagonals])
    np.testing.assert_array_equal(n[1], [20, 4, 8, 2])
    rng = np.random.default_rng(5)
    wi, wo = _directions(rng, 50), _directions(rng, 50)
    p = initial_params(mean[:1])
    low, one = p.copy(), p.copy()
    low[:, lobe_offset(3) + 9], one[:, lobe_offset(3) + 9] = 0.2, 1.0
    np.testing.assert_array_equal(lafortune_eval(low, wi, wo), lafortune_eval(one, wi, wo))
