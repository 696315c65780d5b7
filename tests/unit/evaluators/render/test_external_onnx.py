"""The ``external_onnx`` BSDF: a user's ONNX model evaluated by onnxruntime inside the render,
in Dr.Jit's evaluated (wavefront) mode.

Oracles, each independent of the code under test:

- Mitsuba's native ``diffuse`` BSDF of the same albedo, for Lambertian models written as
  ONNX graphs with ``onnx.helper`` (:mod:`tests.helpers.onnx_models`): a BTF
  ``albedo / pi * cos(theta_i)`` (``generate.btf``'s convention, foreshortening of the
  light included) on the textured plane, and a BRDF ``albedo / pi`` on the sphere. Both
  BSDFs sample the cosine lobe from the same random numbers, so the images agree to float32
  rounding, not only within Monte Carlo noise;
- the closed form ``eval = albedo / pi * cos(theta_o)``, ``pdf = cos(theta_o) / pi`` for
  direct calls.
"""

from __future__ import annotations

import types
from pathlib import Path

import numpy as np
import pytest

from evaluators.render.bsdfs.external_onnx import (
    external_onnx_plugin,
    onnx_bsdfs_alive,
    wavefront_scope,
)
from evaluators.render.kind import render_passes
from evaluators.render.scenes import SceneSetup, build_scene
from models.external.onnx_model import load_onnx
from storage.errors import FormatError
from tests.helpers.onnx_models import ALBEDO, lambert_model, save

DIFFUSE = {"type": "diffuse", "reflectance": {"type": "rgb", "value": list(ALBEDO)}}


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("onnx")
    return {k: save(lambert_model(k), d / f"lambert_{k}.onnx") for k in ("brdf", "btf")}


def _render(mi: types.ModuleType, scene: str, bsdf: object, spp: int = 16) -> np.ndarray:
    setup = SceneSetup(resolution=(48, 48), spp=spp, max_depth=3)
    sc = mi.load_dict(build_scene(scene, mi, bsdf, setup))
    return render_passes(mi, sc, [spp], [7])


def test01_model_eval_and_cost_fields(files: dict[str, Path]) -> None:
    m = load_onnx(files["btf"], "btf")
    assert (m.kind, m.runtime) == ("btf", "onnxruntime")
    assert m.param_bytes == 3 * 4  # the 1x3 albedo (the int64 slice bounds are no parameters)
    rng = np.random.default_rng(0)
    wi = rng.normal(size=(1000, 3)).astype(np.float32)
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    out = m.eval(wi, wi, uv=np.zeros((1000, 2), np.float32))
    ref = np.asarray(ALBEDO, np.float32) / np.float32(np.pi) * wi[:, 2:3]
    np.testing.assert_allclose(out, ref, rtol=1e-6, atol=1e-7)
    assert out.dtype == np.float32 and m.stats.rows == 1000
    with pytest.raises(ValueError, match="needs uv"):
        m.eval(wi, wi)
    with pytest.raises(FormatError, match="declared kind .brdf. needs inputs"):
        load_onnx(files["btf"], "brdf")


@pytest.mark.parametrize(("kind", "scene"), [("btf", "plane_points"), ("brdf", "sphere_env")])
def test02_lambertian_renders_as_mitsuba_diffuse(
    mi: types.ModuleType, files: dict[str, Path], kind: str, scene: str
) -> None:
    import drjit as dr

    ref = _render(mi, scene, DIFFUSE)
    bsdf = external_onnx_plugin(files[kind], {"kind": kind}, None, mi)
    img = _render(mi, scene, bsdf)
    assert ref.mean() > 0.05
    np.testing.assert_allclose(img, ref, rtol=1e-4, atol=1e-5)
    # The evaluated mode was scoped to the render: symbolic again afterwards.
    assert dr.flag(dr.JitFlag.SymbolicLoops) and dr.flag(dr.JitFlag.SymbolicCalls)


def test03_direct_eval_pdf_sample(mi: types.ModuleType, files: dict[str, Path]) -> None:
    import drjit as dr

    bsdf = mi.load_dict(external_onnx_plugin(files["brdf"], {"kind": "brdf"}, None, mi))
    si = dr.zeros(mi.SurfaceInteraction3f)
    si.wi = mi.Vector3f(0.0, 0.6, 0.8)
    wo = mi.Vector3f([0.0, 0.3, 0.0], [0.0, 0.0, 0.6], [1.0, -0.954, 0.8])
    wo = dr.normalize(wo)
    ctx = mi.BSDFContext()
    value = np.asarray(bsdf.eval(ctx, si, wo).numpy()).T
    pdf = np.asarray(bsdf.pdf(ctx, si, wo).numpy())
    cos_o = np.maximum(np.asarray(wo.z.numpy()), 0.0)
    expect = np.asarray(ALBEDO) / np.pi * cos_o[:, None]
    np.testing.assert_allclose(value, expect, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(pdf, cos_o / np.pi, rtol=1e-6, atol=1e-8)
    bs, weight = bsdf.sample(ctx, si, mi.Float(0.5), mi.Point2f(0.3, 0.7))
    np.testing.assert_allclose(np.asarray(weight.numpy()).ravel(), ALBEDO, rtol=1e-5)


def test04_scope_follows_live_onnx_bsdfs(mi: types.ModuleType, files: dict[str, Path]) -> None:
    import gc

    import drjit as dr

    bsdf = mi.load_dict(external_onnx_plugin(files["btf"], {"kind": "btf"}, None, mi))
    assert onnx_bsdfs_alive()
    with wavefront_scope() as on:
        assert on and not dr.flag(dr.JitFlag.SymbolicLoops)
    assert dr.flag(dr.JitFlag.SymbolicLoops)
    # Traced symbolically (outside the scope), the BSDF cannot call out: 0, and counted.
    impl = bsdf
    before = impl.symbolic_calls
    diffuse = mi.load_dict(DIFFUSE)
    img = _render_without_scope(mi, diffuse)
    assert img.mean() > 0.05  # the other material's render is unharmed
    assert impl.symbolic_calls > before
    del bsdf, impl
    gc.collect()
    assert not onnx_bsdfs_alive()
    with wavefront_scope() as on:
        assert not on


def _render_without_scope(mi: types.ModuleType, bsdf: object) -> np.ndarray:
    setup = SceneSetup(resolution=(16, 16), spp=4, max_depth=3)
    sc = mi.load_dict(build_scene("sphere_env", mi, bsdf, setup))
    return np.asarray(mi.render(sc, spp=4, seed=1))


def test05_bad_kind_and_file(mi: types.ModuleType, files: dict[str, Path], tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="kind must be 'brdf' or 'btf'"):
        external_onnx_plugin(files["btf"], {"kind": "fabric"}, None, mi)
    bad = tmp_path / "cut.onnx"
    bad.write_bytes(files["btf"].read_bytes()[:20])
    with pytest.raises(ValueError, match="^cut.onnx: "):
        external_onnx_plugin(bad, {"kind": "btf"}, None, mi)
    # The declared kind is checked against the file, naming the model's reference.
    with pytest.raises(
        ValueError, match=r"^sha256:ab: declared kind 'brdf' needs inputs \(wi, wo\)"
    ):
        external_onnx_plugin(files["btf"], {"kind": "brdf", "model": "sha256:ab"}, None, mi)
    # A file that goes bad after the dict was made fails at load, naming it.
    gone = tmp_path / "gone.onnx"
    gone.write_bytes(files["btf"].read_bytes())
    spec = external_onnx_plugin(gone, {"kind": "btf"}, None, mi)
    gone.write_bytes(b"")
    with pytest.raises(Exception, match="gone.onnx: empty file"):
        mi.load_dict(spec)
