"""The user-MLP BSDFs ``external_mlp`` (BRDF) and ``external_mlp_btf`` (BTF).

Oracles:

- the numpy reference :meth:`models.external.mlp.MlpMaterial.eval`, for ``eval`` (times
  ``cos theta_o`` for the BRDF, Mitsuba's convention; as it stands for the BTF, whose value
  includes foreshortening), to float32 precision;
- Mitsuba's own ``diffuse`` for the BTF convention (closed form: a Lambertian BTF of
  albedo ``a`` is ``a / pi cos(theta_light)``, which is exactly Mitsuba's ``eval`` of a
  diffuse BSDF);
- :func:`tests.helpers.mitsuba_probes.check_pdf_and_sampling` (pdf >= 0, integral <= 1,
  weight = eval / pdf) and Mitsuba's chi-square test for the GGX/cosine mixture.
"""

from __future__ import annotations

import types
from pathlib import Path
from typing import Any

import drjit as dr
import numpy as np
import pytest
import torch

import matforge.export as export
from evaluators.render.bsdfs.external_mlp import EXTERNAL_MLP_NAME, register_external_mlp_bsdf
from evaluators.render.bsdfs.external_mlp_btf import (
    EXTERNAL_MLP_BTF_NAME,
    register_external_mlp_btf_bsdf,
)
from models.external.mlp import read_mlp
from tests.helpers.mitsuba_probes import check_pdf_and_sampling, hemisphere, interaction


@pytest.fixture(scope="module")
def mi(mi: types.ModuleType) -> types.ModuleType:
    register_external_mlp_bsdf(mi)
    register_external_mlp_btf_bsdf(mi)
    return mi


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("external_bsdf")
    torch.manual_seed(2)
    net = torch.nn.Sequential(torch.nn.Linear(10, 16), torch.nn.ReLU(), torch.nn.Linear(16, 6))
    hybrid = export.brdf_mlp(
        net,
        root / "hybrid.json",
        inputs=["wi", "wo", "cos_d", "h"],
        output_activation=["exp"] * 3 + ["sigmoid"] * 3,
        analytic={"kd": [0.3, 0.2, 0.1], "alpha": 0.2, "eta": [1.5, 1.5, 1.5]},
    )
    plain = export.brdf_mlp(
        net[:2] + torch.nn.Sequential(torch.nn.Linear(16, 3)),
        root / "plain.json",
        inputs=["wi", "wo", "cos_d", "h"],
        output_activation="softplus",
    )
    tex = torch.rand(3, 4, 4, generator=torch.Generator().manual_seed(1))
    btf_net = torch.nn.Sequential(torch.nn.Linear(7, 8), torch.nn.Tanh(), torch.nn.Linear(8, 3))
    btf = export.btf_mlp(
        btf_net,
        root / "btf.json",
        textures=[tex],
        output_activation="exp",
        inputs=[{"type": "texture"}, "wi.xy", "wo.xy"],
    )
    # Lambertian: no weights, the bias is albedo / pi; matforge applies cos(theta_i).
    albedo = np.array([0.2, 0.5, 0.8])
    lin = torch.nn.Linear(2, 3)
    with torch.no_grad():
        lin.weight.zero_()
        lin.bias.copy_(torch.from_numpy(albedo / np.pi))
    lambert = export.btf_mlp(
        lin, root / "lambert.json", textures=[], inputs=["uv"], foreshortening="apply"
    )
    return {"hybrid": hybrid, "plain": plain, "btf": btf, "lambert": lambert}


def test01_create(mi: types.ModuleType, files: dict[str, Path]) -> None:
    assert register_external_mlp_bsdf(mi) is register_external_mlp_bsdf(mi)
    bsdf = mi.load_dict({"type": EXTERNAL_MLP_NAME, "filename": str(files["hybrid"])})
    assert "ExternalMlp[" in str(bsdf) and bsdf.specular_weight > 0.1
    with pytest.raises(Exception, match="btf.json is a BTF, not a BRDF"):
        mi.load_dict({"type": EXTERNAL_MLP_NAME, "filename": str(files["btf"])})


@pytest.mark.parametrize("name", ["hybrid", "plain"])
def test02_eval_is_the_reference_times_cos(
    mi: types.ModuleType, files: dict[str, Path], name: str
) -> None:
    rng = np.random.default_rng(3)
    wi, wo = hemisphere(rng, 2000, 89.0), hemisphere(rng, 2000, 89.0)
    bsdf = mi.load_dict({"type": EXTERNAL_MLP_NAME, "filename": str(files[name])})
    got = np.asarray(bsdf.eval(mi.BSDFContext(), interaction(mi, wi), mi.Vector3f(*wo.T))).T
    ref = read_mlp(files[name]).eval(wi.astype(np.float64), wo.astype(np.float64))
    np.testing.assert_allclose(got, ref * wo[:, 2:3], rtol=1e-4, atol=1e-6)
    below = wo * np.array([1, 1, -1], np.float32)
    assert not np.asarray(
        bsdf.eval(mi.BSDFContext(), interaction(mi, wi), mi.Vector3f(*below.T))
    ).any()


@pytest.mark.parametrize("name", ["hybrid", "plain"])
def test03_sampling(mi: types.ModuleType, files: dict[str, Path], name: str) -> None:
    bsdf = mi.load_dict({"type": EXTERNAL_MLP_NAME, "filename": str(files[name])})
    rng = np.random.default_rng(4)
    for deg in (10.0, 60.0):
        check_pdf_and_sampling(mi, bsdf, deg, 20000, rng)


def _btf_eval(
    mi: types.ModuleType, bsdf: Any, uv: np.ndarray, light: np.ndarray, view: np.ndarray
) -> np.ndarray:
    si = interaction(mi, view)
    si.uv = mi.Point2f(*uv.T)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.dp_dv = mi.Vector3f(0, 1, 0)
    return np.asarray(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*light.T)), np.float64).T


def test04_btf_eval_is_the_reference(mi: types.ModuleType, files: dict[str, Path]) -> None:
    rng = np.random.default_rng(5)
    light, view = hemisphere(rng, 1000, 85.0), hemisphere(rng, 1000, 85.0)
    uv = rng.uniform(0, 1, (1000, 2)).astype(np.float32)
    bsdf = mi.load_dict(
        {
            "type": EXTERNAL_MLP_BTF_NAME,
            "filename": str(files["btf"]),
            "uv_scale_u": 2.0,
            "uv_scale_v": 3.0,
        }
    )
    got = _btf_eval(mi, bsdf, uv, light, view)
    scaled = uv.astype(np.float64) * np.array([2.0, 3.0])
    ref = read_mlp(files["btf"]).eval(light.astype(np.float64), view.astype(np.float64), scaled)
    np.testing.assert_allclose(got, ref, rtol=2e-4, atol=1e-6)


def test05_lambertian_btf_is_mitsubas_diffuse(mi: types.ModuleType, files: dict[str, Path]) -> None:
    rng = np.random.default_rng(6)
    light, view = hemisphere(rng, 500, 89.0), hemisphere(rng, 500, 89.0)
    uv = rng.uniform(0, 1, (500, 2)).astype(np.float32)
    ours = mi.load_dict({"type": EXTERNAL_MLP_BTF_NAME, "filename": str(files["lambert"])})
    diffuse = mi.load_dict(
        {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.2, 0.5, 0.8]}}
    )
    si = interaction(mi, view)
    expected = np.asarray(diffuse.eval(mi.BSDFContext(), si, mi.Vector3f(*light.T))).T
    np.testing.assert_allclose(_btf_eval(mi, ours, uv, light, view), expected, rtol=1e-5)
    assert dr.all(ours.pdf(mi.BSDFContext(), si, mi.Vector3f(*light.T)) > 0)
