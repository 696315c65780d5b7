"""``sampling="pndf"``: the glint BSDF draws from the footprint's P-NDF itself.

Oracles:

- Mitsuba's chi-square harness (:mod:`mitsuba.chi2`, via
  :func:`tests.helpers.mitsuba_probes.direction_chi2`) for the directions ``sample`` draws
  against ``pdf``, on both paths of the tiny example (its lobes below the finest tile, its
  maps' tiles above) and on Yan's lobes;
- unbiasedness: the mean sample weight (a Monte Carlo estimate of the albedo) of the new
  sampler equals that of the GGX mixture within 4 combined standard errors;
- the weight spread (coefficient of variation of ``f cos / pdf``) falls: the figures are in
  BENCHMARKS.md.
"""

from __future__ import annotations

import math
import types
from typing import Any

import numpy as np
import pytest

from evaluators.render.bsdfs.glint import (
    GLINT_BSDF_NAME,
    GlintLayer,
    put_layers,
    register_glint_bsdf,
)
from materials.glints.examples import procedural_example
from materials.glints.footprint import TinyExample
from materials.glints.lobes import make_lobes
from materials.glints.ndf_maps import auto_extent, ndf_maps
from materials.glints.pndf_drjit import jit_lobes, jit_map_sampler, jit_maps
from materials.glints.surface import Transform
from materials.microfacet import NAMED_CONDUCTORS
from tests.helpers.mitsuba_probes import direction_chi2

TEXELS_PER_UV = 64.0
TRANSFORM = Transform.compose(rotation_deg=25.0, scale=(1.1, 0.9))
WI = (math.sin(0.5), 0.0, math.cos(0.5))


@pytest.fixture(scope="module")
def example() -> TinyExample:
    normals = procedural_example("anisotropic_noise", 16, np.random.default_rng(9))
    lobes = make_lobes(normals, rate=2, sigma_r=0.03)
    e = auto_extent(lobes)
    return TinyExample(lobes, ndf_maps(lobes, 48, e), e)


def _plugin(mi: types.ModuleType, ex: TinyExample, method: str, sampling: str) -> dict[str, Any]:
    register_glint_bsdf(mi)
    eta, k = NAMED_CONDUCTORS["Al"]
    layer = GlintLayer(
        method=method,
        lobes=jit_lobes(mi, ex.lobes),
        maps=jit_maps(mi, ex.maps, ex.extent) if method == "tiny_example" else None,
        transform=(TRANSFORM.a, TRANSFORM.offset)
        if method == "tiny_example"
        else (np.eye(2), np.zeros(2)),
        texel_scale=1.0,
        fresnel=("conductor", eta, k),
        alpha=0.3,
        fallback_texels=16.0,
        sampling=sampling,
        sampler=jit_map_sampler(mi, ex.maps, ex.extent) if method == "tiny_example" else None,
    )
    key = put_layers(f"test-sampling-{method}-{sampling}", layer)
    return {"type": GLINT_BSDF_NAME, "layers": key, "texels_per_uv": TEXELS_PER_UV}


def _duv(d: float) -> tuple[tuple[float, float], tuple[float, float]]:
    return ((d, 0.0), (0.0, d))


# duv 0.02: a 0.64-texel footprint (the lobes); 0.3: 9.6 texels (the maps' tiles).
CASES = [("tiny_example", 0.02), ("tiny_example", 0.3), ("yan", 0.02)]


@pytest.mark.parametrize(("method", "duv"), CASES)
def test01_chi2_pndf_sampling(
    mi: types.ModuleType, example: TinyExample, method: str, duv: float
) -> None:
    """The directions drawn follow ``pdf`` (Sidak-corrected over the three cases)."""
    plugin = _plugin(mi, example, method, "pndf")
    ok, p, messages = direction_chi2(mi, plugin, WI, duv=_duv(duv), test_count=len(CASES))
    assert ok, (p, messages)


def _weights(
    mi: types.ModuleType, plugin: dict[str, Any], duv: float, n: int, seed: int
) -> np.ndarray:
    import drjit as dr

    bsdf = mi.load_dict(plugin)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(*WI)
    si.uv = mi.Point2f(0.37, 0.61)
    si.duv_dx = mi.Vector2f(duv, 0.0)
    si.duv_dy = mi.Vector2f(0.0, duv)
    rng = np.random.default_rng(seed)
    u = rng.random((n, 3)).astype(np.float32)
    _, w = bsdf.sample(mi.BSDFContext(), si, mi.Float(u[:, 0]), mi.Point2f(u[:, 1], u[:, 2]))
    return np.asarray(w.numpy())[1]  # the green channel (w is (3, n))


def weight_stats(mi: types.ModuleType, ex: TinyExample, method: str, sampling: str, duv: float,
                 n: int = 200_000, seed: int = 0) -> tuple[float, float, float]:  # fmt: skip
    """``(mean, standard error, coefficient of variation)`` of the green channel's sample
    weight ``f cos / pdf`` over ``n`` draws."""
    w = _weights(mi, _plugin(mi, ex, method, sampling), duv, n, seed)
    mean = float(w.mean())
    return mean, float(w.std() / math.sqrt(n)), float(w.std() / max(mean, 1e-30))


@pytest.mark.parametrize(("method", "duv"), CASES)
def test02_unbiased_and_less_spread(
    mi: types.ModuleType, example: TinyExample, method: str, duv: float
) -> None:
    """Both samplers estimate the same albedo (4 combined standard errors), and the P-NDF
    sampler's weights spread less: its coefficient of variation is under half the mixture's."""
    m0, e0, cv0 = weight_stats(mi, example, method, "ggx_mix", duv, seed=1)
    m1, e1, cv1 = weight_stats(mi, example, method, "pndf", duv, seed=2)
    assert abs(m0 - m1) < 4.0 * math.hypot(e0, e1), (m0, e0, m1, e1)
    assert cv1 < 0.5 * cv0, (cv0, cv1)


class _NoSources:
    """A row source that knows no jobs (the layer's bytes come out unknown)."""

    def source(self, ref: str) -> None:
        return None


def test03_rows_name_non_default_lookup_and_sampling() -> None:
    """Result rows carry ``lookup`` and ``sampling`` only where they differ from the
    defaults, so rows of older renders keep their config."""
    from evaluators.render.sources.glint import glint_row_facts

    def facts(glint: dict[str, str]) -> dict[str, object]:
        return glint_row_facts(_NoSources(), {"glint": glint}).config  # type: ignore[arg-type]

    old = facts({"data": "job:x"})
    assert "lookup" not in old and "sampling" not in old
    same = facts({"data": "job:x", "lookup": "flat"})
    assert same == old
    new = facts({"data": "job:x", "lookup": "paper", "sampling": "pndf"})
    assert new["lookup"] == "paper" and new["sampling"] == "pndf"
