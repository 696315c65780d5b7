"""How the MERL table BSDF holds its table: precisions (float32, float16, rgb9e5) and layouts.

Oracles, each independent of the code under test:

- numpy's own IEEE half rounding (``astype(np.float16)``) and the shared-exponent decode
  written here from the OpenGL ``EXT_texture_shared_exponent`` formula
  (``value = mantissa * 2^(exponent - 15 - 9)``), then the float64 numpy reference lookup
  :func:`materials.halfdiff.lookup` over the rounded table: the Dr.Jit BSDF must equal it to
  float32 precision (the bounds of ``test_merl_table.py``), so decoding adds no error of its
  own;
- the float32 table itself, for the rounding bounds of each precision (a multilinear
  interpolation of values each within a relative ``e`` of the truth, with non-negative
  weights, is within ``e`` of the interpolated truth);
- Mitsuba's native BSDF rendered on ``sphere_env``, for HDR-FLIP (below 0.06, as asked of
  the table BSDF) and for the image mean.

Run with ``-s`` to see the measured numbers.
"""

from __future__ import annotations

import types
from typing import Any

import numpy as np
import pytest

from evaluators.metrics.images import flip
from evaluators.render.bsdfs.merl_table import (
    MERL_BSDF_NAME,
    RGB9E5_MISSING,
    encode_rgb9e5,
    merl_bsdf,
    register_merl_bsdf,
)
from evaluators.render.kind import render_passes
from evaluators.render.scenes import SceneSetup, build_scene
from materials import halfdiff as hd
from materials.lobe_fit import fit_sampling_lobe
from materials.tabulate import tabulate_mitsuba
from storage.formats.merl import MerlTable
from tests.helpers.mitsuba_probes import AU_03, PLASTIC_03, hemisphere, interaction


@pytest.fixture(scope="module")
def mi(mi: types.ModuleType) -> types.ModuleType:
    register_merl_bsdf(mi)
    return mi


@pytest.fixture(scope="module")
def au() -> MerlTable:
    """The tabulated GGX gold conductor (missing bins below the horizon, as rendered)."""
    table, _ = tabulate_mitsuba(AU_03)
    return table


def brdf(mi: types.ModuleType, bsdf: Any, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """``(N, 3)`` float64 ``eval / wo.z`` at float32 pairs."""
    value = bsdf.eval(mi.BSDFContext(), interaction(mi, wi), mi.Vector3f(*wo.T))
    cos_o = wo[:, 2:3].astype(np.float64)
    return np.asarray(value, np.float64).T / np.where(cos_o > 0, cos_o, np.inf)


def decode_rgb9e5(words: np.ndarray) -> np.ndarray:
    """The EXT_texture_shared_exponent decode, in float64; the missing word gives -1."""
    w = words.astype(np.int64)
    scale = 2.0 ** ((w >> 27) - 15 - 9)
    rgb = np.stack([(w & 0x1FF), (w >> 9) & 0x1FF, (w >> 18) & 0x1FF], axis=1) * scale[:, None]
    return np.where((words == RGB9E5_MISSING)[:, None], -1.0, rgb)


def pairs(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Random pairs, grazing pairs and near-specular pairs (the narrow theta_h bins)."""
    wi = np.concatenate([hemisphere(rng, 40_000), hemisphere(rng, 10_000, 89.0)])
    wo = np.concatenate([hemisphere(rng, 40_000), hemisphere(rng, 10_000, 89.0)])
    mirror = wi[:10_000] * np.array([-1.0, -1.0, 1.0], np.float32)
    wo[:10_000] = mirror + rng.normal(scale=2e-3, size=(10_000, 3)).astype(np.float32)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    wo[:, 2] = np.abs(wo[:, 2])
    return wi, wo


def smooth_table(rng: np.random.Generator, missing: float) -> np.ndarray:
    th, td, pd = (
        a.reshape(s)
        for a, s in zip(
            hd.bin_centers(180), [(90, 1, 1, 1), (1, 90, 1, 1), (1, 1, 180, 1)], strict=True
        )
    )
    rgb = (1.0 + 40.0 * np.exp(-th / 0.05)) * (1.0 + np.sin(td) * np.cos(pd) ** 2)
    rgb = rgb * np.array([0.3, 0.6, 0.9])
    rgb[rng.random(rgb.shape[:3]) < missing] = hd.MISSING  # whole bins, all channels
    return rgb


def test01_encode_rgb9e5_round_trip() -> None:
    """Shared-exponent words decode (by the formula, not by the BSDF) to within half a unit
    of the shared scale, and the largest channel to within 2^-9 relative; missing bins
    become the missing word; zero stays zero."""
    rng = np.random.default_rng(3)
    rgb = np.exp(rng.uniform(-12.0, 9.0, (200_000, 1))) * rng.uniform(0.0, 1.0, (200_000, 3))
    rgb[:1000] = 0.0
    rgb[1000:2000, 1] = -1.0
    words = encode_rgb9e5(rgb)
    assert words.dtype == np.uint32
    back = decode_rgb9e5(words)
    assert np.all(words[1000:2000] == RGB9E5_MISSING) and np.all(back[1000:2000] == -1.0)
    assert np.all(back[:1000] == 0.0)
    ok = np.ones(len(rgb), bool)
    ok[:2000] = False
    scale = 2.0 ** ((words[ok].astype(np.int64) >> 27) - 24)
    err = np.abs(back[ok] - rgb[ok])
    assert np.all(err <= 0.5 * scale[:, None] * (1 + 1e-12))
    peak = rgb[ok].max(axis=1)
    rel = np.abs(back[ok].max(axis=1) - peak) / peak
    normal = peak > 2.0**-15  # below, the exponent is at its floor and precision drops
    print(f"\nlargest channel: relative error max {rel[normal].max():.2e} (bound 2^-9)")
    assert rel[normal].max() <= 2.0**-9


@pytest.mark.parametrize("precision", ["float16", "rgb9e5"])
def test02_decoded_lookup_matches_numpy_of_rounded_table(
    mi: types.ModuleType, au: MerlTable, precision: str
) -> None:
    """The BSDF at ``precision`` == the float64 numpy lookup over the table rounded by an
    independent encoder/decoder, to float32 precision: decoding in Dr.Jit adds nothing."""
    rng = np.random.default_rng(11)
    wi, wo = pairs(rng)
    for label, rgb in (("smooth, 5 % missing", smooth_table(rng, 0.05)), ("Au", au.rgb)):
        # The BSDF rounds the float32 table it holds (float64 -> float32 -> float16 can
        # differ from float64 -> float16 by a half unit, at ties), so the reference does too.
        single = rgb.astype(np.float32)
        if precision == "float16":
            rounded = single.astype(np.float16).astype(np.float64)
        else:
            rounded = decode_rgb9e5(encode_rgb9e5(single.reshape(-1, 3))).reshape(rgb.shape)
        for layout in ("phi_d", "theta_h"):
            bsdf = merl_bsdf(mi, MerlTable(rgb, 180), precision=precision, layout=layout)
            got = brdf(mi, bsdf, wi, wo)
            ref = hd.lookup(rounded, wi.astype(np.float64), wo.astype(np.float64), interpolate=True)
            ref = np.where(ref < 0, 0.0, ref)
            rel = np.abs(got - ref) / np.maximum(np.abs(ref), 1e-6 * ref.max())
            print(
                f"\n{precision} {layout} {label}: vs numpy of the rounded table: median "
                f"{np.median(rel):.2e}, 99.9 % {np.quantile(rel, 0.999):.2e}, max {rel.max():.2e}"
            )
            assert np.quantile(rel, 0.999) < 1e-5 and rel.max() < 1e-4


def test03_rounding_bounds_against_float32(mi: types.ModuleType, au: MerlTable) -> None:
    """Against the exact (float32) table: float16 within 2^-11 relative per channel (plus
    float32 rounding), rgb9e5 within 2^-9 of the largest channel; the theta_h-fastest
    layout gives the float32 table's values (same arithmetic on the same numbers; only the
    addresses differ, so agreement is to the last bit)."""
    rng = np.random.default_rng(5)
    wi, wo = pairs(rng)
    lobe = fit_sampling_lobe(au.rgb)
    exact = brdf(mi, merl_bsdf(mi, au, lobe), wi, wo)
    np.testing.assert_array_equal(
        brdf(mi, merl_bsdf(mi, au, lobe, layout="theta_h"), wi, wo), exact
    )
    half = brdf(mi, merl_bsdf(mi, au, lobe, precision="float16"), wi, wo)
    floor = 1e-6 * exact.max()
    rel = np.abs(half - exact) / np.maximum(exact, floor)
    print(f"\nfloat16 vs float32: max relative {rel.max():.2e} (bound 2^-11 = {2.0**-11:.2e})")
    assert rel.max() <= 2.0**-11 + 1e-5
    shared = brdf(mi, merl_bsdf(mi, au, lobe, precision="rgb9e5"), wi, wo)
    rel = np.abs(shared - exact).max(axis=1) / np.maximum(exact.max(axis=1), floor)
    print(f"rgb9e5 vs float32: max relative to the largest channel {rel.max():.2e}")
    assert rel.max() <= 2.0**-9 + 1e-5


def test04_bad_options(mi: types.ModuleType) -> None:
    """Unknown precisions and layouts, and rgb9e5 on a table with bins missing in some
    channels only, are refused by name."""
    rgb = np.ones((90, 90, 180, 3))
    with pytest.raises(Exception, match="precision must be one of"):
        merl_bsdf(mi, MerlTable(rgb), precision="float8")
    with pytest.raises(Exception, match="layout must be one of"):
        merl_bsdf(mi, MerlTable(rgb), layout="theta_d")
    rgb[3, 4, 5, 1] = hd.MISSING
    with pytest.raises(Exception, match="rgb9e5.*missing in some channels"):
        merl_bsdf(mi, MerlTable(rgb), precision="rgb9e5")
    # Through the plugin's own parameters, as a scene file gives them.
    bsdf = mi.load_dict(
        {
            "type": MERL_BSDF_NAME,
            "data": mi.TensorXf(np.ones((90, 90, 180, 3))),
            "precision": "rgb9e5",
            "layout": "theta_h",
        }
    )
    assert bsdf.precision == "rgb9e5" and bsdf.layout == "theta_h"


@pytest.mark.parametrize("name", ["conductor", "plastic"])
def test05_renders_like_native(mi: types.ModuleType, name: str) -> None:
    """``sphere_env`` with the table BSDF at each precision against Mitsuba's native BSDF
    (another seed): HDR-FLIP below 0.06 and the image mean within 1 %; the small tables
    differ from the float32 table at the same seed by far less than native vs native noise."""
    plugin = {"conductor": AU_03, "plastic": PLASTIC_03}[name]
    table, _ = tabulate_mitsuba(plugin)
    lobe = fit_sampling_lobe(table.rgb)
    setup = SceneSetup(resolution=(128, 128), spp=256, max_depth=8)

    def render(bsdf: Any, seed: int) -> np.ndarray:
        scene = mi.load_dict(build_scene("sphere_env", mi, bsdf, setup))
        return np.asarray(render_passes(mi, scene, [256], [seed]), np.float64)

    native = render(mi.load_dict(plugin), 1)
    native2 = render(mi.load_dict(plugin), 2)
    noise, _ = flip(native, native2)
    images = {
        p: render(merl_bsdf(mi, table, lobe, precision=p), 2)
        for p in ("float32", "float16", "rgb9e5")
    }
    print(f"\n{name}: native vs native (seeds 1, 2) HDR-FLIP {noise:.4f}")
    for p, image in images.items():
        err, _ = flip(native, image)
        same_seed, _ = flip(images["float32"], image)
        ratio = image.mean() / native.mean()
        print(
            f"{name} {p}: HDR-FLIP vs native {err:.4f}, vs float32 table (same seed) "
            f"{same_seed:.4f}, mean ratio {ratio:.4f}"
        )
        assert err < 0.06
        assert abs(ratio - 1.0) < 0.01
        assert same_seed < 0.25 * noise
