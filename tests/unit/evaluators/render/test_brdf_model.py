"""The trained-model BSDF (``brdf_model``): fused evaluation, MIS sampling, analytic fallback.

Oracles, each independent of the code under test:

- :func:`models.brdf.portable.eval_portable`, the numpy reference of ``model.json``, for
  the fused Dr.Jit evaluation (hybrid, neural, analytic), to float32 precision;
- :mod:`materials.microfacet` (``specular_brdf`` with the exact real-IOR Fresnel), for the
  analytic fallback ``f_a`` under the ``ANALYTIC_ONLY`` context bit;
- Mitsuba's chi-square harness (:mod:`mitsuba.chi2`), for the consistency of ``sample``
  and ``pdf``; closed forms (pdf >= 0, pdf integrates to at most 1, weight = eval / pdf).

Models are written by :func:`models.brdf.portable.to_portable` from freshly initialised torch
models whose weights are perturbed (random but plausible: corrections of a few 0.01-0.1 /sr,
gates between 0.3 and 0.95) and whose materials get chosen ``kd``, ``eta``, ``alpha``.
Run with ``-s`` to see the measured numbers.
"""

from __future__ import annotations

import json
import math
import types
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from evaluators.render.bsdfs.brdf_model import (
    ANALYTIC_ONLY,
    MODEL_BSDF_NAME,
    register_model_bsdf,
)
from materials import microfacet as mf
from models.brdf.fused import bake_material
from tests.helpers.brdf_models import MATERIALS, make_model
from tests.helpers.mitsuba_probes import check_pdf_and_sampling, hemisphere, interaction


@pytest.fixture(scope="module")
def mi(mi: types.ModuleType) -> types.ModuleType:
    """The LLVM Mitsuba of tests/conftest.py, with this module's plugins registered."""
    mod = mi
    register_model_bsdf(mod)
    return mod


@pytest.fixture(scope="module")
def models(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("model_bsdf")
    docs = {
        "hybrid": make_model("hybrid", 16, 2, 4),
        "neural": make_model("neural", 16, 2, 11),
        "analytic": make_model("analytic", 0, 0, 0),
    }
    out = {}
    for kind, doc in docs.items():
        out[kind] = root / f"{kind}.json"
        out[kind].write_text(json.dumps(doc))
    return out


def load(mi: types.ModuleType, path: Path, material: str, **extra: Any) -> Any:
    return mi.load_dict(
        {"type": MODEL_BSDF_NAME, "filename": str(path), "material": material, **extra}
    )


def brdf(
    mi: types.ModuleType, bsdf: Any, wi: np.ndarray, wo: np.ndarray, ctx: Any = None
) -> np.ndarray:
    """``(N, 3)`` float64 ``eval / wo.z`` at float32 pairs."""
    ctx = ctx if ctx is not None else mi.BSDFContext()
    value = bsdf.eval(ctx, interaction(mi, wi), mi.Vector3f(*wo.T))
    cos_o = wo[:, 2:3].astype(np.float64)
    return np.asarray(value, np.float64).T / np.where(cos_o > 0, cos_o, np.inf)


def test01_create(mi: types.ModuleType, models: dict[str, Path]) -> None:
    assert register_model_bsdf(mi) is register_model_bsdf(mi)  # idempotent
    bsdf = load(mi, models["hybrid"], "gold")
    assert isinstance(bsdf, mi.BSDF) and bsdf.neural_max_depth is None
    assert "ModelBSDF[hybrid 'gold', alpha=0.25" in str(bsdf)
    assert bsdf.flags() & int(mi.BSDFFlags.GlossyReflection)
    assert load(mi, models["neural"], "gold").specular_weight == 0.0  # cosine sampling only
    assert load(mi, models["hybrid"], "plastic", neural_max_depth=1).neural_max_depth == 1
    with pytest.raises(Exception, match="no material 'steel' in the model; it has gold"):
        load(mi, models["hybrid"], "steel")
    with pytest.raises(Exception, match="'filename' and 'material' are required"):
        mi.load_dict({"type": MODEL_BSDF_NAME, "filename": str(models["hybrid"])})
    with pytest.raises(Exception, match="neural_max_depth needs a model with an analytic part"):
        load(mi, models["neural"], "gold", neural_max_depth=1)
    bad = models["hybrid"].with_name("bad.json")
    bad.write_text('{"format": "something/else"}')
    with pytest.raises(Exception, match="not a matforge.brdf-model/1 model document"):
        load(mi, bad, "gold")


@pytest.mark.parametrize("kind", ["hybrid", "neural", "analytic"])
def test02_eval_matches_portable(mi: types.ModuleType, models: dict[str, Path], kind: str) -> None:
    """Fused Dr.Jit ``eval / cos`` == ``eval_portable`` (numpy, float64) at random pairs."""
    from models.brdf.portable import eval_portable

    doc = json.loads(models[kind].read_text())
    rng = np.random.default_rng(7)
    wi, wo = hemisphere(rng, 50_000, 89.0), hemisphere(rng, 50_000, 89.0)
    worst = 0.0
    for name in MATERIALS:
        got = brdf(mi, load(mi, models[kind], name), wi, wo)
        ref = eval_portable(doc, name, wi.astype(np.float64), wo.astype(np.float64))
        rel = np.abs(got - ref) / np.maximum(np.abs(ref), 1e-3)
        worst = max(worst, float(np.quantile(rel, 0.999)))
        assert np.quantile(rel, 0.999) < 1e-5 and rel.max() < 1e-4, (name, rel.max())
    print(f"\n{kind}: relative error vs eval_portable, 99.9 % quantile {worst:.2e}")
    # Below the horizon (either side): exactly 0, and the network is not consulted.
    wi2 = np.array([[0.0, 0.6, 0.8], [0.0, 0.6, -0.8], [0.6, 0.0, 0.8]], np.float32)
    wo2 = np.array([[0.0, -0.6, -0.8], [0.6, 0.0, 0.8], [0.0, -0.6, 0.8]], np.float32)
    value = np.asarray(
        load(mi, models[kind], "gold").eval(
            mi.BSDFContext(), interaction(mi, wi2), mi.Vector3f(*wo2.T)
        )
    )
    assert np.all(value[:, :2] == 0.0) and np.all(value[:, 2] > 0.0)


def test03_analytic_fallback(mi: types.ModuleType, models: dict[str, Path]) -> None:
    """With ``ANALYTIC_ONLY`` the hybrid BSDF is Eq. 3 alone (``materials.microfacet``),
    sampling is unchanged."""
    rng = np.random.default_rng(9)
    wi, wo = hemisphere(rng, 20_000, 89.0), hemisphere(rng, 20_000, 89.0)
    kd, eta, alpha = MATERIALS["gold"]
    ref = np.asarray(kd) / math.pi + mf.specular_brdf(
        wi.astype(np.float64),
        wo.astype(np.float64),
        alpha,
        lambda c: mf.fresnel_conductor(c, np.asarray(eta), 0.0),
    )
    bsdf = load(mi, models["hybrid"], "gold")
    fallback = mi.BSDFContext()
    fallback.type_mask = fallback.type_mask | ANALYTIC_ONLY
    got = brdf(mi, bsdf, wi, wo, fallback)
    assert np.allclose(got, ref, rtol=2e-5, atol=1e-7)
    full = brdf(mi, bsdf, wi, wo)
    assert np.abs(full - got).mean() > 1e-3 * np.abs(got).mean()  # the network does something
    si = interaction(mi, wi)
    u = rng.random((len(wi), 3)).astype(np.float32)
    s1, s2 = mi.Float(u[:, 0]), mi.Vector2f(u[:, 1], u[:, 2])
    bs_full, _ = bsdf.sample(mi.BSDFContext(), si, s1, s2)
    bs_fall, _ = bsdf.sample(fallback, si, s1, s2)
    assert np.array_equal(np.asarray(bs_full.wo), np.asarray(bs_fall.wo))
    assert np.array_equal(np.asarray(bs_full.pdf), np.asarray(bs_fall.pdf))
    # neural_max_depth is only a hint for the integrator: the BSDF evaluates the same.
    hinted = load(mi, models["hybrid"], "gold", neural_max_depth=1)
    assert np.array_equal(brdf(mi, hinted, wi, wo), full)


CHI2_CASES = [
    ("hybrid", "gold", 0),
    ("hybrid", "plastic", 30),
    ("hybrid", "sharp", 60),
    ("neural", "plastic", 45),
]


@pytest.mark.parametrize(
    ("kind", "name", "deg"), CHI2_CASES, ids=[f"{k}-{n}-{d}deg" for k, n, d in CHI2_CASES]
)
def test04_chi2(
    mi: types.ModuleType, models: dict[str, Path], kind: str, name: str, deg: int
) -> None:
    """Mitsuba's chi-square test of ``sample`` against ``pdf`` (1 M samples, seed 0).

    ``ires=16`` (the harness's default is 4): the harness integrates the pdf over each
    cell with ``ires^2`` points, too few for GGX lobes below alpha ~ 0.15, where Mitsuba's
    native ``roughconductor`` fails too (alpha 0.1 at 60 deg: p = 0.0 with ires 4, 0.76
    with 16). Measured for ``sharp`` at 60 deg with 8 M samples: p = 0.09, 0.11, 0.74
    (seeds 0-2), so no discrepancy grows with the sample count."""
    from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain

    t = math.radians(deg)
    wi = mi.Vector3f(math.sin(t), 0.0, math.cos(t))
    xml = (
        f'<string name="filename" value="{models[kind]}"/><string name="material" value="{name}"/>'
    )
    sample_func, pdf_func = BSDFAdapter(MODEL_BSDF_NAME, xml, wi=wi)
    chi2: Any = ChiSquareTest(
        domain=SphericalDomain(),
        sample_func=sample_func,
        pdf_func=pdf_func,
        sample_dim=3,
        ires=16,
    )
    ok = chi2.run(significance_level=0.01, test_count=len(CHI2_CASES), quiet=True)
    print(f"\nchi2 {kind} {name} at {deg} deg: p = {chi2.p_value:.3f}")
    assert ok, chi2.messages


def test05_pdf_and_sample_consistency(mi: types.ModuleType, models: dict[str, Path]) -> None:
    """pdf >= 0 on the sphere and integrates to <= 1; sample's pdf and weight agree with
    pdf and eval; eval_pdf is (eval, pdf)."""
    rng = np.random.default_rng(3)
    for name, deg in (("gold", 0.0), ("sharp", 70.0)):
        bsdf = load(mi, models["hybrid"], name)
        integral, stderr, w = check_pdf_and_sampling(mi, bsdf, deg, 1 << 18, rng)
        print(
            f"\n{name} at {deg:.0f} deg: pdf integral {integral:.4f} +- {stderr:.4f}, "
            f"albedo {w.mean():.4f}, max sample weight {w.max():.3f}"
        )


def test06_bake_errors(models: dict[str, Path]) -> None:
    doc = json.loads(models["hybrid"].read_text())
    baked = bake_material(doc, "plastic")
    assert baked.model == "hybrid" and baked.alpha == 0.12 and len(baked.z) == 4
    assert 0.1 <= baked.specular_weight <= 0.9
    doc["architecture"]["output_heads"][0]["activation"] = "softplus"
    with pytest.raises(ValueError, match="unsupported output heads"):
        bake_material(doc, "plastic")
    del doc["network"]
    doc["architecture"]["output_heads"][0]["activation"] = "exp"
    with pytest.raises(ValueError, match="malformed model document"):
        bake_material(doc, "plastic")
