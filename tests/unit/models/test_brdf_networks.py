"""The BRDF models of ``train.brdf``: analytic part, heads, constraints, portable format.

Oracles: :mod:`materials.microfacet` (numpy, float64, written independently of the torch
code) for Eq. 3; the definitions of the heads (Eq. 1-2: ``exp`` and ``sigmoid``); the
stated parameter ranges; the pure-numpy evaluator of ``model.json`` for the whole forward.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from evaluators.metrics.brdf import direction_pairs
from materials import microfacet as mf
from models.brdf.networks import (
    ALPHA_MIN,
    ANALYTIC_PARAMS,
    Architecture,
    BrdfModel,
    alpha_from_raw,
    analytic_brdf,
    build_model,
    equal_neural_latent,
    eta_from_raw,
    kd_from_raw,
    raw_from_constrained,
)
from models.brdf.portable import (
    FORMAT,
    checkpoint_bytes,
    eval_portable,
    from_portable,
    load_checkpoint,
    to_portable,
)

ARCHS = {
    "hybrid": Architecture("hybrid", 16, 2, 4),
    "neural": Architecture("neural", 16, 3, equal_neural_latent(4)),
    "analytic": Architecture("analytic", 0, 0, 0),
}


def pairs(n: int = 2000, seed: int = 7) -> tuple[np.ndarray, np.ndarray]:
    return direction_pairs(n, seed=seed)


def numpy_ggx_lambert(
    wi: np.ndarray, wo: np.ndarray, kd: np.ndarray, eta: np.ndarray, alpha: float
) -> np.ndarray:
    """Eq. 3 from materials.microfacet: Lambert + GGX with the exact dielectric Fresnel,
    one channel at a time (``fresnel_dielectric`` takes a scalar IOR)."""
    out = np.empty((len(wi), 3))
    for c in range(3):

        def fresnel(cos_d: np.ndarray, e: float = float(eta[c])) -> np.ndarray:
            return np.broadcast_to(mf.fresnel_dielectric(cos_d, e), cos_d.shape[:-1] + (3,))

        out[:, c] = kd[c] / np.pi + mf.specular_brdf(wi, wo, alpha, fresnel)[:, c]
    return out


def perturbed(arch: Architecture, n_materials: int = 3, seed: int = 0) -> BrdfModel:
    """A model with random weights and per-material values away from the defaults."""
    gen = torch.Generator().manual_seed(seed)
    model = build_model(arch, n_materials, gen)
    with torch.no_grad():
        for p in model.material_parameters():
            p.add_(torch.randn(p.shape, generator=gen) * 0.7)
    return model


@pytest.mark.parametrize("alpha", [0.02, 0.3, 0.9])
def test01_analytic_part_equals_numpy_microfacet(alpha: float) -> None:
    wi, wo = pairs()
    kd = np.array([0.1, 0.5, 0.9])
    eta = np.array([1.2, 2.5, 9.0])
    ref = numpy_ggx_lambert(wi, wo, kd, eta, alpha)
    got = analytic_brdf(
        torch.from_numpy(wi),
        torch.from_numpy(wo),
        torch.from_numpy(kd),
        torch.from_numpy(eta),
        torch.tensor([alpha], dtype=torch.float64),
    ).numpy()
    np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-12)


def test02_model_analytic_part_uses_its_constrained_params() -> None:
    model = perturbed(ARCHS["hybrid"]).double()
    wi, wo = pairs(500)
    kd, eta, alpha = (t.detach().numpy() for t in model.analytic_params())
    with torch.no_grad():
        out = model(torch.from_numpy(wi)[None].expand(3, -1, -1),
                    torch.from_numpy(wo)[None].expand(3, -1, -1))  # fmt: skip
    assert out.f_a is not None
    for m in range(3):
        ref = numpy_ggx_lambert(wi, wo, kd[m], eta[m], float(alpha[m, 0]))
        np.testing.assert_allclose(out.f_a[m].numpy(), ref, rtol=1e-10, atol=1e-12)


def test03_hybrid_heads_are_exp_and_sigmoid() -> None:
    model = perturbed(ARCHS["hybrid"]).double()
    wi, wo = (torch.from_numpy(a)[None].expand(3, -1, -1) for a in pairs(300))
    with torch.no_grad():
        out = model(wi, wo)
        z = model.z[:, None, :].expand(3, 300, 4)
        assert model.mlp is not None
        raw = model.mlp(torch.cat([wi, wo, z], dim=-1))
    assert out.f_c is not None and out.f_g is not None and out.f_a is not None
    torch.testing.assert_close(out.f_c, torch.exp(raw[..., :3]), rtol=0, atol=0)
    torch.testing.assert_close(out.f_g, 1.0 / (1.0 + torch.exp(-raw[..., 3:])))
    torch.testing.assert_close(out.f, out.f_c + out.f_g * out.f_a, rtol=0, atol=0)
    assert bool((out.f_c > 0).all()) and bool(((out.f_g >= 0) & (out.f_g <= 1)).all())


def test04_parameter_ranges_and_inverse() -> None:
    raw = torch.linspace(-60.0, 60.0, 241, dtype=torch.float64)
    kd, eta, alpha = kd_from_raw(raw), eta_from_raw(raw), alpha_from_raw(raw)
    assert float(kd.min()) >= 0.0 and float(kd.max()) <= 1.0
    assert float(eta.min()) >= 1.0 and float(eta.max()) <= 10.0
    assert float(alpha.min()) >= ALPHA_MIN * (1 - 1e-12) and float(alpha.max()) <= 1.0
    inner = torch.linspace(-5.0, 5.0, 11, dtype=torch.float64)
    back = raw_from_constrained(kd_from_raw(inner), eta_from_raw(inner), alpha_from_raw(inner))
    for b in back:
        torch.testing.assert_close(b, inner, rtol=1e-8, atol=1e-8)
    # log-uniform alpha: the midpoint of the raw range is the geometric mean of the range
    mid = float(alpha_from_raw(torch.tensor(0.0, dtype=torch.float64)))
    assert math.isclose(mid, math.sqrt(ALPHA_MIN), rel_tol=1e-12)


def test05_per_material_parameter_counts_are_equal() -> None:
    for lat in (4, 8):
        hybrid = Architecture("hybrid", 32, 3, lat)
        neural = Architecture("neural", 32, 3, equal_neural_latent(lat))
        assert hybrid.per_material_params == neural.per_material_params == ANALYTIC_PARAMS + lat
        for arch in (hybrid, neural):  # the floats the model actually stores per material
            model = BrdfModel(arch, 5)
            stored = sum(p.numel() for p in model.material_parameters()) // 5
            assert stored == arch.per_material_params
    # The paper's 12 and 16 count an anisotropic alpha (8 analytic floats): l + 8.
    assert Architecture("neural", 32, 3, 4 + 8).per_material_params == 12
    assert Architecture("analytic", 0, 0, 0).per_material_params == ANALYTIC_PARAMS


@pytest.mark.parametrize("kind", list(ARCHS))
def test06_portable_numpy_evaluator_reproduces_torch(kind: str) -> None:
    model = perturbed(ARCHS[kind])
    names, families = ["a", "b", "c"], ["metal", "paint", "metal"]
    doc = to_portable(model, names, families)
    assert doc["format"] == FORMAT and doc["architecture"]["per_material_params"] == (
        ARCHS[kind].per_material_params
    )
    wi, wo = pairs(1500)
    model64 = perturbed(ARCHS[kind]).double()  # the same model in float64, and its document
    doc64 = to_portable(model64, names, families)
    for m, name in enumerate(names):
        index = torch.tensor([m])
        with torch.no_grad():
            f32 = model(torch.from_numpy(wi).float()[None], torch.from_numpy(wo).float()[None],
                        index).f[0].double().numpy()  # fmt: skip
            f64 = model64(torch.from_numpy(wi)[None], torch.from_numpy(wo)[None], index).f[0]
        # The trained (float32) model against its model.json: float32 rounding only, within
        # 1e-5 almost everywhere; GGX's D cancels digits near a sharp peak (up to ~2e-5).
        ref = eval_portable(doc, name, wi, wo)
        rel = np.abs(f32 - ref) / (np.abs(ref) + 1e-7)
        assert np.quantile(rel, 0.99) < 1e-5 and rel.max() < 1e-4, rel.max()
        # In float64 the two implementations agree to rounding: the same function.
        np.testing.assert_allclose(
            f64.numpy(), eval_portable(doc64, name, wi, wo), rtol=1e-10, atol=1e-13
        )


def test07_portable_below_horizon_and_errors() -> None:
    doc = to_portable(perturbed(ARCHS["hybrid"]), ["a", "b", "c"], ["x", "x", "x"])
    wi = np.array([[0.0, 0.6, 0.8], [0.0, 0.6, -0.8]])
    wo = np.array([[0.0, -0.6, 0.8], [0.0, -0.6, 0.8]])
    out = eval_portable(doc, "b", wi, wo)
    assert np.all(out[0] > 0) and np.all(out[1] == 0)
    with pytest.raises(ValueError, match="no material 'zz'"):
        eval_portable(doc, "zz", wi, wo)
    with pytest.raises(ValueError, match="not a matforge.brdf-model/1"):
        eval_portable({**doc, "format": "other"}, "a", wi, wo)


@pytest.mark.parametrize("kind", list(ARCHS))
def test08_checkpoint_and_portable_round_trips(kind: str) -> None:
    model = perturbed(ARCHS[kind])
    data = checkpoint_bytes(model, ["a", "b", "c"], ["f", "g", "f"])
    assert data == checkpoint_bytes(model, ["a", "b", "c"], ["f", "g", "f"])
    back, names, families = load_checkpoint(data)
    assert names == ["a", "b", "c"] and families == ["f", "g", "f"]
    for (k, v), (k2, v2) in zip(model.state_dict().items(), back.state_dict().items(), strict=True):
        assert k == k2 and torch.equal(v, v2)
    doc = to_portable(model, names, families)
    again, _, _ = from_portable(doc)
    for net_a, net_b in zip(model.network_parameters(), again.network_parameters(), strict=True):
        assert torch.equal(net_a, net_b)  # weights are written exactly
    wi, wo = pairs(200)
    for name in names:
        np.testing.assert_allclose(
            eval_portable(to_portable(again, names, families), name, wi, wo),
            eval_portable(doc, name, wi, wo),
            rtol=1e-5,
        )
