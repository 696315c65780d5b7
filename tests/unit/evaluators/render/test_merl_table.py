"""The MERL table BSDF (``merl_table``): lookup, sampling and the fitted lobe.

Oracles, each independent of the code under test:

- the numpy reference lookup :func:`materials.halfdiff.lookup` (``interpolate=True``), for
  the Dr.Jit interpolation, to float32 precision;
- Mitsuba's own ``roughconductor`` and ``roughplastic``, evaluated at random pairs (not at
  bin centres), for the table BSDF of their tabulations: the error is the table's
  resolution, bounded as measured in ``test_tabulate.py``;
- Mitsuba's chi-square harness (:mod:`mitsuba.chi2`), for the consistency of ``sample``
  and ``pdf``; closed forms (pdf >= 0, pdf integrates to at most 1, weight = eval / pdf);
- the parameters a tabulated GGX lobe was made with, for the fit.

Run with ``-s`` to see the measured numbers.
"""

from __future__ import annotations

import math
import types
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from evaluators.render.bsdfs.merl_table import (
    MERL_BSDF_NAME,
    merl_bsdf,
    register_merl_bsdf,
)
from materials import halfdiff as hd
from materials.lobe_fit import fit_sampling_lobe
from materials.tabulate import tabulate_mitsuba
from storage.formats.merl import MerlTable, write_merl
from tests.helpers.mitsuba_probes import (
    AU_03,
    PLASTIC_03,
    check_pdf_and_sampling,
    hemisphere,
    interaction,
)

PLUGINS = {"conductor": AU_03, "plastic": PLASTIC_03}


@pytest.fixture(scope="module")
def mi(mi: types.ModuleType) -> types.ModuleType:
    """The LLVM Mitsuba of tests/conftest.py, with this module's plugins registered."""
    mod = mi
    register_merl_bsdf(mod)
    return mod


@pytest.fixture(scope="module")
def tables(mi: types.ModuleType, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Tabulations of the two Mitsuba materials, written as ``.binary`` files."""
    root = tmp_path_factory.mktemp("merl_bsdf")
    out = {}
    for name, plugin in PLUGINS.items():
        table, _ = tabulate_mitsuba(plugin)
        out[name] = root / f"{name}.binary"
        write_merl(out[name], table)
    return out


def load(mi: types.ModuleType, path: Path, extra: str = "") -> Any:
    xml = f'<string name="filename" value="{path}"/>{extra}'
    return mi.load_string(f'<bsdf version="3.0.0" type="{MERL_BSDF_NAME}">{xml}</bsdf>')


def brdf(mi: types.ModuleType, bsdf: Any, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """``(N, 3)`` float64 ``eval / wo.z`` of a Mitsuba BSDF at float32 pairs."""
    value = bsdf.eval(mi.BSDFContext(), interaction(mi, wi), mi.Vector3f(*wo.T))
    cos_o = wo[:, 2:3].astype(np.float64)
    return np.asarray(value, np.float64).T / np.where(cos_o > 0, cos_o, np.inf)


def test01_create(mi: types.ModuleType, tables: dict[str, Path]) -> None:
    assert register_merl_bsdf(mi) is register_merl_bsdf(mi)  # idempotent
    bsdf = load(mi, tables["conductor"])
    assert isinstance(bsdf, mi.BSDF)
    assert bsdf.flags() == mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
    assert "MerlBSDF[phi_d_bins=180" in str(bsdf)
    # A context that excludes glossy reflection sees nothing.
    ctx = mi.BSDFContext()
    ctx.type_mask = +mi.BSDFFlags.DiffuseReflection
    wi = np.array([[0.0, 0.0, 1.0]], np.float32)
    si, wo = interaction(mi, wi), mi.Vector3f(0.0, 0.0, 1.0)
    assert np.all(np.asarray(bsdf.eval(ctx, si, wo)) == 0.0)
    assert np.all(np.asarray(bsdf.pdf(ctx, si, wo)) == 0.0)
    assert np.all(np.asarray(bsdf.eval(mi.BSDFContext(), si, wo)) > 0.0)
    fixed = load(
        mi,
        tables["plastic"],
        '<float name="alpha" value="0.2"/><float name="specular_weight" value="0.5"/>',
    )
    assert "alpha=0.2," in str(fixed) and "specular_weight=0.5]" in str(fixed)
    with pytest.raises(Exception, match="exactly one of 'filename' and 'data'"):
        mi.load_dict({"type": MERL_BSDF_NAME})
    with pytest.raises(Exception, match="table shape"):
        mi.load_dict({"type": MERL_BSDF_NAME, "data": mi.TensorXf(np.zeros((90, 90, 3)))})
    with pytest.raises(Exception, match="size mismatch"):
        bad = tables["plastic"].with_name("short.binary")
        bad.write_bytes(tables["plastic"].read_bytes()[:1000])
        load(mi, bad)


def test02_eval_matches_numpy_lookup(mi: types.ModuleType) -> None:
    """Dr.Jit interpolation == ``halfdiff.lookup(interpolate=True)`` at random pairs."""
    rng = np.random.default_rng(7)
    # A table with structure along all three axes, in both phi_d layouts, and with 5 % of
    # its entries missing in one channel (renormalised per channel in both). Its phi_d
    # dependence vanishes at theta_d = 0, as for any BRDF: phi_d is undefined there, and
    # float32 directions cannot resolve it (the numpy reference runs in float64).
    for n_p in hd.PHI_D_VARIANTS:
        th, td, pd = (
            a.reshape(s)
            for a, s in zip(
                hd.bin_centers(n_p), [(90, 1, 1, 1), (1, 90, 1, 1), (1, 1, n_p, 1)], strict=True
            )
        )
        rgb = (1.0 + 40.0 * np.exp(-th / 0.05)) * (1.0 + np.sin(td) * np.cos(pd) ** 2)
        rgb = rgb * np.array([0.3, 0.6, 0.9])
        rgb[rng.random(rgb.shape) < 0.05 / 3] = hd.MISSING
        wi, wo = hemisphere(rng, 100_000), hemisphere(rng, 100_000)
        got = brdf(mi, merl_bsdf(mi, MerlTable(rgb, n_p)), wi, wo)
        ref = hd.lookup(rgb, wi.astype(np.float64), wo.astype(np.float64), interpolate=True)
        ref = np.where(ref < 0, 0.0, ref)  # all corners missing: 0 in the BSDF (documented)
        rel = np.abs(got - ref) / np.maximum(np.abs(ref), 1e-6)
        print(
            f"\nP={n_p}: relative error median {np.median(rel):.2e}, "
            f"99.9 % {np.quantile(rel, 0.999):.2e}, max {rel.max():.2e}"
        )
        assert np.quantile(rel, 0.999) < 1e-5 and rel.max() < 1e-4
    # Below the horizon: 0, and all-missing bins: 0 (never negative).
    table = MerlTable(np.full((90, 90, 180, 3), hd.MISSING))
    wi = np.array([[0.0, 0.6, 0.8], [0.0, 0.6, -0.8]], np.float32)
    wo = np.array([[0.6, 0.0, 0.8], [0.6, 0.0, 0.8]], np.float32)
    assert np.all(
        brdf(mi, merl_bsdf(mi, table, fit_sampling_lobe(np.ones((90, 90, 180, 3)))), wi, wo) == 0.0
    )


def test02b_whole_bin_lookup_matches_numpy(mi: types.ModuleType) -> None:
    """The lookup path for tables whose bins are missing in all channels or none (MERL
    files, tabulations) == ``halfdiff.lookup(interpolate=True)``, the float64 numpy
    reference with its own (trigonometric) Rusinkiewicz angles, at random pairs, pairs
    near the specular peak and grazing pairs, to float32 precision."""
    rng = np.random.default_rng(17)
    th, td, pd = (
        a.reshape(s)
        for a, s in zip(
            hd.bin_centers(180), [(90, 1, 1, 1), (1, 90, 1, 1), (1, 1, 180, 1)], strict=True
        )
    )
    smooth = (1.0 + 40.0 * np.exp(-th / 0.05)) * (1.0 + np.sin(td) * np.cos(pd) ** 2)
    smooth = smooth * np.array([0.3, 0.6, 0.9])
    holes = smooth.copy()
    holes[rng.random(holes.shape[:3]) < 0.05] = hd.MISSING  # whole bins, all channels
    tabulated, _ = tabulate_mitsuba(AU_03)  # missing bins below the horizon, as rendered
    wi = np.concatenate([hemisphere(rng, 60_000), hemisphere(rng, 20_000, 89.0)])
    wo = np.concatenate([hemisphere(rng, 60_000), hemisphere(rng, 20_000, 89.0)])
    # Near-specular pairs, where the square-root theta_h bins are narrowest.
    mirror = wi[:20_000] * np.array([-1.0, -1.0, 1.0], np.float32)
    wo[:20_000] = mirror + rng.normal(scale=2e-3, size=(20_000, 3)).astype(np.float32)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    wo[:, 2] = np.abs(wo[:, 2])
    for label, rgb in (("no missing", smooth), ("5 % bins missing", holes), ("Au", tabulated.rgb)):
        bsdf = merl_bsdf(mi, MerlTable(rgb, 180))
        assert bsdf.whole_bins_missing  # the path under test
        got = brdf(mi, bsdf, wi, wo)
        ref = hd.lookup(rgb, wi.astype(np.float64), wo.astype(np.float64), interpolate=True)
        ref = np.where(ref < 0, 0.0, ref)  # all corners missing: 0 in the BSDF (documented)
        rel = np.abs(got - ref) / np.maximum(np.abs(ref), 1e-6 * max(ref.max(), 1e-30))
        print(
            f"\n{label}: relative error median {np.median(rel):.2e}, "
            f"99.9 % {np.quantile(rel, 0.999):.2e}, max {rel.max():.2e}"
        )
        assert np.quantile(rel, 0.999) < 1e-5 and rel.max() < 1e-4


@pytest.mark.parametrize("name", sorted(PLUGINS))
def test03_eval_matches_mitsuba(mi: types.ModuleType, tables: dict[str, Path], name: str) -> None:
    """The table BSDF of a tabulated Mitsuba material against Mitsuba's own eval."""
    rng = np.random.default_rng(11)
    wi, wo = hemisphere(rng, 50_000, 70.0), hemisphere(rng, 50_000, 70.0)
    got = brdf(mi, load(mi, tables[name]), wi, wo)
    ref = brdf(mi, mi.load_dict(PLUGINS[name]), wi, wo)
    rel = np.abs(got - ref) / np.maximum(np.abs(ref), 1e-3 * ref.max())
    print(
        f"\n{name}: relative error vs Mitsuba median {np.median(rel):.2e}, "
        f"95 % {np.quantile(rel, 0.95):.2e}, 99 % {np.quantile(rel, 0.99):.2e}"
    )
    assert np.median(rel) < 1.5e-3 and np.quantile(rel, 0.99) < 5e-3


def test04_fitted_lobe(tables: dict[str, Path]) -> None:
    """The fit recovers the roughness a GGX table was made with, and splits energy sanely."""
    from storage.formats.merl import read_merl

    metal = fit_sampling_lobe(read_merl(tables["conductor"]).rgb)
    plastic = fit_sampling_lobe(read_merl(tables["plastic"]).rgb)
    print(f"\nconductor {metal}\nplastic {plastic}")
    assert abs(metal.alpha - 0.3) < 0.02 and metal.specular_weight == 0.9
    assert metal.diffuse < 0.01 * metal.specular
    # roughplastic's substrate is not Lambertian (Fresnel-weighted, internal scattering): its
    # fitted lobe is a little wider, and the diffuse part takes most of the samples.
    assert 0.25 < plastic.alpha < 0.45 and 0.1 <= plastic.specular_weight < 0.4
    with pytest.raises(ValueError, match="too few valid bins"):
        fit_sampling_lobe(np.full((90, 90, 180, 3), hd.MISSING))


CHI2_CASES = [
    (name, deg, precision)
    for name in sorted(PLUGINS)
    for deg in (0, 30, 60)
    for precision in ("float32", "rgb9e5")
]


@pytest.mark.parametrize(
    ("name", "deg", "precision"), CHI2_CASES, ids=[f"{n}-{d}deg-{p}" for n, d, p in CHI2_CASES]
)
def test05_chi2(
    mi: types.ModuleType, tables: dict[str, Path], name: str, deg: int, precision: str
) -> None:
    """Mitsuba's chi-square test of ``sample`` against ``pdf`` (1 M samples, seed 0), with
    the exact table and with the smallest one (``rgb9e5``)."""
    from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain

    t = math.radians(deg)
    wi = mi.Vector3f(math.sin(t), 0.0, math.cos(t))
    xml = (
        f'<string name="filename" value="{tables[name]}"/>'
        f'<string name="precision" value="{precision}"/>'
    )
    sample_func, pdf_func = BSDFAdapter(MERL_BSDF_NAME, xml, wi=wi)
    chi2: Any = ChiSquareTest(
        domain=SphericalDomain(), sample_func=sample_func, pdf_func=pdf_func, sample_dim=3
    )
    ok = chi2.run(significance_level=0.01, test_count=len(CHI2_CASES), quiet=True)
    print(f"\nchi2 {name} at {deg} deg: p = {chi2.p_value:.3f}")
    assert ok, chi2.messages


@pytest.mark.parametrize("precision", ["float32", "rgb9e5"])
@pytest.mark.parametrize("name", sorted(PLUGINS))
def test06_pdf_and_sample_consistency(
    mi: types.ModuleType, tables: dict[str, Path], name: str, precision: str
) -> None:
    """pdf >= 0 on the whole sphere and integrates to <= 1; sample's pdf and weight agree
    with pdf and eval; eval_pdf is (eval, pdf)."""
    bsdf = load(mi, tables[name], f'<string name="precision" value="{precision}"/>')
    rng = np.random.default_rng(3)
    for deg in (0.0, 45.0, 80.0):
        integral, stderr, w = check_pdf_and_sampling(mi, bsdf, deg, 1 << 20, rng)
        print(
            f"\n{name} at {deg:.0f} deg: pdf integral {integral:.4f} +- {stderr:.4f}, "
            f"max sample weight {w.max():.3f}"
        )


def test07_metal_sampling_as_good_as_native(mi: types.ModuleType, tables: dict[str, Path]) -> None:
    """'Well enough for glossy metals to converge': the sample weights of the table BSDF
    (the one-sample albedo estimator) have at most 1.25x the variance of Mitsuba's native
    roughconductor sampling, and a small fraction of cosine sampling's; all three estimate
    the same albedo."""
    table_bsdf, native = load(mi, tables["conductor"]), mi.load_dict(AU_03)
    rng = np.random.default_rng(5)
    n = 1 << 20
    ctx = mi.BSDFContext()
    for deg in (0.0, 30.0, 60.0, 75.0):
        t = math.radians(deg)
        wi = np.tile(np.array([[math.sin(t), 0.0, math.cos(t)]], np.float32), (n, 1))
        si = interaction(mi, wi)
        u = rng.random((n, 3)).astype(np.float32)
        s1, s2 = mi.Float(u[:, 0]), mi.Vector2f(u[:, 1], u[:, 2])
        w_tab = np.asarray(table_bsdf.sample(ctx, si, s1, s2)[1], np.float64).mean(axis=0)
        w_nat = np.asarray(native.sample(ctx, si, s1, s2)[1], np.float64).mean(axis=0)
        wo = np.asarray(mi.warp.square_to_cosine_hemisphere(s2), np.float32).T
        w_cos = math.pi * brdf(mi, table_bsdf, wi, wo).mean(axis=1)
        ratio = w_tab.var() / w_nat.var()
        print(
            f"\nalbedo at {deg:.0f} deg: table {w_tab.mean():.4f}, native {w_nat.mean():.4f}, "
            f"cosine {w_cos.mean():.4f}; weight variance: table / native {ratio:.3f}, "
            f"table / cosine {w_tab.var() / w_cos.var():.3f}"
        )
        se = math.sqrt((w_tab.var() + w_nat.var()) / n)
        assert abs(w_tab.mean() - w_nat.mean()) < 5.0 * se + 2e-3 * w_nat.mean()
        assert abs(w_tab.mean() - w_cos.mean()) < 5.0 * w_cos.std() / math.sqrt(n)
        assert ratio < 1.25 and w_tab.var() < 0.3 * w_cos.var()
