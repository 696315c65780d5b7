"""``render`` with ``{"external": ...}``: a user's own model, uploaded as a file.

The proof with a model we did not write (issue 23, "Known BRDFs"): a Lambert + GGX BRDF
written in plain PyTorch in this test (:class:`TorchGgxLambert`, not matforge's code) is
exported with :func:`matforge.export.brdf_mlp` as the MLP format's analytic part with no
network, imported into the store (validated, as ``matforge import`` and ``POST
/api/artifacts`` do), and rendered in ``sphere_env`` through the ``external`` source.

Oracle: Mitsuba's own BSDFs of the same parameters. ``f = kd / pi + D G F / (4 cos_i
cos_o)`` with GGX ``D``, separable Smith ``G`` and the exact Fresnel of a real IOR ``eta``
is exactly ``blendbsdf(weight 0.5, diffuse(2 kd), roughconductor(ggx, alpha, eta, k = 0,
specular_reflectance 2))``: Mitsuba's ``roughconductor`` uses the same GGX ``D``, the
separable Smith ``G1(wi) G1(wo)``, and ``fresnel_conductor`` with ``k = 0`` (equal to the
dielectric Fresnel for light arriving from outside); a blend of weight 0.5 halves each
lobe, which the doubled albedos undo. (``roughplastic`` is not equal: it couples the
diffuse lobe to the Fresnel transmittance.) Accepted: HDR-FLIP < 0.02 and channel means
within 1 %, at 64 x 64, 1024 spp (both renders are noisy; their own seed-to-seed FLIP is
printed with ``-s``).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

import matforge.export as export
from evaluators.metrics.images import flip, hdr_exposure_range
from jobapi.errors import SpecError
from service.settings import Settings
from service.submission import import_file, run_in_process
from storage.artifacts import ArtifactStore
from storage.errors import FormatError
from storage.formats.exr import read_exr
from storage.jobs import JobStore
from tests.helpers.renders import assert_same_render

SIZE, SPP, MAX_DEPTH = 64, 1024, 3
KD, ALPHA, ETA = [0.3, 0.15, 0.05], 0.25, 1.5


class TorchGgxLambert(torch.nn.Module):
    """Lambert + GGX in plain torch (Walter et al. 2007, Eqs. 33-34; Born and Wolf's
    unpolarised Fresnel of a dielectric); ``forward(wi, wo)`` is the plain BRDF (1/sr)."""

    def __init__(self, kd: list[float], alpha: float, eta: float) -> None:
        super().__init__()
        self.kd = torch.nn.Parameter(torch.tensor(kd, dtype=torch.float64))
        self.alpha = torch.nn.Parameter(torch.tensor(alpha, dtype=torch.float64))
        self.eta = torch.nn.Parameter(torch.tensor(eta, dtype=torch.float64))

    def forward(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        h = torch.nn.functional.normalize(wi + wo, dim=-1)
        a2 = self.alpha**2
        d = a2 / (math.pi * ((a2 - 1) * h[:, 2] ** 2 + 1) ** 2)

        def g1(v: torch.Tensor) -> torch.Tensor:
            return 2 / (1 + torch.sqrt(1 + a2 * (1 - v[:, 2] ** 2) / v[:, 2] ** 2))

        c = (wi * h).sum(-1)
        ct = torch.sqrt(1 - (1 - c**2) / self.eta**2)
        rs = (c - self.eta * ct) / (c + self.eta * ct)
        rp = (self.eta * c - ct) / (self.eta * c + ct)
        spec = d * g1(wi) * g1(wo) * 0.5 * (rs**2 + rp**2) / (4 * wi[:, 2] * wo[:, 2])
        return self.kd / math.pi + spec[:, None]


def _import(settings: Settings, path: Path) -> str:
    jobs = JobStore(settings.db_path)
    try:
        record = import_file(path, jobs, ArtifactStore(settings.store_dir))
    finally:
        jobs.close()
    return f"sha256:{record.digest}"


def render(settings: Settings, material: dict[str, Any], seed: int) -> np.ndarray:
    params = {
        "scene": "sphere_env",
        "material": material,
        "resolution": [SIZE, SIZE],
        "spp": SPP,
        "max_depth": MAX_DEPTH,
    }
    job = run_in_process({"kind": "render", "seed": seed, "params": params}, settings)
    assert job.state == "succeeded", job.error
    (image,) = [a for a in job.artifacts if a.name == "image.exr"]
    return read_exr(ArtifactStore(settings.store_dir).path(image.digest)).astype(np.float64)


@pytest.mark.slow
def test01_torch_ggx_lambert_renders_like_mitsuba(
    settings: Settings, tmp_path: Path, mitsuba_llvm: None
) -> None:
    user = TorchGgxLambert(KD, ALPHA, ETA)
    # The exported file reproduces the torch module (numpy reference vs torch, float64).
    gen = torch.Generator().manual_seed(0)
    v = torch.nn.functional.normalize(
        torch.rand(2, 500, 3, generator=gen, dtype=torch.float64) * torch.tensor([2.0, 2.0, 1.0])
        - torch.tensor([1.0, 1.0, -0.05]),
        dim=-1,
    )
    path = export.brdf_mlp(
        None,
        tmp_path / "ggx-lambert.json",
        analytic={"kd": user.kd, "alpha": user.alpha, "eta": user.eta},
        name="torch GGX",
    )
    from models.external.mlp import read_mlp

    with torch.no_grad():
        expected = user(v[0], v[1]).numpy()
    np.testing.assert_allclose(read_mlp(path).eval(v[0].numpy(), v[1].numpy()), expected, rtol=1e-9)
    ref = _import(settings, path)
    ours = render(settings, {"external": {"model": ref, "kind": "brdf"}}, 1)
    mitsuba = {
        "type": "blendbsdf",
        "weight": 0.5,
        "bsdf_0": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [2 * k for k in KD]}},
        "bsdf_1": {
            "type": "roughconductor",
            "distribution": "ggx",
            "alpha": ALPHA,
            "eta": ETA,
            "k": 0.0,
            "specular_reflectance": 2.0,
        },
    }
    native = render(settings, {"mitsuba": mitsuba}, 2)
    native2 = render(settings, {"mitsuba": mitsuba}, 3)
    exposure = hdr_exposure_range(native)
    err, _ = flip(native, ours, exposure_range=exposure)
    noise, _ = flip(native, native2, exposure_range=exposure)
    ratio = ours.reshape(-1, 3).mean(0) / native.reshape(-1, 3).mean(0)
    print(
        f"\nHDR-FLIP external vs Mitsuba {err:.4f} (Mitsuba vs itself {noise:.4f}); "
        f"mean ratio {ratio}"
    )
    assert err < 0.02
    np.testing.assert_allclose(ratio, 1.0, atol=0.01)


def test02_bad_files_are_refused_at_import_and_in_the_job(
    settings: Settings, tmp_path: Path
) -> None:
    bad = tmp_path / "mine.json"
    bad.write_text(
        json.dumps(
            {
                "format": "matforge.mlp-brdf/1",
                "inputs": ["wi", "wo"],
                "layers": [],
                "output": {"combine": "network"},
            }
        )
    )
    with pytest.raises(FormatError, match="mine.json: not a valid MLP model: .*needs at least"):
        _import(settings, bad)
    # A file that reached the store without the check (any bytes): the job names the ref.
    store, jobs = ArtifactStore(settings.store_dir), JobStore(settings.db_path)
    try:
        info = store.put_bytes(b'{"format": "matforge.mlp-brdf/1"}')
        jobs.record_upload(info.digest, "raw.json", "application/json", info.size)
    finally:
        jobs.close()
    ref = f"sha256:{info.digest}"
    params = {
        "material": {"external": {"model": ref, "kind": "brdf"}},
        "resolution": [8, 8],
        "spp": 1,
    }
    job = run_in_process({"kind": "render", "seed": 0, "params": params}, settings)
    assert job.state == "failed"
    assert job.error is not None and job.error.startswith(f"material.external.model: {ref}: ")
    # The right file, the wrong kind.
    good = export.brdf_mlp(None, tmp_path / "a.json", analytic={"kd": KD, "alpha": 0.3, "eta": 1.5})
    params["material"] = {"external": {"model": _import(settings, good), "kind": "btf"}}
    # refused before queueing, naming the field and the file's format
    with pytest.raises(SpecError, match=r"params\.material\.external\.kind: .* is a brdf model"):
        run_in_process({"kind": "render", "seed": 0, "params": params}, settings)


def test03_spec_time_errors(settings: Settings) -> None:
    ref = "sha256:" + "0" * 64
    cases = [
        ({"model": ref, "kind": "bssrdf"}, "external.kind: Input should be 'brdf' or 'btf'"),
        ({"model": "mine.json", "kind": "brdf"}, "external.model: must be an artifact reference"),
        ({"model": ref, "kind": "brdf", "uv_scale": 2}, "uv_scale: applies to kind 'btf' only"),
        ({"model": ref}, "external.kind: this key is required"),
    ]
    for value, message in cases:
        with pytest.raises(SpecError, match=message):
            run_in_process(
                {"kind": "render", "params": {"material": {"external": value}}}, settings
            )


def test04_lambertian_mlp_btf_renders_like_mitsubas_diffuse(
    settings: Settings, tmp_path: Path, mitsuba_llvm: None
) -> None:
    """A BTF whose network is the constant ``albedo / pi`` with ``foreshortening: "apply"``
    is Lambertian (the UBO2014 convention, ``generate.btf``'s): on ``plane_points`` it
    renders as Mitsuba's ``diffuse`` of that albedo. Both sample the light direction by
    cosine and draw the same random numbers at the same seed, so the images agree to
    float32 rounding (:func:`tests.helpers.renders.assert_same_render`)."""
    albedo = np.array([0.2, 0.5, 0.8])
    lin = torch.nn.Linear(2, 3)
    with torch.no_grad():
        lin.weight.zero_()
        lin.bias.copy_(torch.from_numpy(albedo / np.pi))
    path = export.btf_mlp(
        lin, tmp_path / "lambert.json", textures=[], inputs=["uv"], foreshortening="apply"
    )
    ref = _import(settings, path)

    def plane(material: dict[str, Any], seed: int) -> np.ndarray:
        params = {
            "scene": "plane_points",
            "material": material,
            "resolution": [48, 48],
            "spp": 64,
            "max_depth": 2,
        }
        job = run_in_process({"kind": "render", "seed": seed, "params": params}, settings)
        assert job.state == "succeeded", job.error
        (image,) = [a for a in job.artifacts if a.name == "image.exr"]
        return read_exr(ArtifactStore(settings.store_dir).path(image.digest)).astype(np.float64)

    ours = plane({"external": {"model": ref, "kind": "btf", "uv_scale": 2}}, 1)
    diffuse = {"type": "diffuse", "reflectance": {"type": "rgb", "value": albedo.tolist()}}
    native = plane({"mitsuba": diffuse}, 1)
    assert float(native.mean()) > 0.01
    assert_same_render(ours, native, rtol=1e-5)


def test05_a_broken_onnx_file_in_the_store_is_refused_before_queueing(
    settings: Settings,
) -> None:
    """A file that reached the store without the upload check (a ModelProto cut after its
    first fields) is refused at submission, naming the field and the file, and nothing is
    queued (the reference: onnx's own parser refuses the bytes)."""
    store, jobs = ArtifactStore(settings.store_dir), JobStore(settings.db_path)
    try:
        info = store.put_bytes(b"\x08\x08\x12\x07pytorch")  # a ModelProto's first fields
        jobs.record_upload(info.digest, "m.onnx", "application/octet-stream", info.size)
        before = jobs.count_jobs()
    finally:
        jobs.close()
    ref = f"sha256:{info.digest}"
    material = {"external": {"model": ref, "kind": "brdf"}}
    params = {"material": material, "resolution": [8, 8], "spp": 1}
    with pytest.raises(SpecError, match=r"params\.material\.external\.model: .*" + ref[7:17]):
        run_in_process({"kind": "render", "seed": 0, "params": params}, settings)
    jobs = JobStore(settings.db_path)
    try:
        assert jobs.count_jobs() == before
    finally:
        jobs.close()


def test06_an_onnx_output_of_the_wrong_width_fails_the_job_naming_the_ref(
    settings: Settings, tmp_path: Path, mitsuba_llvm: None
) -> None:
    """A BRDF whose output is ``[N, 4]`` at run time (its width hidden from shape inference,
    so the upload accepts it) fails its render with the shape, what the signature needs and
    the user's ``sha256:`` ref in the job's ``error``, not an internal error naming Dr.Jit
    or the store's file name (the reference: the graph's construction,
    :func:`tests.helpers.onnx_models.runtime_width_model`)."""
    from tests.helpers.onnx_models import runtime_width_model, save

    ref = _import(settings, save(runtime_width_model(4), tmp_path / "wide.onnx"))
    params = {
        "scene": "sphere_env",
        "spp": 1,
        "resolution": [8, 8],
        "material": {"external": {"model": ref, "kind": "brdf"}},
    }
    job = run_in_process({"kind": "render", "seed": 0, "params": params}, settings)
    assert job.state == "failed"
    error = job.error or ""
    assert error.startswith(f"{ref}: the model's output rgb has shape ["), error
    assert ", 4] for " in error and "needs [N, 3]" in error, error
    assert "internal error" not in error and "drjit" not in error, error
