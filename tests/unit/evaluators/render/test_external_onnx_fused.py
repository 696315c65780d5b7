"""The ``external_onnx`` BSDF of a graph that is an MLP: traced into the render kernel
(:mod:`models.external.onnx_mlp`), not run in onnxruntime.

Oracles: Mitsuba's native ``diffuse`` BSDF for the Lambertian graphs of
:mod:`tests.helpers.onnx_models` (written with ``onnx.helper``; both BSDFs sample the
cosine lobe from the same random numbers, so the images agree to float32 rounding); and the
same weights as a ``matforge.mlp-brdf/1`` document rendered by ``external_mlp``: the same
cosine sampling and the same dense kernel, so the images agree to float32 rounding of the
differently ordered sums (the onnxruntime-vs-fused tolerance of
``tests/unit/models/external/test_onnx_mlp.py``, ~1e-5 relative, times a render's averaging).
"""

from __future__ import annotations

import json
import types
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from evaluators.render.bsdfs.external_mlp import EXTERNAL_MLP_NAME, register_external_mlp_bsdf
from evaluators.render.bsdfs.external_onnx import external_onnx_plugin, onnx_bsdfs_alive
from evaluators.render.kind import render_passes
from evaluators.render.scenes import SceneSetup, build_scene
from models.fused_mlp import random_layers, torch_mlp
from tests.helpers.onnx_models import ALBEDO, lambert_model, save

DIFFUSE = {"type": "diffuse", "reflectance": {"type": "rgb", "value": list(ALBEDO)}}


def _render(mi: types.ModuleType, scene: str, bsdf: object, spp: int = 16) -> np.ndarray:
    setup = SceneSetup(resolution=(48, 48), spp=spp, max_depth=3)
    sc = mi.load_dict(build_scene(scene, mi, bsdf, setup))
    return render_passes(mi, sc, [spp], [7])


@pytest.mark.parametrize(("kind", "scene"), [("btf", "plane_points"), ("brdf", "sphere_env")])
def test01_fused_lambertian_renders_as_mitsuba_diffuse(
    mi: types.ModuleType, tmp_path: Path, kind: str, scene: str
) -> None:
    import drjit as dr

    path = save(lambert_model(kind, opaque=False), tmp_path / f"lambert_{kind}.onnx")
    ref = _render(mi, scene, DIFFUSE)
    bsdf = mi.load_dict(external_onnx_plugin(path, {"kind": kind}, None, mi))
    assert type(bsdf).__name__.startswith("OnnxFused")
    assert not onnx_bsdfs_alive()  # nothing asks for the evaluated (wavefront) mode
    img = _render(mi, scene, bsdf)
    assert ref.mean() > 0.05
    np.testing.assert_allclose(img, ref, rtol=1e-4, atol=1e-5)
    assert dr.flag(dr.JitFlag.SymbolicLoops)


def test02_onnx_mlp_renders_as_the_same_weights_in_json(
    mi: types.ModuleType, tmp_path: Path
) -> None:
    """An MLP exported with :func:`matforge.export_onnx.brdf_onnx` and the same weights as
    an MLP document give the same image (and the ONNX BSDF is the fused one)."""
    import torch

    from matforge.export_onnx import brdf_onnx

    layers = random_layers(np.random.default_rng(4), 6, 16, 2, 3, last="softplus")

    class Brdf(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.mlp = torch_mlp(layers)

        def forward(self, wi: Any, wo: Any) -> Any:
            return self.mlp(torch.cat([wi, wo], dim=1))

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        onnx_path = brdf_onnx(Brdf(), tmp_path / "mlp.onnx")
    doc = {
        "format": "matforge.mlp-brdf/1",
        "inputs": ["wi", "wo"],
        "layers": [{"weight": ly.weight.tolist(), "bias": ly.bias.tolist(),
                    "activation": ly.activation} for ly in layers],
        "output": {"combine": "network", "activation": "identity"},
    }  # fmt: skip
    json_path = tmp_path / "mlp.json"
    json_path.write_text(json.dumps(doc))
    register_external_mlp_bsdf(mi)
    ref = _render(mi, "sphere_env", {"type": EXTERNAL_MLP_NAME, "filename": str(json_path)})
    bsdf = mi.load_dict(external_onnx_plugin(onnx_path, {"kind": "brdf"}, None, mi))
    assert type(bsdf).__name__ == "OnnxFusedBrdf"
    img = _render(mi, "sphere_env", bsdf)
    assert ref.mean() > 0.01
    np.testing.assert_allclose(img, ref, rtol=1e-4, atol=1e-5)
    forced = external_onnx_plugin(onnx_path, {"kind": "brdf", "runtime": "onnxruntime"}, None, mi)
    assert type(mi.load_dict(forced)).__name__ == "OnnxBrdf"


def test03_evaluate_tss_and_score_take_the_fused_kernel(
    mi: types.ModuleType, tmp_path: Path
) -> None:
    """``evaluate.tss``'s plane model and ``score``'s candidate of a recognised ONNX BTF are
    the fused kernel (runtime ``drjit-fused``), equal to the Lambertian closed form
    ``albedo / pi * wi.z``; an opaque graph stays in onnxruntime in both."""
    from evaluators.score.external import open_external
    from evaluators.tss.external import ExternalPlaneModel, OnnxPlaneModel, load_external_btf

    plain = save(lambert_model("btf", opaque=False), tmp_path / "plain.onnx")
    opaque = save(lambert_model("btf"), tmp_path / "opaque.onnx")

    class Ctx:
        def __init__(self, path: Path) -> None:
            self.path = path

        def resolve(self, ref: str) -> Path:
            return self.path

    value = {"model": "sha256:" + "0" * 64, "kind": "btf"}
    plane = load_external_btf(value, Ctx(plain), mi)  # type: ignore[arg-type]
    assert isinstance(plane, ExternalPlaneModel) and plane.runtime == "drjit-fused"
    assert plane.resolution == (32, 32)
    rng = np.random.default_rng(2)
    wi = rng.normal(size=(500, 3))
    wi[:, 2] = np.abs(wi[:, 2])
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    uv = rng.random((500, 2))
    out = plane.eval(mi.Point2f(*uv.T), mi.Vector3f(*wi.T), mi.Vector3f(*wi.T))
    expect = np.asarray(ALBEDO) / np.pi * wi[:, 2:3]
    np.testing.assert_allclose(np.asarray(out.numpy()).T, expect, rtol=1e-6, atol=1e-8)
    other = load_external_btf(value, Ctx(opaque), mi)  # type: ignore[arg-type]
    assert isinstance(other, OnnxPlaneModel) and other.runtime == "onnxruntime"
    assert open_external(plain, "plain", "btf").runtime == "drjit-fused"
    assert open_external(opaque, "opaque", "btf").runtime == "onnxruntime"


def test04_runtime_onnxruntime_is_asked_for_per_material(
    mi: types.ModuleType, tmp_path: Path
) -> None:
    """``{"external": {..., "runtime": "onnxruntime"}}`` runs a recognised graph in
    onnxruntime (render, score, evaluate.tss), labelled so; an MLP file refuses it, naming
    the field."""
    from pydantic import TypeAdapter

    from evaluators.render.sources import MaterialParam, resolve_material
    from evaluators.score.external import open_external
    from evaluators.tss.external import OnnxPlaneModel, load_external_btf
    from jobapi.errors import JobFailed
    from models.external import load_external

    plain = save(lambert_model("brdf", opaque=False), tmp_path / "plain.onnx")
    btf = save(lambert_model("btf", opaque=False), tmp_path / "plain_btf.onnx")
    ref = "sha256:" + "0" * 64

    class Ctx:
        def __init__(self, path: Path) -> None:
            self.path = path

        def resolve(self, ref: str) -> Path:
            return self.path

    def bsdf_of(path: Path, **extra: Any) -> Any:
        spec = {"external": {"model": ref, "kind": "brdf", **extra}}
        material = TypeAdapter(MaterialParam).validate_python(spec)
        return resolve_material(material, Ctx(path), mi)  # type: ignore[arg-type]

    assert type(bsdf_of(plain)).__name__ == "OnnxFusedBrdf"
    assert type(bsdf_of(plain, runtime="auto")).__name__ == "OnnxFusedBrdf"
    assert type(bsdf_of(plain, runtime="onnxruntime")).__name__ == "OnnxBrdf"
    assert open_external(plain, "p", "brdf", "onnxruntime").runtime == "onnxruntime"
    value = {"model": ref, "kind": "btf", "runtime": "onnxruntime"}
    plane = load_external_btf(value, Ctx(btf), mi)  # type: ignore[arg-type]
    assert isinstance(plane, OnnxPlaneModel) and plane.runtime == "onnxruntime"
    mlp = tmp_path / "m.json"
    mlp.write_text(json.dumps({
        "format": "matforge.mlp-brdf/1", "inputs": ["wi", "wo"],
        "layers": [{"weight": [[0.1] * 6] * 3, "bias": [0.0] * 3, "activation": "identity"}],
        "output": {"combine": "network", "activation": "exp"},
    }))  # fmt: skip
    with pytest.raises(JobFailed, match=r"material\.external\.runtime"):
        bsdf_of(mlp, runtime="onnxruntime")
    with pytest.raises(ValueError, match="runtime applies to ONNX models"):
        load_external(mlp, "brdf", runtime="onnxruntime")
