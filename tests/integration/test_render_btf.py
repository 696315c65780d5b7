"""BTF materials through the ``render`` kind: ``{"btf": ...}`` (the table), ``{"model":
"job:<train.btf id>"}`` (a trained model) and ``{"btf_surface": ...}`` (the path-traced
surface itself), on ``plane_points`` and ``sphere_points``.

References, none written by us:

- Mitsuba's own ``diffuse`` plugin, for the table of a flat Lambertian ``generate.btf``
  job and for that job's surface;
- the stored slices (float32, exact) for the table BSDF's ``eval``, and the numpy model
  :meth:`models.btf.portable.PortableBtf.slice` for the model BSDF's;
- the procedural surface rendered as real geometry, for the table of its BTF (coarsely:
  the BTF is tabulated at 6 directions and 16^2 texels), and a different surface as the
  control of the texel-for-texel alignment;
- the error messages name the field.

Run with ``-s`` to see the measured numbers.
"""

from __future__ import annotations

import types
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

from evaluators.render.sources import resolve_material
from jobapi.context import JobContext
from jobapi.errors import SpecError
from models.btf.data import BtfDataset
from service.settings import Settings
from service.submission import run_in_process
from storage.artifacts import ArtifactStore
from storage.formats.exr import read_exr
from storage.jobs import Job, JobStore

DIFFUSE = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.2, 0.5, 0.8]}}
FLAT = {"kind": "generate.btf", "seed": 1, "params": {
    "surface": {"bsdf": DIFFUSE}, "directions": {"preset": "small"}, "resolution": 8,
    "spp": 2}}  # fmt: skip


def procedural(seed: int) -> dict[str, Any]:
    return {"kind": "generate.btf", "seed": seed, "params": {
        "surface": {"procedural": "leather", "size": 16, "relief": 0.03},
        "directions": {"preset": "small"}, "resolution": 16, "spp": 4}}  # fmt: skip


@dataclass
class Env:
    settings: Settings
    flat: Job
    leather: Job
    other: Job
    models: dict[str, Job]
    ctx: JobContext


@pytest.fixture(scope="module")
def env(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Env]:
    root = tmp_path_factory.mktemp("btf_render")
    settings = Settings.from_env({}).with_(data_dir=root / "data", pool_processes=1)

    def ok(spec: dict[str, Any]) -> Job:
        job = run_in_process(spec, settings)
        assert job.state == "succeeded", job.error
        return job

    flat, leather, other = ok(FLAT), ok(procedural(1)), ok(procedural(2))
    models = {
        name: ok({"kind": "train.btf", "seed": 0,
                  "params": {"data": f"job:{leather.id}", "model": name, **extra}})
        for name, extra in (("c2f", {"epochs": 1}), ("lafortune", {"lafortune_iterations": 2}))
    }  # fmt: skip
    jobs = JobStore(settings.db_path)
    ctx = JobContext(
        job_id="0" * 32, seed=0, spec={}, store=ArtifactStore(settings.store_dir), jobs=jobs,
        workdir=root,
    )  # fmt: skip
    yield Env(settings, flat, leather, other, models, ctx)
    jobs.close()


def render(
    env: Env, material: dict[str, Any], scene: str = "plane_points", seed: int = 2, **params: Any
) -> Job:
    spec = {"kind": "render", "seed": seed, "params": {
        "scene": scene, "resolution": [64, 48], "spp": 4, "max_depth": 3, "material": material,
        **params}}  # fmt: skip
    return run_in_process(spec, env.settings)


def image(env: Env, job: Job) -> np.ndarray:
    assert job.state == "succeeded", job.error
    (digest,) = [a.digest for a in job.artifacts if a.name == "image.exr"]
    path = ArtifactStore(env.settings.store_dir).open_verified(digest)
    return read_exr(path, "image.exr").astype(np.float64)


@pytest.mark.parametrize("scene", ["plane_points", "sphere_points"])
def test01_flat_lambertian_table_is_mitsuba_diffuse(env: Env, scene: str) -> None:
    """The table of a flat Lambertian BTF renders as Mitsuba's ``diffuse`` with the same
    albedo. The table interpolates the apparent BRDF ``BTF / cos(theta_i)`` (constant here)
    and applies the query's ``cos(theta_i)``, so between and beyond the 6 measured
    directions it is exact, not merely within the few percent that interpolating ``cos``
    itself between the 0/30/60 degree rings would give; on a single convex object under
    point lights every pixel is direct light (the same at any sampling), so the images
    agree to float32 rounding: 1e-4 relative. The sphere checks Mitsuba's uv there (its
    mirrored frame changes nothing for an isotropic BTF). The flat job's surface is that
    same ``diffuse`` dict: the same image, bit for bit."""
    ref = image(env, render(env, {"mitsuba": DIFFUSE}, scene))
    table = image(env, render(env, {"btf": f"job:{env.flat.id}", "uv_scale": [2, 1]}, scene))
    surface = image(env, render(env, {"btf_surface": f"job:{env.flat.id}"}, scene))
    assert ref.mean() > 0.01
    np.testing.assert_allclose(table, ref, rtol=1e-4, atol=1e-6 * ref.max())
    assert np.array_equal(surface, ref)


def test02_table_eval_returns_the_slices(env: Env, mi: types.ModuleType) -> None:
    """Through the material source, the table BSDF at texel centres and the job's own
    (light, view) pairs returns every stored float32 value exactly (``eval``'s light is
    Mitsuba's ``wo``, its view ``si.wi``)."""
    data = BtfDataset.open(f"job:{env.leather.id}", env.ctx)
    assert data.slices is not None
    bsdf = resolve_material({"btf": f"job:{env.leather.id}"}, env.ctx, mi)
    out = eval_grid(mi, bsdf, data.wi, data.wo, *data.resolution)
    assert np.array_equal(out, data.slices)


def eval_grid(
    mi: types.ModuleType, bsdf: Any, wi: np.ndarray, wo: np.ndarray, h: int, w: int
) -> np.ndarray:
    """``(N, h, w, 3)`` float32: ``bsdf.eval`` at every texel centre for each pair."""
    import drjit as dr

    jj, ii = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    uv = np.stack([(ii.ravel() + 0.5) / w, (jj.ravel() + 0.5) / h], axis=1)
    out = np.empty((len(wi), h, w, 3), np.float32)
    for k in range(len(wi)):
        si = dr.zeros(mi.SurfaceInteraction3f, h * w)
        si.uv = mi.Point2f(*uv.astype(np.float32).T)
        si.sh_frame = mi.Frame3f(mi.Vector3f(1, 0, 0), mi.Vector3f(0, 1, 0), mi.Vector3f(0, 0, 1))
        si.wi = mi.Vector3f(*np.tile(wo[k], (h * w, 1)).astype(np.float32).T)
        light = mi.Vector3f(*np.tile(wi[k], (h * w, 1)).astype(np.float32).T)
        value = bsdf.eval(mi.BSDFContext(), si, light)
        out[k] = np.asarray(value, np.float32).T.reshape(h, w, 3)
    return out


@pytest.mark.parametrize("model", ["c2f", "lafortune"])
def test03_model_eval_is_the_portable_model(env: Env, mi: types.ModuleType, model: str) -> None:
    """``{"model": "job:<train.btf id>"}`` is a ``btf_model`` BSDF whose eval at texel
    centres and the BTF's directions equals the numpy model's slices
    (:meth:`PortableBtf.slice`) to float32 precision; it renders on both scenes."""
    import json

    from models.btf.portable import read_model, read_textures

    job = env.models[model]
    bsdf = resolve_material({"model": f"job:{job.id}"}, env.ctx, mi)
    portable = read_model(
        json.loads(env.ctx.read_ref(f"job:{job.id}/model.json")),
        read_textures(env.ctx.read_ref(f"job:{job.id}/textures.npz")),
    )
    data = BtfDataset.open(f"job:{env.leather.id}", env.ctx)
    pick = np.arange(0, len(data), 5)
    out = eval_grid(mi, bsdf, data.wi[pick], data.wo[pick], *portable.resolution)
    ref = np.stack([portable.slice(data.wi[k], data.wo[k]) for k in pick])
    assert ref.max() > 0.0
    # float32 Dr.Jit against float32 numpy: measured a tenth of this (AMD EPYC).
    np.testing.assert_allclose(out, ref, rtol=1e-4, atol=1e-6 * ref.max())
    for scene in ("plane_points", "sphere_points"):
        img = image(env, render(env, {"model": f"job:{job.id}", "uv_scale": [4, 2]}, scene))
        assert np.all(np.isfinite(img)) and img.max() > 0.0


def _pattern(img: np.ndarray) -> np.ndarray:
    """The texture's pattern: luminance (blurred by 1.5 pixels against Monte Carlo noise)
    over its local mean (8 pixels: the lighting's falloff removed)."""
    from scipy.ndimage import gaussian_filter

    lum = img.mean(axis=-1)
    return gaussian_filter(lum, 1.5) / np.maximum(gaussian_filter(lum, 8.0), 1e-6) - 1.0


def test04_surface_against_its_table(env: Env) -> None:
    """The path-traced procedural surface (relief mesh, principled BSDF with the job's maps)
    and the table of its BTF, both tiled twice over ``plane_points``:

    - mean brightness within 12 %: the table knows the BTF at 6 directions only (the
      glossy part of the principled BSDF is blurred between them and held constant beyond
      60 degrees), and each texel's slice value averages parallax and shadows over the
      texel; measured ~4 %;
    - texel for texel: the two images' patterns (luminance over its local mean) correlate
      above 0.5 (measured ~0.8), while the table of a different leather (another seed)
      does not (below 0.25; measured ~0): the uv of the plane and the patch coordinates
      line up. Each render has its own seed, so their Monte Carlo noise is independent.
    """
    common: dict[str, Any] = {"resolution": [96, 72], "spp": 16}
    uv = {"uv_scale": 2}
    surface = image(env, render(env, {"btf_surface": f"job:{env.leather.id}", **uv}, **common))
    table = image(env, render(env, {"btf": f"job:{env.leather.id}", **uv}, seed=3, **common))
    other = image(env, render(env, {"btf": f"job:{env.other.id}", **uv}, seed=4, **common))
    rel = table.mean() / surface.mean() - 1.0
    lit = surface.mean(axis=-1) > 0.1 * surface.mean()
    corr = np.corrcoef(_pattern(table)[lit], _pattern(surface)[lit])[0, 1]
    control = np.corrcoef(_pattern(other)[lit], _pattern(surface)[lit])[0, 1]
    print(f"\nmean: table {rel:+.1%} of the surface; pattern corr {corr:.2f}, control "
          f"{control:.2f}")  # fmt: skip
    assert abs(rel) < 0.12
    assert corr > 0.5 and control < 0.25


def test05_errors_name_the_field(env: Env, monkeypatch: pytest.MonkeyPatch) -> None:
    model = env.models["c2f"]
    missing = "job:" + "0" * 32
    failures: dict[str, dict[str, Any]] = {
        "material.btf: job " + model.id + " is a train.btf job, not a BTF": {
            "btf": f"job:{model.id}"},
        f"material.btf: no job {'0' * 32}": {"btf": missing},
        f"material.btf_surface: job {model.id} is a train.btf job, not generate.btf": {
            "btf_surface": f"job:{model.id}"},
        f"material.model: job {env.flat.id} is a generate.btf job without a BTF model": {
            "model": f"job:{env.flat.id}"},
        f"material.model: job:{model.id}/model.json is a BTF model": {
            "model": f"job:{model.id}/model.json", "material": "leather"},
        "material.uv_scale: a btf_surface's relief scales with its tile": {
            "btf_surface": f"job:{env.leather.id}", "uv_scale": [2, 3]},
        "material: this material is a surface with relief": {
            "btf_surface": f"job:{env.leather.id}", "scene": "sphere_points"},
    }  # fmt: skip
    for message, material in failures.items():
        scene = material.pop("scene", "plane_points")
        job = render(env, material, scene)
        assert job.state == "failed" and str(job.error).startswith(message), (message, job.error)

    import evaluators.render.sources.btf as btf_source

    monkeypatch.setattr(btf_source, "MAX_TABLE_BYTES", 1024)
    job = render(env, {"btf": f"job:{env.leather.id}"})
    assert job.state == "failed"
    assert str(job.error).startswith("material.btf: the BTF of job ") and "0.0 GiB" in str(
        job.error
    )

    refused: dict[str, dict[str, Any]] = {
        "btf: must be a whole job": {"btf": f"job:{env.flat.id}/btf.json"},
        "uv_scale: must be positive": {"btf": f"job:{env.flat.id}", "uv_scale": -1},
        "uv_scale: must be a number or a pair": {"btf": f"job:{env.flat.id}", "uv_scale": [1]},
        "material: a whole-job reference names a BTF model": {
            "model": f"job:{model.id}", "material": "gold"},
        "uv_scale: applies to BTF models": {
            "model": f"job:{model.id}/model.json", "material": "gold", "uv_scale": 2},
        "spp: not a key of a 'btf' material": {"btf": f"job:{env.flat.id}", "spp": 2},
    }  # fmt: skip
    for message, material in refused.items():
        with pytest.raises(SpecError, match=message):
            run_in_process({"kind": "render", "params": {"material": material}}, env.settings)
