"""``evaluate.tss`` of a user's BTF (``{"model": {"external": {...}}}``): an MLP BTF
exported with ``matforge.export.btf_mlp`` from plain torch is shaded in texture space
through the fused kernel, per texel, with rows that name its runtime and file; an ONNX BTF
runs through onnxruntime on the passes' texel batches, its rows naming ``onnxruntime``.

Oracles for the images: the reference frame of an MLP whose network ignores the latent is
a Lambertian plane lit by the three lights; with N = 0 and the radiance texture much finer
than the view, the texture-space frame converges to it (FLIP small), and reusing the
texture for N = 2 frames of a moving head is no better. The Lambertian ONNX BTF's radiance
texture equals the flat diffuse plane's radiance written out here in numpy
(``albedo / pi * cos(theta_i) * I / r^2`` per light), to float32 rounding; its whole
evaluate.tss run scores as the Lambertian MLP's (the same images to float32 rounding).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest
import torch

from service import kinds
from service.settings import Settings
from service.submission import import_file, run_in_process
from storage.artifacts import ArtifactStore
from storage.jobs import Job, JobStore
from tests.helpers import onnx_models

ALBEDO = (0.2, 0.5, 0.8)


def lambert_mlp(path: Path) -> Path:
    """A BTF MLP ``(latent 2, wi, wo) -> albedo / pi``, foreshortening applied by matforge:
    zero weights, the bias the albedo (the latent texture is random and unused)."""
    import matforge.export

    net = torch.nn.Sequential(torch.nn.Linear(8, 4), torch.nn.ReLU(), torch.nn.Linear(4, 3))
    with torch.no_grad():
        for p in net.parameters():
            p.zero_()
        net[2].bias.copy_(torch.tensor(ALBEDO) / math.pi)
    tex = torch.randn(2, 8, 8, generator=torch.Generator().manual_seed(0))
    return matforge.export.btf_mlp(net, path, textures=[tex], foreshortening="apply")


def run_tss(model: Any, settings: Settings) -> Job:
    spec = {"kind": "evaluate.tss", "seed": 0, "params": {
        "model": model, "frames": 4, "intervals": [0, 2], "image": [24, 24],
        "resolutions": [96]}}  # fmt: skip
    return run_in_process(spec, settings)


def test01_mlp_btf_in_texture_space(tmp_path: Path) -> None:
    kinds.load_builtin()
    settings = Settings.from_env({}).with_(data_dir=tmp_path / "data", pool_processes=1)
    jobs, store = JobStore(settings.db_path), ArtifactStore(settings.store_dir)
    ref = f"sha256:{import_file(lambert_mlp(tmp_path / 'm.json'), jobs, store).digest}"
    job = run_tss({"external": {"model": ref, "kind": "btf"}}, settings)
    assert job.state == "succeeded", job.error
    (digest,) = [a.digest for a in job.artifacts if a.name == "metrics.json"]
    doc = json.loads(store.read(digest))
    assert doc["model"]["external"] == {"model": ref, "kind": "btf"}
    rows = {r["label"]: r for r in doc["rows"]}
    assert {r["pass"] for r in rows.values()} == {"per_texel"}
    assert rows["96/N=0"]["flip_mean"] < 0.1
    assert rows["96/N=0"]["flip_mean"] <= rows["96/N=2"]["flip_mean"] + 1e-9

    from evaluators.tss.rows import tss_rows
    from jobapi.row_sources import StoreSource

    out = tss_rows(StoreSource(jobs.get(job.id), jobs, store))
    assert out and all(r.runtime == "drjit-fused" and r.dataset == ref for r in out)
    assert all(r.ms_per_frame and r.ms_per_frame > 0 for r in out)

    onnx = onnx_models.save(onnx_models.lambert_model("btf", ALBEDO), tmp_path / "l.onnx")
    onnx_ref = f"sha256:{import_file(onnx, jobs, store).digest}"
    other = run_tss({"external": {"model": onnx_ref, "kind": "btf"}}, settings)
    assert other.state == "succeeded", other.error
    (digest,) = [a.digest for a in other.artifacts if a.name == "metrics.json"]
    onnx_doc = json.loads(store.read(digest))
    assert onnx_doc["model"]["runtime"] == "onnxruntime"
    # The same Lambertian plane: every row's scores as the MLP's. The images agree to
    # float32 rounding (albedo / pi * cos computed by two runtimes); FLIP and PSNR of
    # images that close differ by far less than 1e-4 (FLIP) and 1e-2 dB (PSNR ~40 dB).
    onnx_rows = {r["label"]: r for r in onnx_doc["rows"]}
    assert set(onnx_rows) == set(rows)
    for label, row in rows.items():
        assert onnx_rows[label]["flip_mean"] == pytest.approx(row["flip_mean"], abs=1e-4)
        assert onnx_rows[label]["psnr_mean"] == pytest.approx(row["psnr_mean"], abs=1e-2)
    out = tss_rows(StoreSource(jobs.get(other.id), jobs, store))
    assert out and all(r.runtime == "onnxruntime" and r.dataset == onnx_ref for r in out)
    assert all(r.ms_per_frame and r.ms_per_frame > 0 for r in out)


def test03_onnx_lambert_texture_is_the_flat_diffuse_plane(tmp_path: Path) -> None:
    """The shading pass of the Lambertian ONNX BTF against the radiance of a flat diffuse
    plane written out in numpy (module docstring): float32 rounding apart, equal."""
    import numpy as np

    from evaluators.tss.external import OnnxPlaneModel
    from evaluators.tss.params import DEFAULT_LIGHTS, PLANE_SIDE
    from evaluators.tss.passes import Plane
    from materials.backend import load_mitsuba
    from models.external.onnx_model import load_onnx

    mi = load_mitsuba()
    if not mi.variant().startswith(("llvm_", "cuda_")):
        pytest.skip("evaluate.tss needs a vectorised Mitsuba variant")
    onnx = onnx_models.save(onnx_models.lambert_model("btf", ALBEDO), tmp_path / "l.onnx")
    model = OnnxPlaneModel(load_onnx(onnx, "btf"), mi)
    lights = list(DEFAULT_LIGHTS)
    plane = Plane(model, lights, uv_scale=2)
    eye = np.array([0.1, -0.3, 0.6])
    basis = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]])  # looking down
    cam = plane.camera(eye, basis, 0.5)
    r = 24
    tex = np.stack([np.asarray(c) for c in plane.shade(r, cam, amortised=True)], axis=1)

    jj, ii = np.meshgrid(np.arange(r), np.arange(r), indexing="ij")
    x, y = ((ii.ravel() + 0.5) / r - 0.5) * PLANE_SIDE, ((jj.ravel() + 0.5) / r - 0.5) * PLANE_SIDE
    p = np.stack([x, y, np.zeros(r * r)], axis=1)
    to_eye = eye - p
    wo_z = to_eye[:, 2] / np.linalg.norm(to_eye, axis=1)
    expect = np.zeros((r * r, 3))
    for light in lights:
        d = np.asarray(light.position) - p
        r2 = np.sum(d * d, axis=1)
        cos_i = d[:, 2] / np.sqrt(r2)
        lit = (cos_i > 0) & (wo_z > 0)
        expect += np.where(lit, cos_i / r2, 0.0)[:, None] * np.asarray(ALBEDO) / np.pi \
            * np.asarray(light.rgb())  # fmt: skip
    assert expect.max() > 0
    np.testing.assert_allclose(tex, expect, rtol=1e-5, atol=1e-7 * expect.max())


def test02_a_brdf_is_refused_at_spec_time() -> None:
    from jobapi.errors import SpecError
    from service.specs import validate_spec

    kinds.load_builtin()
    spec = {"kind": "evaluate.tss", "params": {
        "model": {"external": {"model": "sha256:" + "0" * 64, "kind": "brdf"}}}}  # fmt: skip
    with pytest.raises(SpecError, match="kind must be 'btf'"):
        validate_spec(spec)
