"""``{"model": REF, "fabric": {...}}``: the ``fabric_model`` BSDF and its latent.

Oracles: ``models.fabric.fused.decoder_numpy`` (the numpy reference decoder of the same
weights) recombined with the material's albedos (Eq. 8) at the footprint the BSDF derives
from the uv partials (the square of the parallelogram's area); the encoder run directly
(``encode_material``) for a ``model.pt``; the training latents for a ``model.json``.
The network is random (a small architecture, outputs pushed positive) -- these tests check
the plumbing, not the learning.
"""

from __future__ import annotations

import math
import types
from pathlib import Path

import numpy as np
import pytest

from evaluators.render.bsdfs.fabric_model import FABRIC_MODEL_BSDF_NAME, register_fabric_model_bsdf
from evaluators.render.sources.fabric_model import latent_for
from jobapi.errors import JobFailed
from materials.fabric.params import FabricParams, params_json
from models.fabric.fused import decoder_numpy, encode_material, load_fabric_model, material_maps
from tests.helpers.fabric_models import OTHER, TINY, TRAINED, record_of, write_model
from tests.helpers.mitsuba_probes import direction_chi2


@pytest.fixture(scope="module")
def model_files(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, np.ndarray]:
    return write_model(tmp_path_factory.mktemp("fabric_model"))


def test01_eval_is_the_numpy_decoder(mi: types.ModuleType, model_files: tuple) -> None:
    import drjit as dr

    js, _, latents = model_files
    register_fabric_model_bsdf(mi)
    material = TRAINED.replace(kd_warp=(0.8, 0.2, 0.1), ks_weft=(0.1, 0.5, 0.9))
    bsdf = mi.load_dict(
        {
            "type": FABRIC_MODEL_BSDF_NAME,
            "filename": str(js),
            "latent": mi.TensorXf(latents[0]),
            "params": params_json(material),
            "tiles_per_uv": 4.0,
        }
    )
    rng = np.random.default_rng(2)
    n = 512
    view = rng.normal(size=(n, 3))
    view[:, 2] = np.abs(view[:, 2]) + 0.1
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    light = rng.normal(size=(n, 3))  # both sides: reflection and transmission
    light /= np.linalg.norm(light, axis=1, keepdims=True)
    uv = rng.random((n, 2))
    dx, dy = rng.normal(size=(n, 2)) * 0.05, rng.normal(size=(n, 2)) * 0.05
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(view.T.astype(np.float32))
    si.uv = mi.Point2f(uv.T.astype(np.float32))
    si.duv_dx = mi.Vector2f(dx.T.astype(np.float32))
    si.duv_dy = mi.Vector2f(dy.T.astype(np.float32))
    got = np.asarray(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(light.T.astype(np.float32))))
    got = got.reshape(3, n).T

    size = 4.0 * np.sqrt(np.abs(dx[:, 0] * dy[:, 1] - dx[:, 1] * dy[:, 0]))
    comps = decoder_numpy(
        load_fabric_model(js.read_bytes()), latents[0], uv[:, 0] * 4, uv[:, 1] * 4, size, light,
        view,
    )  # fmt: skip
    want = comps @ material.albedos()
    assert np.all(np.isfinite(got)) and want.max() > 0.01
    np.testing.assert_allclose(got, want, rtol=2e-3, atol=1e-5)
    # The back side answers as the front for mirrored directions (a two-sided sheet).
    si.wi = mi.Vector3f(view[:, 0], view[:, 1], -view[:, 2])
    back = mi.Vector3f(light[:, 0], light[:, 1], -light[:, 2])
    flipped = np.asarray(bsdf.eval(mi.BSDFContext(), si, back)).reshape(3, n).T
    np.testing.assert_allclose(flipped, got, rtol=1e-5, atol=1e-7)


def test02_latents(model_files: tuple) -> None:
    js, pt, latents = model_files
    from_json = load_fabric_model(js.read_bytes())
    # Albedos do not matter: the training latent of the same geometry and roughness.
    same = TRAINED.replace(kd_warp=0.9, ks_weft=0.1)
    np.testing.assert_array_equal(latent_for(from_json, same, "job:x/model.json"), latents[0])
    np.testing.assert_array_equal(latent_for(from_json, OTHER, "job:x/model.json"), latents[1])
    with pytest.raises(JobFailed, match="carries no encoder and none of its training"):
        latent_for(from_json, TRAINED.replace(alpha=0.31), "job:x/model.json")
    from_pt = load_fabric_model(pt.read_bytes())
    new = TRAINED.replace(alpha=0.31)
    z = latent_for(from_pt, new, "job:x/model.pt")
    direct = encode_material(from_pt, new, *material_maps(new, 256))
    assert z.shape == (TINY.latent_dim,) and math.isfinite(float(z.sum()))
    np.testing.assert_allclose(z, direct, rtol=1e-6, atol=1e-7)


class _Ctx:
    """The one ``JobContext`` method the resolver uses: ``resolve(ref) -> Path``."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def resolve(self, ref: str) -> Path:
        return self.path


def eval_bsdf(mi: types.ModuleType, bsdf: object, n: int = 256) -> np.ndarray:
    """``(n, 3)`` values of ``bsdf.eval`` at fixed random footprints and directions."""
    import drjit as dr

    rng = np.random.default_rng(9)
    view = rng.normal(size=(n, 3))
    view[:, 2] = np.abs(view[:, 2]) + 0.1
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    light = rng.normal(size=(n, 3))
    light /= np.linalg.norm(light, axis=1, keepdims=True)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(view.T.astype(np.float32))
    si.uv = mi.Point2f(rng.random((2, n)).astype(np.float32))
    si.duv_dx = mi.Vector2f((rng.normal(size=(2, n)) * 0.02).astype(np.float32))
    si.duv_dy = mi.Vector2f((rng.normal(size=(2, n)) * 0.02).astype(np.float32))
    got = bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(light.T.astype(np.float32)))  # type: ignore[attr-defined]
    return np.asarray(got).reshape(3, n).T.copy()


def test03_interpolation_endpoints(mi: types.ModuleType, model_files: tuple) -> None:
    """Reference: the plain ``{"model", "fabric"}`` renders of A and of B (same resolver)."""
    from evaluators.render.sources.fabric_model import (
        lerp_latent,
        lerp_params,
        resolve_model_fabric,
    )

    _, pt, _ = model_files
    ctx = _Ctx(pt)
    a = {**record_of(TRAINED), "beta": 0.2, "kd_warp": [0.8, 0.2, 0.1], "tiles_per_uv": 4}
    b = {**a, "beta": 1.4, "alpha": 0.7, "kd_warp": 0.3}

    def values(fabric: dict, interpolate: dict | None = None) -> np.ndarray:
        value: dict = {"model": "job:x/model.pt", "fabric": fabric}
        if interpolate is not None:
            value["interpolate"] = interpolate
        return eval_bsdf(mi, resolve_model_fabric(value, ctx, mi))  # type: ignore[arg-type]

    va, vb = values(a), values(b)
    assert np.abs(va - vb).max() > 1e-3  # A and B shade differently
    np.testing.assert_array_equal(values(a, {"fabric": b, "t": 0.0}), va)
    np.testing.assert_array_equal(values(a, {"fabric": b, "t": 1.0}), vb)
    mid = values(a, {"fabric": b, "t": 0.5})
    assert np.all(np.isfinite(mid))
    assert np.abs(mid - va).max() > 1e-4 and np.abs(mid - vb).max() > 1e-4

    pa = FabricParams(**{k: v for k, v in a.items() if k != "tiles_per_uv"})
    pb = FabricParams(**{k: v for k, v in b.items() if k != "tiles_per_uv"})
    half = lerp_params(pa, pb, 0.5)
    assert half.beta == pytest.approx((0.8, 0.8)) and half.alpha == pytest.approx((0.5, 0.6))
    assert half.kd_warp == pytest.approx((0.55, 0.25, 0.2))
    assert lerp_params(pa, pb, 0.0) == pa and lerp_params(pa, pb, 1.0) == pb
    za, zb = np.float32([1.5, -2.0]), np.float32([0.25, 3.0])
    np.testing.assert_array_equal(lerp_latent(za, zb, 0.25), np.float32([1.1875, -0.75]))
    with pytest.raises(ValueError, match="patterns differ"):
        lerp_params(pa, OTHER, 0.5)


def test04_interpolation_specs_are_checked() -> None:
    """Reference: the documented spec-time rules (t in [0, 1], same pattern and tiling)."""
    from pydantic import ValidationError

    from evaluators.render.kind import RenderParams

    a = {"pattern": "twill_3x3", "beta": 0.2}

    def material(interpolate: object) -> dict:
        ref = "sha256:" + "0" * 64
        return {"scene": "cloth_plane", "material": {"model": ref, "fabric": a,
                                                     "interpolate": interpolate}}  # fmt: skip

    ok = RenderParams.model_validate(material({"fabric": {**a, "beta": 0.8}, "t": 1}))
    assert ok.material["interpolate"]["t"] == 1.0
    assert ok.material["interpolate"]["fabric"]["beta"] == 0.8  # defaults filled in
    bad = {
        "must be less than or equal to 1|less than or equal to 1": {"fabric": a, "t": 1.5},
        "greater than or equal to 0": {"fabric": a, "t": -0.1},
        "interpolate.t: this key is required": {"fabric": a},
        r"interpolate.fabric.pattern must equal fabric.pattern \('twill_3x3'\), got 'plain'": {
            "fabric": {"pattern": "plain"},
            "t": 0.5,
        },
        "interpolate.fabric.tiles_per_uv must equal": {
            "fabric": {**a, "tiles_per_uv": 8},
            "t": 0.5,
        },  # fmt: skip
        "interpolate.extra: Extra inputs": {"fabric": a, "t": 0.5, "extra": 1},
        r"alpha must lie in \[0.02, 1.0\]": {"fabric": {**a, "alpha": 3}, "t": 0.5},
    }
    for message, interpolate in bad.items():
        with pytest.raises(ValidationError, match=message):
            RenderParams.model_validate(material(interpolate))
    with pytest.raises(ValidationError, match="interpolate applies to fabric models"):
        RenderParams.model_validate({"material": {"model": "sha256:" + "0" * 64,
                                                  "material": "m", "interpolate": {
                                                      "fabric": a, "t": 0.5}}})  # fmt: skip


@pytest.mark.parametrize("side", [1.0, -1.0], ids=["front", "back"])
def test05_chi2_sampling(mi: types.ModuleType, model_files: tuple, side: float) -> None:
    """``sample``'s directions follow ``pdf`` (Mitsuba's chi-square harness, 1 M draws), with
    the viewer on either side of the sheet."""
    js, _, latents = model_files
    register_fabric_model_bsdf(mi)
    plugin = {
        "type": FABRIC_MODEL_BSDF_NAME,
        "filename": str(js),
        "latent": mi.TensorXf(latents[0]),
        "params": params_json(TRAINED),
        "tiles_per_uv": 4.0,
    }
    wi = (math.sin(0.6), 0.0, side * math.cos(0.6))
    duv = ((0.02, 0.0), (0.0, 0.02))
    ok, p, messages = direction_chi2(mi, plugin, wi, duv=duv, test_count=2)
    print(f"\nchi2 fabric_model, side {side:+g}: p = {p:.3f}")
    assert ok, messages
