"""Data, loss and fitting loop of ``train.brdf``.

Oracles: :func:`materials.halfdiff.lookup` (numpy) for the torch table lookup; the moments of
the cosine-weighted distribution; the closed form of Eq. 5; and invariants of the loop:
determinism, frozen network weights, the divergence guard.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from evaluators.metrics.brdf import direction_pairs
from jobapi.errors import JobFailed
from materials import halfdiff as hd
from models.brdf.data import cosine_pairs, lookup_tables
from models.brdf.losses import joint_loss, log_cos_error
from models.brdf.networks import Architecture, BrdfOutput, build_model
from models.brdf.train import FitConfig, deterministic_torch, fit


def random_table(seed: int, missing: float = 0.02) -> np.ndarray:
    rng = np.random.default_rng(seed)
    rgb = rng.random((90, 90, 180, 3)) * 3.0
    rgb[rng.random((90, 90, 180)) < missing] = -1.0
    return rgb


def lambert_tables(albedos: list[float]) -> torch.Tensor:
    """``(M, 90, 90, 180, 3)`` float32 tables of Lambertian materials (albedo / pi)."""
    return torch.stack([torch.full((90, 90, 180, 3), a / math.pi) for a in albedos])


def test01_torch_lookup_matches_numpy_lookup() -> None:
    tables = [random_table(1), random_table(2, missing=0.5)]
    wi, wo = direction_pairs(4000, seed=3)
    stacked = torch.from_numpy(np.stack(tables).astype(np.float32))
    wi_t = torch.from_numpy(wi)[None].expand(2, -1, -1)
    wo_t = torch.from_numpy(wo)[None].expand(2, -1, -1)
    got = lookup_tables(stacked, wi_t, wo_t).double().numpy()
    for m, rgb in enumerate(tables):
        ref = hd.lookup(rgb.astype(np.float32).astype(np.float64), wi, wo, interpolate=True)
        # torch interpolates in float32 (weights and an 8-corner sum: a few ulps of values up
        # to 3, ~1e-6 at worst), numpy in float64; measured a tenth of this bound.
        np.testing.assert_allclose(got[m], ref, rtol=2e-6, atol=1e-6)
    assert np.any(got[1] < 0)  # some pairs see only missing corners in the sparse table


def test02_cosine_pairs_are_cosine_weighted() -> None:
    gen = torch.Generator().manual_seed(0)
    wi, wo = cosine_pairs(2, 50_000, gen)
    assert wi.shape == wo.shape == (2, 50_000, 3)
    for w in (wi, wo):
        torch.testing.assert_close(w.norm(dim=-1), torch.ones(2, 50_000, dtype=torch.float64))
        assert bool((w[..., 2] > 0).all())
        # pdf cos/pi: E[cos] = 2/3, E[cos^2] = 1/2
        assert abs(float(w[..., 2].mean()) - 2 / 3) < 0.005
        assert abs(float((w[..., 2] ** 2).mean()) - 0.5) < 0.005


def test03_loss_is_eq5_and_skips_missing_pairs() -> None:
    ref = torch.tensor([[[1.0, 2.0, 3.0], [5.0, 5.0, 5.0]]])
    f = torch.tensor([[[2.0, 2.0, 1.0], [0.0, 0.0, 0.0]]])
    cos = torch.tensor([[[0.5], [0.9]]])
    expected = sum(
        (math.log1p(0.5 * a) - math.log1p(0.5 * b)) ** 2 for a, b in ((1, 2), (2, 2), (3, 1))
    )
    assert math.isclose(float(log_cos_error(ref, f, cos)[0, 0]), expected, rel_tol=1e-6)
    valid = torch.tensor([[True, False]])
    out = BrdfOutput(f=f, f_a=f * 2.0)
    parts = joint_loss("hybrid", out, ref, cos, valid)
    assert parts.hybrid is not None and parts.analytic is not None
    assert math.isclose(float(parts.hybrid), expected, rel_tol=1e-6)
    assert math.isclose(float(parts.total), float(parts.hybrid + parts.analytic), rel_tol=1e-6)
    assert joint_loss("neural", out, ref, cos, valid).analytic is None
    assert joint_loss("analytic", out, ref, cos, valid).hybrid is None


def _fit(arch: Architecture, tables: torch.Tensor, seed: int, **cfg: object) -> torch.nn.Module:
    settings = {"steps": 20, "batch_pairs": 64, "lr": 0.005, "weight_decay": 0.01, "clip": 0.01}
    settings.update(cfg)
    model = build_model(arch, tables.shape[0], torch.Generator().manual_seed(seed))
    with deterministic_torch():
        fit(model, tables, FitConfig(**settings), torch.Generator().manual_seed(seed + 1))  # type: ignore[arg-type]
    return model


def test04_fit_is_deterministic_and_learns() -> None:
    tables = lambert_tables([0.2, 0.8])
    arch = Architecture("analytic", 0, 0, 0)
    a = _fit(arch, tables, 0, steps=300, lr=0.05, clip=1.0)
    b = _fit(arch, tables, 0, steps=300, lr=0.05, clip=1.0)
    for (k, v), (_, w) in zip(a.state_dict().items(), b.state_dict().items(), strict=True):
        assert torch.equal(v, w), k
    kd = torch.sigmoid(a.state_dict()["raw_kd"])
    assert float(kd[1].mean()) > float(kd[0].mean())  # the brighter material got the larger kd


def test05_frozen_network_stays_bit_identical() -> None:
    tables = lambert_tables([0.3])
    arch = Architecture("hybrid", 16, 2, 4)
    model = build_model(arch, 1, torch.Generator().manual_seed(0))
    before = [p.detach().clone() for p in model.network_parameters()]
    mats = [p.detach().clone() for p in model.material_parameters()]
    cfg = FitConfig(steps=10, batch_pairs=64, lr=0.01, weight_decay=0.5, clip=1.0,
                    train_network=False)  # fmt: skip
    with deterministic_torch():
        fit(model, tables, cfg, torch.Generator().manual_seed(1))
    for p, q in zip(model.network_parameters(), before, strict=True):
        assert torch.equal(p, q)
    moved = [not torch.equal(p, q) for p, q in zip(model.material_parameters(), mats, strict=True)]
    assert any(moved)


def test06_divergence_fails_with_a_clear_message() -> None:
    tables = lambert_tables([0.5])
    with pytest.raises(JobFailed, match=r"train: training diverged at step \d+/50.*Lower lr"):
        _fit(Architecture("neural", 16, 2, 11), tables, 0, steps=50, lr=1e4, clip=1e6)
