"""The aggregated patch BSDF of Eq. 3-5 and its four components (Eq. 7-8).

Oracles, none of which calls the estimator's own integrand:

- flat yarns (beta = 0), no visibility effects: the coverage-weighted point BSDF, with the
  coverage counted from the pattern matrix and the point BSDF from ``slab_reference.py``
  (explicit-matrix SGGX, depth-integrated slab); with twisted fibres, the average of that
  reference over the rasterised tile;
- curved yarns without visibility: Eq. 3-5 evaluated by the test itself as a ratio of
  pixel sums over the rasterised n_p / t_p maps, with the reference BSDF;
- statistics: the standard error's log-log slope against N is -1/2; errors divided by the
  reported standard error have unit scale; Sobol's RMSE beats independent sampling at equal
  N on the same queries, against a high-sample reference;
- physics: centre independence as the footprint covers many tiles; finite, non-negative
  values; a white furnace, ``int f_P A_P(wo) dwo <= A_P^in(wi)`` (albedo <= 1), which for
  flat white Lambertian yarns equals the yarn coverage.
"""

from __future__ import annotations

import numpy as np
import pytest

from materials.fabric import yarn
from materials.fabric.aggregate import AggregateEstimate, FootprintQueries, estimate
from materials.fabric.array_ops import NumpyOps
from materials.fabric.integrand import point_components
from materials.fabric.params import FabricParams, sample_params
from materials.fabric.patterns import PATTERNS
from tests.helpers.slab_reference import direction, slab_specular

Z = np.array([0.0, 0.0, 1.0])


def queries(
    wi: list[np.ndarray], wo: list[np.ndarray], centres: np.ndarray, size: float
) -> FootprintQueries:
    """Every (wi, wo) pair at every centre."""
    pairs = [(a, b, c) for a, b in zip(wi, wo, strict=True) for c in centres]
    return FootprintQueries(
        centre=np.array([c for _, _, c in pairs]),
        size=np.full(len(pairs), size),
        wi=np.array([a for a, _, _ in pairs]),
        wo=np.array([b for _, b, _ in pairs]),
    )


WI = [direction(35, 20), direction(70, 200), direction(150, 40), direction(10, 0)]
WO = [direction(20, 210), direction(50, 10), direction(30, 250), direction(85, 90)]


def flat_reference(params: FabricParams, q: FootprintQueries) -> np.ndarray:
    """(Q, 4) coverage-weighted point BSDF for flat yarns with psi = 0, times |cos theta_i|."""
    pat = params.pattern
    cov_warp = 0.8 * pat.warp_up.mean()
    cov_weft = 0.8 * (~pat.warp_up).mean()
    t_warp, t_weft = np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0])
    cos_i = np.abs(q.wi[:, 2])
    lit = q.wi[:, 2] > 0
    s_warp = slab_specular(q.wi, q.wo, Z, t_warp, params.alpha.warp)
    s_weft = slab_specular(q.wi, q.wo, Z, t_weft, params.alpha.weft)
    diffuse = np.where(lit, 1.0 / np.pi, 0.0)
    ref = np.stack(
        [cov_warp * diffuse, cov_weft * diffuse, cov_warp * s_warp, cov_weft * s_weft], axis=1
    )
    return ref * cos_i[:, None]


def assert_close(est: AggregateEstimate, ref: np.ndarray, *, sigmas: float, rel: float) -> None:
    bound = sigmas * est.stderr + rel * np.abs(ref) + 1e-9
    assert np.all(np.abs(est.mean - ref) <= bound), np.max(np.abs(est.mean - ref) / bound)


@pytest.mark.parametrize("name", ["plain", "twill_3x3", "satin_5x10"])
def test01_flat_yarns_give_the_coverage_weighted_point_bsdf(name: str) -> None:
    params = FabricParams(
        PATTERNS[name],
        psi_deg=0.0,
        alpha=(0.25, 0.5),
        beta=0.0,
        w=0.4,  # type: ignore[arg-type]
        kd_warp=(0.9, 0.2, 0.1),
        kd_weft=(0.1, 0.3, 0.8),
        ks_warp=0.7,
        ks_weft=(0.2, 0.5, 0.4),  # type: ignore[arg-type]
    )
    centres = np.random.default_rng(1).uniform(-3, 3, size=(3, 2))
    q = queries(WI, WO, centres, 2.0)  # whole tiles: the coverage is exact
    ref = flat_reference(params, q)
    albedos = params.albedos()
    for with_visibility in (True, False):
        # Independent sampling: its standard error has N - 1 degrees of freedom, so a
        # 4.5-sigma bound is sharp (the flat case has no ratio bias: A_P = cos theta_o).
        est = estimate(
            params, q, samples=4096, sampler="independent", with_visibility=with_visibility
        )
        assert_close(est, ref, sigmas=4.5, rel=0.0)
        # Eq. 8: recombining with the albedos gives the full aggregate.
        rgb = est.recombine(params)
        np.testing.assert_array_equal(rgb, est.mean @ albedos)
        bound = 4.5 * est.stderr @ albedos + 1e-9  # |sum a_c e_c| <= sum a_c |e_c|
        assert np.all(np.abs(rgb - ref @ albedos) <= bound)
        np.testing.assert_allclose(est.area, q.wo[:, 2], rtol=1e-6)
    sobol = estimate(params, q, samples=1024, seed=4)
    assert_close(sobol, ref, sigmas=5.0, rel=3e-2)
    # A Gaussian kernel (sigma = 8 / sqrt(12) = 2.3 tiles) averages a periodic coverage to
    # its tile mean up to exp(-2 pi^2 sigma^2) ~ 1e-45.
    wide = queries(WI, WO, centres, 8.0)
    gauss = estimate(params, wide, samples=4096, sampler="independent", kernel="gaussian")
    assert_close(gauss, flat_reference(params, wide), sigmas=4.5, rel=0.0)


def test02_flat_twisted_yarns_average_over_the_tile() -> None:
    """psi != 0 turns t_p across the yarn: average the reference BSDF over the raster."""
    params = FabricParams(PATTERNS["twill_3x3"], psi_deg=(30, -20), alpha=0.3, beta=0.0)  # type: ignore[arg-type]
    maps = yarn.rasterize(params, 300)
    wi, wo = direction(40, 30), direction(25, 160)
    est = estimate(params, queries([wi], [wo], np.array([[0.3, 0.8]]), 1.0), samples=4096)
    ref = np.zeros(4)
    for col, kind in ((2, yarn.WARP), (3, yarn.WEFT)):
        tangents = maps.tangent[maps.yarn == kind].astype(np.float64)
        count = len(tangents)
        f = slab_specular(
            np.tile(wi, (count, 1)), np.tile(wo, (count, 1)), np.tile(Z, (count, 1)), tangents, 0.3
        )
        ref[col] = f.mean() * (maps.yarn == kind).mean() * wi[2]
        ref[col - 2] = (maps.yarn == kind).mean() * wi[2] / np.pi
    np.testing.assert_allclose(est.mean[0], ref, rtol=2e-2)


def eq3_reference(params: FabricParams, wi: np.ndarray, wo: np.ndarray, res: int) -> np.ndarray:
    """Eq. 3-5 without visibility as pixel sums over the rasterised tile (test's own code)."""
    maps = yarn.rasterize(params, res)
    keep = maps.yarn.ravel() != yarn.GAP
    kind = maps.yarn.ravel()[keep]
    n = maps.normal.reshape(-1, 3).astype(np.float64)
    t = maps.tangent.reshape(-1, 3).astype(np.float64)
    jac = 1.0 / n[:, 2]
    co = np.maximum(n @ wo, 0.0)
    area = np.sum(co * jac)  # Eq. 5 (gaps included, with n_p = n_s)
    n, t, jac, co = n[keep], t[keep], jac[keep], co[keep]
    c_i = np.maximum(n @ wi, 0.0) if wi[2] > 0 else np.maximum(-(n @ wi), 0.0)
    spec = np.zeros(len(n))
    live = (c_i > 0) & (co > 0)
    rows = int(live.sum())  # per pixel, with explicit matrices
    spec[live] = slab_specular(
        np.tile(wi, (rows, 1)), np.tile(wo, (rows, 1)), n[live], t[live], params.alpha.warp
    )
    w = params.w
    diff = (
        (w * c_i + (1 - w) * np.minimum(c_i, max(wi[2], 0.0)))
        / np.pi
        * co
        / np.maximum(c_i * co, 1e-300)
    )
    diff = np.where(c_i * co > 0, diff, 0.0) if wi[2] > 0 else np.zeros(len(n))
    out = []
    for f in (diff, spec):
        for kk in (yarn.WARP, yarn.WEFT):
            out.append(np.sum(np.where(kind == kk, f * c_i * co * jac, 0.0)) / area)
    return np.array([out[0], out[1], out[2], out[3]])


@pytest.mark.parametrize(
    ("wi", "wo"),
    [(direction(40, 30), direction(30, 200)), (direction(140, 60), direction(35, 250))],
)
def test03_curved_yarns_without_visibility_match_eq3(wi: np.ndarray, wo: np.ndarray) -> None:
    params = FabricParams(
        PATTERNS["satin_5x5"],
        psi_deg=25.0,
        u_max_deg=30.0,
        alpha=0.4,
        beta=0.7,
        w=0.6,  # type: ignore[arg-type]
    )
    ref = eq3_reference(params, wi, wo, 160)
    q = queries([wi], [wo], np.array([[0.37, 0.61]]), 1.0)
    est = estimate(params, q, samples=8192, with_visibility=False)
    assert_close(est, ref[None], sigmas=5.0, rel=2e-2)


def curved() -> FabricParams:
    return FabricParams(
        PATTERNS["twill_3x3"],
        psi_deg=(20, -15),
        u_max_deg=(30, 25),
        alpha=(0.3, 0.5),  # type: ignore[arg-type]
        beta=(0.8, 0.6),
        w=0.7,  # type: ignore[arg-type]
    )


def test04_large_footprints_stop_depending_on_the_centre() -> None:
    """Across six centres, the scatter of f_P beyond its standard errors (chi^2 per degree of
    freedom) is huge for a quarter tile and consistent with noise over many tiles."""
    params = curved()
    centres = np.random.default_rng(4).uniform(0, 1, size=(6, 2))
    wi, wo = [direction(45, 30), direction(160, 80)], [direction(30, 200), direction(40, 10)]
    chi2 = {}
    for size in (0.25, 2.5, 24.5):
        est = estimate(params, queries(wi, wo, centres, size), samples=4096, seed=1)
        total = est.mean.reshape(2, 6, 4).sum(axis=2)  # (direction pair, centre)
        var = (est.stderr.reshape(2, 6, 4) ** 2).sum(axis=2)
        mean = (total / var).sum(axis=1, keepdims=True) / (1 / var).sum(axis=1, keepdims=True)
        chi2[size] = float(((total - mean) ** 2 / var).sum() / (2 * 5))
    assert chi2[0.25] > 50 * chi2[24.5], chi2  # small footprints see single yarns
    assert chi2[24.5] < 5.0, chi2  # p ~ 1e-6 for 10 degrees of freedom and exact errors
    assert chi2[0.25] > chi2[2.5] > chi2[24.5], chi2


def test05_standard_error_falls_as_one_over_sqrt_n_and_is_calibrated() -> None:
    params = curved()
    centres = np.random.default_rng(5).uniform(0, 1, size=(4, 2))
    q = queries(WI[:2], WO[:2], centres, 0.7)
    ref = estimate(params, q, samples=1 << 15, sampler="sobol", seed=99).mean
    ns = np.array([128, 512, 2048, 8192])
    mean_se, z2 = [], []
    for n in ns:
        est = estimate(params, q, samples=int(n), sampler="independent", seed=int(n))
        live = est.stderr > 0
        mean_se.append(est.stderr[live].mean())
        z2.append((((est.mean - ref)[live] / est.stderr[live]) ** 2).mean())
    slope = np.polyfit(np.log(ns), np.log(mean_se), 1)[0]
    assert -0.6 < slope < -0.4, slope
    assert 0.3 < np.mean(z2) < 3.0, z2


def test06_sobol_beats_independent_sampling_at_equal_n() -> None:
    """RMSE against a 2^16-sample reference, same queries, same N, three seeds each.

    The gain is large where the footprint holds a few yarns and shrinks as it covers many
    (the integrand's edges outnumber what N points resolve).
    """
    params = curved()
    centres = np.random.default_rng(6).uniform(0, 1, size=(4, 2))
    for size, n, most in ((0.3, 1024, 0.5), (1.5, 4096, 0.95)):
        q = queries(WI, WO, centres, size)
        ref = estimate(params, q, samples=1 << 16, sampler="sobol", seed=123, replicates=2).mean
        scale = np.abs(ref).mean(axis=0)
        rmse = {}
        for sampler in ("independent", "sobol"):
            err = [
                (estimate(params, q, samples=n, sampler=sampler, seed=s).mean - ref) / scale
                for s in range(3)
            ]
            rmse[sampler] = float(np.sqrt(np.mean(np.square(err))))
        assert rmse["sobol"] < most * rmse["independent"], (size, rmse)


def test07_values_are_finite_and_non_negative() -> None:
    rng = np.random.default_rng(7)
    for name in sorted(PATTERNS):
        params = sample_params(rng, name)
        m = 12
        wi = rng.normal(size=(m, 3))
        wi[: m // 3, 2] = -np.abs(wi[: m // 3, 2])  # light from below
        wi[m // 3 :, 2] = np.abs(wi[m // 3 :, 2])
        wi[-1] = [1.0, 0.0, 1e-3]  # grazing light
        wo = rng.normal(size=(m, 3))
        wo[:, 2] = np.abs(wo[:, 2]) + 1e-3
        wo[-2] = [0.0, 1.0, 2e-3]  # grazing view
        size = rng.uniform(0, 3, m)
        size[:2] = 0.0  # point queries
        q = FootprintQueries(
            rng.uniform(-5, 5, (m, 2)),
            size,
            wi / np.linalg.norm(wi, axis=1, keepdims=True),
            wo / np.linalg.norm(wo, axis=1, keepdims=True),
        )
        for kernel in ("box", "gaussian"):
            est = estimate(params, q, samples=64, kernel=kernel, seed=1)  # type: ignore[arg-type]
            for a in (est.mean, est.stderr, est.area, est.area_in):
                assert np.all(np.isfinite(a)) and np.all(a >= 0)


def furnace(
    params: FabricParams, wi: np.ndarray, m: int = 512, n: int = 128
) -> tuple[np.ndarray, np.ndarray, float]:
    """Per component family, MC over wo of int f_P A_P(wo) dwo / A_P^in(wi), and its error."""
    rng = np.random.default_rng(8)
    u = rng.uniform(size=(m, 2))
    z = u[:, 0]  # uniform hemisphere: pdf 1 / (2 pi)
    r = np.sqrt(1 - z * z)
    wo = np.stack([r * np.cos(2 * np.pi * u[:, 1]), r * np.sin(2 * np.pi * u[:, 1]), z], 1)
    wo = wo[z > 1e-3]
    q = FootprintQueries(
        np.tile([0.2, 0.4], (len(wo), 1)), np.full(len(wo), 3.0), np.tile(wi, (len(wo), 1)), wo
    )
    est = estimate(params, q, samples=n, sampler="sobol", seed=2)
    flux = est.mean * est.area[:, None] * 2 * np.pi  # f_P A_P(wo) / pdf(wo)
    families = np.stack([flux[:, :2].sum(1), flux[:, 2:].sum(1)], axis=1)
    incoming = est.area_in.mean()
    albedo = families.mean(axis=0) / incoming
    err = families.std(axis=0) / np.sqrt(len(wo)) / incoming
    return albedo, err, float(incoming)


@pytest.mark.parametrize("theta_i", [20.0, 70.0, 140.0])
def test08_white_furnace_bounds_the_albedo(theta_i: float) -> None:
    """With unit albedos, diffuse and specular each reflect at most what the yarns intercept."""
    for w in (1.0, 0.3):
        params = curved().replace(w=w)
        albedo, err, _ = furnace(params, direction(theta_i, 35))
        assert np.all(albedo <= 1.0 + 3 * err), (albedo, err)
        assert np.all(albedo >= 0)
        if theta_i > 90:
            assert albedo[0] == 0.0  # no diffuse transmission
    # Flat white Lambertian yarns reflect exactly their coverage: 1 - gap = 0.8.
    flat = curved().replace(beta=(0.0, 0.0), w=1.0)
    if theta_i < 90:
        albedo, err, incoming = furnace(flat, direction(theta_i, 35))
        assert incoming == pytest.approx(np.cos(np.radians(theta_i)), rel=1e-5)
        assert albedo[0] == pytest.approx(0.8, abs=4 * err[0] + 2e-3)


def test09_chunking_threads_and_validation() -> None:
    params = curved()
    q = queries(WI, WO, np.random.default_rng(9).uniform(0, 1, (40, 2)), 0.5)
    a = estimate(params, q, samples=64, replicates=4)
    b = estimate(params, q, samples=64, replicates=4, chunk_queries=64, threads=2)
    # Threads take whole sample blocks, so no sum is reordered (bitwise equal here); 1e-12
    # would still admit a reassociated float64 sum of 64 samples.
    np.testing.assert_allclose(a.mean, b.mean, rtol=1e-12)
    np.testing.assert_allclose(a.stderr, b.stderr, rtol=1e-12)
    up = direction(30, 0)
    with pytest.raises(ValueError, match="wo must point above"):
        FootprintQueries(np.zeros((1, 2)), [1.0], [up], [direction(120, 0)])
    with pytest.raises(ValueError, match="unit vectors"):
        FootprintQueries(np.zeros((1, 2)), [1.0], [2 * up], [up])
    with pytest.raises(ValueError, match="sizes"):
        FootprintQueries(np.zeros((1, 2)), [-1.0], [up], [up])
    with pytest.raises(ValueError, match="expected centre"):
        FootprintQueries(np.zeros((2, 3)), [1.0, 1.0], [up, up], [up, up])
    with pytest.raises(ValueError, match="kernel"):
        estimate(params, q, kernel="disc")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="backend"):
        estimate(params, q, backend="cuda")  # type: ignore[arg-type]


def test10_point_components_of_flat_yarns() -> None:
    """The plain point BSDF f_p at single points: reference slab on yarns, zero in gaps."""
    params = FabricParams(PATTERNS["plain"], alpha=(0.3, 0.45), beta=0.0)  # type: ignore[arg-type]
    geo = yarn.YarnGeometry.from_params(params)
    ops = NumpyOps()
    # Warp-up cell (0, 0) centre, weft-up cell (0, 1) centre, and a gap strip of cell (0, 0).
    s = np.array([0.25, 0.75, 0.02])
    t = np.array([0.25, 0.25, 0.25])
    wi, wo = direction(40, 10), direction(30, 230)
    tile = (np.full(3, wi[0]), np.full(3, wi[1]), np.full(3, wi[2]))
    view = (np.full(3, wo[0]), np.full(3, wo[1]), np.full(3, wo[2]))
    comps = np.stack(point_components(ops, params, geo, yarn.tables(ops, geo), s, t, tile, view))
    warp = slab_specular(wi[None], wo[None], Z, np.array([0.0, 1.0, 0.0]), 0.3)[0]
    weft = slab_specular(wi[None], wo[None], Z, np.array([1.0, 0.0, 0.0]), 0.45)[0]
    expected = np.array(
        [[1 / np.pi, 0.0, 0.0], [0.0, 1 / np.pi, 0.0], [warp, 0.0, 0.0], [0.0, weft, 0.0]]
    )
    np.testing.assert_allclose(comps, expected, rtol=1e-6, atol=1e-12)
