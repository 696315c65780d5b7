"""User MLP materials (``matforge.mlp-brdf/1``, ``matforge.mlp-btf/1``): export, the numpy
reference, the fused Dr.Jit kernel, and bad files.

Oracles:

- the user's own torch module, run by torch in float32 on features that
  :mod:`tests.helpers.external_models` computes with trig and rotation matrices (not
  matforge's code), plus a Lambert + GGX written there in plain torch: the numpy reference
  :meth:`MlpMaterial.eval` must give the same values (float32 precision, rtol 2e-5);
- the numpy reference for the fused Dr.Jit kernel (float32 precision);
- closed forms for the texture lookup (texel centres, midpoints across the periodic edge).
"""

from __future__ import annotations

import json
import math
import types
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

import matforge.export as export
from models.external import load_external, model_format
from models.external.fused import FusedMlp
from models.external.mlp import read_mlp
from models.fused_mlp import ACTIVATIONS
from storage.formats import mlp_model
from tests.helpers.external_models import difference, ggx_lambert, hemisphere

KD = [0.25, 0.4, 0.1]
ETA = [1.5, 1.6, 1.45]
ALPHA = 0.3
FREQS = [1.0, 2.5]


def _net(n_in: int, n_out: int, seed: int) -> torch.nn.Sequential:
    torch.manual_seed(seed)
    net = torch.nn.Sequential(
        torch.nn.Linear(n_in, 32),
        torch.nn.ReLU(),
        torch.nn.Linear(32, 32),
        torch.nn.Tanh(),
        torch.nn.Linear(32, 16),
        torch.nn.Softplus(),
        torch.nn.Linear(16, n_out),
    )
    with torch.no_grad():
        net[-1].weight.mul_(0.3)
    return net.eval()


def torch_features(wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    """wi, wo, h, d, fourier(wi) with FREQS: the test's own encoding."""
    h = torch.nn.functional.normalize(wi + wo, dim=1)
    cols = [wi, wo, h, difference(wi, h)]
    for f in FREQS:
        cols += [torch.sin(f * wi), torch.cos(f * wi)]
    return torch.cat(cols, 1)


INPUTS = ["wi", "wo", "h", "d", {"type": "fourier", "input": "wi", "frequencies": FREQS}]
N_IN = 12 + 2 * len(FREQS) * 3


@pytest.fixture(scope="module")
def hybrid(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, torch.nn.Module]:
    net = _net(N_IN, 6, 0)
    path = export.brdf_mlp(
        net,
        tmp_path_factory.mktemp("ext") / "hybrid.json",
        inputs=INPUTS,
        output_activation=["exp"] * 3 + ["sigmoid"] * 3,
        analytic={"kd": KD, "alpha": ALPHA, "eta": ETA},
        name="test hybrid",
    )
    return path, net


def pairs(n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    return hemisphere(gen, n), hemisphere(gen, n)


def test01_activation_lists_agree() -> None:
    assert mlp_model.ACTIVATIONS == ACTIVATIONS


def test02_numpy_reference_matches_the_users_torch_module(hybrid: Any) -> None:
    """Hybrid combine f = exp(y[0:3]) + sigmoid(y[3:6]) f_a, f_a the test's torch GGX."""
    path, net = hybrid
    wi, wo = pairs(4000, 1)
    wi32, wo32 = wi.float(), wo.float()
    with torch.no_grad():
        y = net(torch_features(wi32, wo32))
        f_a = ggx_lambert(wi32, wo32, torch.tensor(KD), ALPHA, torch.tensor(ETA))
        expected = (torch.exp(y[:, :3]) + torch.sigmoid(y[:, 3:]) * f_a).double().numpy()
    model = load_external(path, "brdf")
    assert (model.kind, model.runtime) == ("brdf", "drjit-fused")
    n_params = sum(p.numel() for p in net.parameters()) + 7
    assert model.param_bytes == 4 * n_params
    got = model.eval(wi32.double().numpy(), wo32.double().numpy())
    np.testing.assert_allclose(got, expected, rtol=2e-5, atol=1e-7)


def test03_numpy_reference_of_a_plain_network_and_a_sum(tmp_path: Path) -> None:
    net = _net(6, 3, 4)
    wi, wo = pairs(500, 2)
    p1 = export.brdf_mlp(
        list(net.children())[::2],
        tmp_path / "a.json",
        activations=["relu", "tanh", "softplus", "identity"],
        output_activation="softplus",
    )
    p2 = export.brdf_mlp(
        net, tmp_path / "b.json", combine="sum", analytic={"kd": KD, "alpha": 0.5, "eta": 1.5}
    )
    with torch.no_grad():
        y = net(torch.cat([wi, wo], 1).float()).double()
        f_a = ggx_lambert(wi, wo, torch.tensor(KD, dtype=torch.float64), 0.5, torch.tensor(1.5))
    np.testing.assert_allclose(
        read_mlp(p1).eval(wi.numpy(), wo.numpy()),
        torch.nn.functional.softplus(y).numpy(),
        rtol=2e-5,
        atol=1e-7,
    )
    expected = np.maximum((y + f_a).numpy(), 0.0)  # the format clamps at 0
    np.testing.assert_allclose(
        read_mlp(p2).eval(wi.numpy(), wo.numpy()), expected, rtol=2e-5, atol=1e-6
    )
    # Below the horizon: 0.
    below = wi.numpy().copy()
    below[:, 2] *= -1
    assert not read_mlp(p2).eval(below, wo.numpy()).any()


def test04_btf_texture_lookup_and_network(tmp_path: Path) -> None:
    """NeuMIP-like: [texture(uv), wi.xy, wo.xy] -> RGB; texel centres give the texel, a
    midpoint across the periodic edge the mean of the two edge texels."""
    gen = torch.Generator().manual_seed(3)
    tex = torch.rand(4, 5, 6, generator=gen)
    net = _net(4 + 4, 3, 5)
    path = export.btf_mlp(
        net,
        tmp_path / "btf.json",
        textures=[tex],
        inputs=[{"type": "texture", "index": 0}, "wi.xy", "wo.xy"],
        output_activation="exp",
    )
    model = load_external(path, "btf")
    assert model.kind == "btf" and model.param_bytes == 4 * (
        tex.numel() + sum(p.numel() for p in net.parameters())
    )
    j, i = np.meshgrid(np.arange(5), np.arange(6), indexing="ij")
    uv = np.stack([(i.ravel() + 0.5) / 6 + 3.0, (j.ravel() + 0.5) / 5 - 1.0], 1)  # periodic
    wi, wo = (t.numpy() for t in pairs(30, 4))
    with torch.no_grad():
        feats = tex.reshape(4, -1).T
        expected = torch.exp(
            net(
                torch.cat(
                    [
                        feats,
                        torch.from_numpy(wi[:, :2]).float(),
                        torch.from_numpy(wo[:, :2]).float(),
                    ],
                    1,
                )
            )
        )
    np.testing.assert_allclose(model.eval(wi, wo, uv), expected.numpy(), rtol=2e-5, atol=1e-7)
    # Midpoint between texel columns W-1 and 0 (u = 0 wraps), row 2.
    feats_mid = 0.5 * (tex[:, 2, 5] + tex[:, 2, 0])
    with torch.no_grad():
        x = torch.cat(
            [feats_mid, torch.from_numpy(wi[0, :2]).float(), torch.from_numpy(wo[0, :2]).float()]
        )[None]
        mid = torch.exp(net(x)).numpy()
    got = model.eval(wi[:1], wo[:1], np.array([[0.0, 2.5 / 5]]))
    np.testing.assert_allclose(got, mid, rtol=2e-5)
    with pytest.raises(ValueError, match="uv"):
        model.eval(wi, wo)


def _dr_dirs(mi: types.ModuleType, v: np.ndarray) -> Any:
    return mi.Vector3f(*(mi.Float(np.ascontiguousarray(c, np.float32)) for c in v.T))


def test05_fused_kernel_matches_the_numpy_reference(
    mi: types.ModuleType, hybrid: Any, tmp_path: Path
) -> None:
    path, _ = hybrid
    wi, wo = (t.float().double().numpy() for t in pairs(3000, 6))
    model = read_mlp(path)
    got = np.asarray(FusedMlp(model, mi).eval(_dr_dirs(mi, wi), _dr_dirs(mi, wo)), np.float64).T
    np.testing.assert_allclose(got, model.eval(wi, wo), rtol=1e-4, atol=1e-6)
    # A BTF with two textures, uv, cos terms, fourier of h, and foreshortening applied.
    gen = torch.Generator().manual_seed(7)
    texs = [torch.rand(3, 8, 4, generator=gen), torch.rand(2, 3, 5, generator=gen)]
    inputs = [
        {"type": "texture", "index": 1},
        "uv",
        "cos_i",
        "cos_o",
        "cos_h",
        "cos_d",
        {"type": "texture", "index": 0},
        {"type": "fourier", "input": "h", "frequencies": [3.0]},
        "d",
    ]
    net = _net(2 + 2 + 4 + 3 + 6 + 3, 3, 8)
    p = export.btf_mlp(
        net,
        tmp_path / "b.json",
        textures=texs,
        inputs=inputs,
        output_activation="sigmoid",
        foreshortening="apply",
    )
    btf = read_mlp(p)
    uv = np.random.default_rng(9).uniform(-2, 3, (3000, 2)).astype(np.float32)
    uv_dr = mi.Point2f(*(mi.Float(np.ascontiguousarray(c)) for c in uv.T))
    got = np.asarray(FusedMlp(btf, mi).eval(_dr_dirs(mi, wi), _dr_dirs(mi, wo), uv_dr)).T
    np.testing.assert_allclose(got, btf.eval(wi, wo, uv.astype(np.float64)), rtol=2e-4, atol=1e-5)


def _doc(tmp_path: Path, doc: dict[str, Any], name: str = "bad.json") -> Path:
    p = tmp_path / name
    p.write_text(json.dumps(doc))
    return p


def _good() -> dict[str, Any]:
    return {
        "format": "matforge.mlp-brdf/1",
        "inputs": ["wi", "wo"],
        "layers": [
            {"weight": [[0.1] * 6] * 4, "bias": [0.0] * 4, "activation": "relu"},
            {"weight": [[0.1] * 4] * 3, "bias": [0.0] * 3, "activation": "identity"},
        ],
        "output": {"activation": "exp", "combine": "network"},
    }


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: d.update(format="matforge.mlp-brdf/9"), "format"),
        (lambda d: d.update(inputs=["wi", "wx"]), r"inputs\[1\]: unknown input 'wx'"),
        (
            lambda d: d.update(inputs=["wi"]),
            r"layers\[0\].weight: takes 6 inputs but the inputs give 3",
        ),
        (lambda d: d["layers"][1].update(bias=[0.0]), r"layers\[1\].bias: 1 values for 3 rows"),
        (lambda d: d["layers"][0].update(activation="gelu"), r"layers\[0\].activation"),
        (lambda d: d["layers"][1].update(weight=[[0.1] * 5] * 3), r"layers\[1\].weight: takes 5"),
        (lambda d: d["output"].update(combine="hybrid"), "needs an analytic part"),
        (
            lambda d: d.update(
                analytic={"kd": [0.1] * 3, "alpha": 0.2, "eta": [0.5] * 3},
                output={"combine": "sum"},
            ),
            "analytic.eta",
        ),
        (lambda d: d["layers"][0].update(weight=[[1e39] * 6] * 4), "float32"),
        (lambda d: d.update(extra=1), "unknown key 'extra'"),
        (lambda d: d.update(inputs=["uv", "wi", "wo"]), "unknown input 'uv'"),  # BRDF: no uv
        (lambda d: d["layers"][0].update(weight=[[0.1] * 6] * 600), "1 to 512 rows"),
        (lambda d: d.update(layers=[d["layers"][0]] * 33), "at most 32"),
    ],
)
def test06_bad_documents_name_the_file_and_the_problem(
    tmp_path: Path, change: Any, message: str
) -> None:
    doc = _good()
    read_mlp(_doc(tmp_path, doc, "good.json"))
    change(doc)
    with pytest.raises(ValueError, match=r"bad\.json") as err:
        read_mlp(_doc(tmp_path, doc))
    assert err.match(message)


def test07_bad_files_and_dispatch(tmp_path: Path) -> None:
    p = tmp_path / "x.json"
    p.write_text("{not json")
    with pytest.raises(ValueError, match="x.json: not a readable JSON"):
        read_mlp(p)
    p.write_bytes(b"\x08\x07\x12\x04abcd")  # an ONNX ModelProto starts with ir_version
    assert model_format(p) == "onnx"
    p.write_bytes(b"GIF89a")
    with pytest.raises(ValueError, match="neither an MLP material"):
        model_format(p)
    good = _doc(tmp_path, _good(), "m.json")
    with pytest.raises(ValueError, match="m.json: is a brdf model, not a btf one"):
        load_external(good, "btf")
    with pytest.raises(ValueError, match="kind must be"):
        load_external(good, "bssrdf")
    # A texture whose base64 payload is cut short.
    doc = {
        "format": "matforge.mlp-btf/1",
        "inputs": [{"type": "texture"}, "wi", "wo"],
        "layers": [{"weight": [[0.1] * 8] * 3, "bias": [0.0] * 3, "activation": "identity"}],
        "output": {"combine": "network"},
        "textures": [mlp_model.texture_entry(np.ones((2, 4, 4), np.float32))],
    }
    read_mlp(_doc(tmp_path, doc, "t.json"))
    doc["textures"][0]["data"] = doc["textures"][0]["data"][:-8]
    with pytest.raises(ValueError, match=r"t.json: .*textures\[0\].data: wrong length"):
        read_mlp(_doc(tmp_path, doc, "t.json"))


def test08_export_refuses_what_it_cannot_write(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="cannot export a GELU"):
        export.brdf_mlp(
            torch.nn.Sequential(torch.nn.Linear(6, 3), torch.nn.GELU()), tmp_path / "g.json"
        )
    with pytest.raises(ValueError, match="layers.0..weight: takes 6 inputs but the inputs give 9"):
        export.brdf_mlp(
            torch.nn.Sequential(torch.nn.Linear(6, 3)),
            tmp_path / "g.json",
            inputs=["wi", "wo", "h"],
        )
    assert not (tmp_path / "g.json").exists()
    assert math.isfinite(
        read_mlp(
            export.brdf_mlp(
                None, tmp_path / "a.json", analytic={"kd": KD, "alpha": ALPHA, "eta": ETA}
            )
        ).eval(np.array([[0, 0, 1.0]]), np.array([[0, 0, 1.0]]))[0, 0]
    )


def test09_protocol_and_lazy_torch(tmp_path: Path) -> None:
    import subprocess
    import sys

    from models.external import ExternalModel

    assert isinstance(read_mlp(_doc(tmp_path, _good(), "m.json")), ExternalModel)
    code = "import sys, matforge, matforge.export; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


@pytest.mark.parametrize("kind", ["hybrid", "neural", "analytic"])
def test10_a_train_brdf_material_is_an_mlp_document(kind: str) -> None:
    """The identity of :mod:`models.external.convert`, against ``eval_portable`` (the
    reference of ``matforge.brdf-model/1``)."""
    from models.brdf.portable import eval_portable
    from models.external.convert import brdf_material_as_mlp
    from models.external.mlp import mlp_from_document
    from tests.helpers.brdf_models import make_model

    doc = make_model(kind, 16, 2, 4)
    name = doc["materials"][1]["name"]
    mlp = mlp_from_document(json.loads(json.dumps(brdf_material_as_mlp(doc, name))))
    wi, wo = (t.numpy() for t in pairs(2000, 11))
    np.testing.assert_allclose(
        mlp.eval(wi, wo), eval_portable(doc, name, wi, wo), rtol=1e-6, atol=1e-9
    )
