"""The relative L2's fittable terms and C below the horizon (fabric review, item 1).

References: the diffuse component of the shading model we fit,
:func:`materials.fabric.shading.diffuse_response`, which is exactly 0 for light from below
the macro surface (``wi.z < 0``); the relative L2's gradient written out by hand,
``dL_c/dp = 2 (p - y) / (N_c (sg(p)^2 + m^2 + EPS))`` (the stop-gradient keeps the
denominator constant), whose bound at a floored scale is analytic; and the torch loss
against its float64 numpy twin.
"""

from __future__ import annotations

import types

import numpy as np
import pytest
import torch

from materials.fabric.array_ops import NumpyOps
from materials.fabric.shading import diffuse_response
from models.fabric.fused import decoder_drjit, decoder_numpy, load_fabric_model
from models.fabric.losses import (
    EPS,
    SCALE_FLOOR,
    fittable_mask,
    linear_prediction,
    relative_l2_loss,
    relative_l2_numpy,
)
from models.fabric.networks import build_network, components, components_numpy
from models.fabric.portable import to_portable

from .conftest import TINY


def _batch(n: int = 64) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Half the queries lit from below, as ``generate.fabric`` draws them; diffuse targets
    0 there and the material's diffuse scale 0 for that kind, as ``component_scales``
    gives them for such data; the specular weft component of a pattern with no weft
    highlight (target and scale 0 everywhere)."""
    rng = np.random.default_rng(5)
    wi_z = torch.from_numpy(np.where(np.arange(n) % 2 == 0, 0.6, -0.6))
    value = torch.from_numpy(rng.uniform(0.05, 0.3, (n, 4)))
    value[wi_z < 0, :2] = 0.0
    value[:, 3] = 0.0
    scale = torch.tensor([[0.2, 0.2, 0.1, 0.0]], dtype=torch.float64).expand(n, 4).clone()
    scale[wi_z < 0, :2] = 0.0
    return wi_z, value, scale


def _raw_for(pred: torch.Tensor, wi_z: torch.Tensor) -> torch.Tensor:
    """Raw outputs whose :func:`linear_prediction` is ``pred`` (inverse of Eq. 9 for S)."""
    k = torch.where(wi_z < 0, 1000.0, 100.0).to(pred.dtype)[:, None]
    return torch.cat([pred[:, :2], torch.log1p(k * pred[:, 2:])], dim=1)


def test01_every_term_has_a_bounded_gradient_near_a_target_it_can_meet() -> None:
    """Predictions 1e-6 off targets the network can meet (the zero diffuse targets below,
    the zero weft target): each term's gradient in the linear prediction is finite and within
    the hand-written bound ``2 |p - y| / (N_c m_floor^2)``. Before the guards the zero-scale
    terms gave ``2 p / (N (p^2 + EPS))``, 3 here for the C terms below the horizon,
    where the guard gives 0."""
    wi_z, value, scale = _batch()
    delta = 1e-6
    raw = _raw_for(value + delta, wi_z).requires_grad_(True)
    parts = relative_l2_loss(raw, value, wi_z, scale)
    assert torch.isfinite(parts.per_component).all()
    # Each raw column moves only its own component: dL/dp_c = (dL/draw_c) / (dp_c/draw_c),
    # and the sum of the four L_c is 4 x total.
    (g_raw,) = torch.autograd.grad(4 * parts.total, raw)
    (dp_draw,) = torch.autograd.grad(linear_prediction(raw, wi_z).sum(), raw)
    grad = g_raw / dp_draw
    keep = torch.from_numpy(fittable_mask(wi_z.numpy()))
    m = torch.maximum(scale, SCALE_FLOOR * scale.amax(dim=1, keepdim=True))
    for c in range(4):
        assert torch.isfinite(grad[:, c]).all(), c
        n_c = max(int(keep[:, c].sum()), 1)
        bound = 2 * delta / (n_c * (m[:, c] ** 2 + EPS))
        # 1e-6: float64 round-off of log1p/expm1 around the 1e-6 offset.
        assert torch.all(grad[:, c].abs() <= bound * (1 + 1e-6)), (c, grad[:, c].abs().max())
        assert torch.all(grad[~keep[:, c], c] == 0.0), c  # dropped terms: no gradient
    # At the targets themselves every gradient is 0.
    exact = _raw_for(value, wi_z).requires_grad_(True)
    relative_l2_loss(exact, value, wi_z, scale).total.backward()
    assert exact.grad is not None and float(exact.grad.abs().max()) < 1e-9


def test02_loss_and_numpy_twin_agree_and_drop_the_unfittable_terms() -> None:
    """The torch loss equals its float64 numpy twin; a C prediction below the horizon
    changes neither (the term is dropped), a C prediction above does."""
    wi_z, value, scale = _batch()
    rng = np.random.default_rng(9)
    pred = value.numpy() * rng.uniform(0.5, 1.5, value.shape) + 0.01
    raw = _raw_for(torch.from_numpy(pred), wi_z)
    parts = relative_l2_loss(raw, value, wi_z, scale)
    twin = relative_l2_numpy(pred, value.numpy(), scale.numpy(), wi_z.numpy())
    # Both float64; the torch side goes through log1p/expm1 (a few ulps): 1e-12 relative.
    np.testing.assert_allclose(float(parts.total), twin, rtol=1e-12)
    below = pred.copy()
    below[wi_z.numpy() < 0, :2] = 5.0
    above = pred.copy()
    above[wi_z.numpy() >= 0, :2] = 5.0
    args = (value.numpy(), scale.numpy(), wi_z.numpy())
    assert relative_l2_numpy(below, *args) == twin
    # C = 5 where y ~ 0.2 is a relative error near 1 in two of four terms (each term is
    # bounded by 1 as p grows, since sg(p)^2 is in the denominator).
    assert relative_l2_numpy(above, *args) > 2 * twin


def test03_c_is_zero_below_the_horizon_in_every_decoder(mi: types.ModuleType) -> None:
    """The shading model's diffuse response is 0 for ``wi.z < 0``; so is C from
    :func:`components`, its numpy twin, the numpy reference decoder and the fused Dr.Jit
    decoder, even where the raw output is positive (no spurious diffuse transmission)."""
    import drjit as dr

    rng = np.random.default_rng(2)
    n = 512
    v = rng.normal(size=(n, 3))
    wi = v / np.linalg.norm(v, axis=1, keepdims=True)
    wo = rng.normal(size=(n, 3))
    wo[:, 2] = np.abs(wo[:, 2]) + 0.05
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    below = wi[:, 2] < 0
    assert 100 < below.sum() < n - 100
    normal = (np.zeros(n), np.zeros(n), np.ones(n))
    shading = diffuse_response(NumpyOps(), tuple(wi.T), tuple(wo.T), normal, 0.5)
    assert np.all(shading[below] == 0.0) and np.all(shading[~below] > 0.0)

    raw = np.full((n, 4), 0.3, dtype=np.float32)
    comp = components(torch.from_numpy(raw), torch.from_numpy(wi[:, 2])).numpy()
    assert np.all(comp[below, :2] == 0) and np.all(comp[~below, :2] == np.float32(0.3))
    assert np.all(components_numpy(raw, wi[:, 2])[below, :2] == 0)
    assert np.all(components_numpy(raw, wi[:, 2])[~below, :2] == np.float32(0.3))

    net = build_network(TINY, 3).eval()
    with torch.no_grad():  # C positive everywhere before the horizon guard
        net.decoder.angular5.bias.copy_(torch.tensor([3.0, 3.0, 1.0, 0.5]))
    z = np.random.default_rng(4).normal(size=(1, TINY.latent_dim)).astype(np.float32)
    doc = to_portable(net, ["m"], ["plain"], [{"alpha": [0.3, 0.4], "beta": [0.5, 0.6]}], z)
    import json

    model = load_fabric_model(json.dumps(doc).encode())
    q = {
        "cx": rng.uniform(0, 1, n).astype(np.float32),
        "cy": rng.uniform(0, 1, n).astype(np.float32),
        "size": rng.uniform(0, 2, n).astype(np.float32),
        "wi": wi.astype(np.float32),
        "wo": wo.astype(np.float32),
    }
    ref = decoder_numpy(model, "m", **q)
    raw_ref = decoder_numpy(model, "m", **q, raw=True)
    assert np.all(raw_ref[:, :2] > 0)
    assert np.all(ref[below, :2] == 0) and np.all(ref[~below, :2] > 0)
    args = [q["cx"], q["cy"], q["size"], *q["wi"].T, *q["wo"][:, :2].T]
    out = decoder_drjit(model, "m", mi.Float)(*(mi.Float(a) for a in args))
    dr.eval(out)
    got = np.stack([o.numpy() for o in out], axis=1)
    assert np.all(got[below, :2] == 0) and np.all(got[~below, :2] > 0)


@pytest.mark.parametrize("addition", ["stderr", "meanterm", "both"])
def test04_each_loss_addition_alone_has_a_bounded_gradient_at_its_targets(addition: str) -> None:
    """The losses that measure the two additions apart (``relative_l2_stderr``: Monte Carlo
    weights only; ``relative_l2_meanterm``: the mean term only; ``relative_l2_mean``: both)
    on the batch above, two material slots: 1e-6 off the targets every gradient is finite
    and within the hand-written bound (the relative L2's ``2 |p - y| / (N_c m_floor^2)``,
    larger denominators only shrink it, plus the mean term's ``2 |r| / (n_g m_floor^2)``),
    and at the targets it is 0."""
    wi_z, value, scale = _batch()
    n = len(value)
    stderr = 0.1 * value if addition in ("stderr", "both") else None  # 0 where the target is
    group = torch.arange(n) // (n // 2) if addition in ("meanterm", "both") else None
    delta = 1e-6
    raw = _raw_for(value + delta, wi_z).requires_grad_(True)
    parts = relative_l2_loss(raw, value, wi_z, scale, stderr=stderr, group=group)
    (g_raw,) = torch.autograd.grad(parts.total, raw)
    (dp_draw,) = torch.autograd.grad(linear_prediction(raw, wi_z).sum(), raw)
    grad = g_raw / dp_draw
    keep = torch.from_numpy(fittable_mask(wi_z.numpy()))
    m = torch.maximum(scale, SCALE_FLOOR * scale.amax(dim=1, keepdim=True))
    smallest_group = n // 4  # two slots x two light sides, 16 rows each
    for c in range(4):
        n_c = max(int(keep[:, c].sum()), 1)
        bound = 2 * delta / (4 * n_c * (m[:, c] ** 2 + EPS))
        if group is not None:
            bound = bound + 2 * delta / (smallest_group * m[:, c] ** 2)
        assert torch.isfinite(grad[:, c]).all(), c
        assert torch.all(grad[:, c].abs() <= bound * (1 + 1e-6)), (c, grad[:, c].abs().max())
        assert torch.all(grad[~keep[:, c], c] == 0.0), c
    exact = _raw_for(value, wi_z).requires_grad_(True)
    relative_l2_loss(exact, value, wi_z, scale, stderr=stderr, group=group).total.backward()
    assert exact.grad is not None and float(exact.grad.abs().max()) < 1e-9


@pytest.mark.parametrize(
    ("loss", "weighted", "mean_term"),
    [("relative_l2", False, False), ("relative_l2_stderr", True, False),
     ("relative_l2_meanterm", False, True), ("relative_l2_mean", True, True)],
)  # fmt: skip
def test05_loss_names_switch_the_additions_on_alone(
    loss: str, weighted: bool, mean_term: bool, synthetic_materials, monkeypatch: pytest.MonkeyPatch
) -> None:  # type: ignore[no-untyped-def]
    """``fit`` passes the stored standard errors and the material slots exactly as the loss
    name says, and trains to finite losses."""
    import dataclasses

    import models.fabric.train as train

    seen: list[tuple[bool, bool]] = []
    original = train.relative_l2_loss

    def record(*args, **kwargs):  # type: ignore[no-untyped-def]
        seen.append((kwargs.get("stderr") is not None, kwargs.get("group") is not None))
        return original(*args, **kwargs)

    monkeypatch.setattr(train, "relative_l2_loss", record)
    mats = [dataclasses.replace(m, stderr=0.01 * np.abs(m.value) + 1e-4)
            for m in synthetic_materials]  # fmt: skip
    config = train.FitConfig(steps=5, batch=64, materials_per_step=2, lr=0.05, momentum=0.9,
                             weight_decay=0.0, clip=1.0, loss=loss)  # fmt: skip
    torch.manual_seed(0)
    net = build_network(TINY, len(mats))
    curves = train.fit(net, train.TrainingSet(mats, "cpu", loss), config,
                       torch.Generator().manual_seed(5))  # fmt: skip
    assert all(np.isfinite(curves.loss))
    assert set(seen) == {(weighted, mean_term)}
