"""``evaluate.tss`` of a user's BTF (``{"model": {"external": {...}}}``): an MLP BTF
exported with ``matforge.export.btf_mlp`` from plain torch is shaded in texture space
through the fused kernel, per texel, with rows that name its runtime and file; an ONNX BTF
is refused, saying why (its time would be missing from the Dr.Jit kernel figures).

Oracle for the images: the reference frame of an MLP whose network ignores the latent is
a Lambertian plane lit by the three lights; with N = 0 and the radiance texture much finer
than the view, the texture-space frame converges to it (FLIP small), and reusing the
texture for N = 2 frames of a moving head is no better.
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

    onnx = onnx_models.save(onnx_models.lambert_model("btf"), tmp_path / "l.onnx")
    onnx_ref = f"sha256:{import_file(onnx, jobs, store).digest}"
    failed = run_tss({"external": {"model": onnx_ref, "kind": "btf"}}, settings)
    assert failed.state == "failed"
    assert "onnxruntime" in (failed.error or "") and "matforge.mlp-btf/1" in (failed.error or "")


def test02_a_brdf_is_refused_at_spec_time() -> None:
    from jobapi.errors import SpecError
    from service.specs import validate_spec

    kinds.load_builtin()
    spec = {"kind": "evaluate.tss", "params": {
        "model": {"external": {"model": "sha256:" + "0" * 64, "kind": "brdf"}}}}  # fmt: skip
    with pytest.raises(SpecError, match="kind must be 'btf'"):
        validate_spec(spec)
