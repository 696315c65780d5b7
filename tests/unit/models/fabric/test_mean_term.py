"""The mean-preserving term and the Monte Carlo weights of ``relative_l2_mean``.

References: closed forms written out by hand (a constant offset ``d`` per cell gives the
mean term ``d^2 / m^2``; its gradient per row is ``2 r / (n_g m^2 n_cells)``), the
analytic limit ``se = 0`` (the plain relative L2), a float64 loop over cells and rows
that does not share the torch code's scatter, and the stationary point of the mean term
(the batch mean of the targets of each cell, the minimiser of a squared mean residual).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from models.fabric.losses import EPS, SCALE_FLOOR, linear_prediction, mean_term, relative_l2_loss
from models.fabric.train import FitConfig, TrainingSet, fit

from .conftest import TINY


def _batch(n: int = 48, seed: int = 3) -> dict[str, torch.Tensor]:
    rng = np.random.default_rng(seed)
    wi_z = rng.uniform(-1, 1, n)
    value = rng.uniform(0.01, 0.3, (n, 4))
    value[wi_z < 0, :2] = 0.0
    scale = rng.uniform(0.05, 0.2, (n, 4))
    group = rng.integers(0, 3, n)
    # a constant scale per (group, side) cell, as component_scales gives per material
    for g in range(3):
        for side in (False, True):
            sel = (group == g) & ((wi_z < 0) == side)
            scale[sel] = scale[sel][:1] if sel.any() else scale[sel]
    t = {"wi_z": wi_z, "value": value, "scale": scale, "group": group}
    t["stderr"] = rng.uniform(0.0, 0.05, (n, 4))
    t["raw"] = rng.normal(0.0, 0.2, (n, 4))
    return {k: torch.tensor(v) for k, v in t.items()}


def _mean_term_loop(pred: np.ndarray, value: np.ndarray, scale: np.ndarray,
                    group: np.ndarray, wi_z: np.ndarray) -> float:  # fmt: skip
    """Float64 reference: explicit loops over cells and components."""
    m = np.maximum(np.abs(scale), SCALE_FLOOR * np.abs(scale).max(axis=1, keepdims=True))
    terms = []
    for g in np.unique(group):
        for below in (False, True):
            rows = np.flatnonzero((group == g) & ((wi_z < 0) == below))
            if len(rows) == 0:
                continue
            for c in range(4):
                if below and c < 2:
                    continue  # C below the horizon is not fitted
                r = np.mean(pred[rows, c] - value[rows, c])
                terms.append(r**2 / np.mean(m[rows, c]) ** 2)
    return float(np.mean(terms))


def test01_mean_term_matches_a_float64_loop() -> None:
    b = _batch()
    pred = linear_prediction(b["raw"], b["wi_z"])
    with_mean = relative_l2_loss(b["raw"], b["value"], b["wi_z"], b["scale"], group=b["group"])
    plain = relative_l2_loss(b["raw"], b["value"], b["wi_z"], b["scale"])
    ref = _mean_term_loop(*(x.numpy() for x in (pred, b["value"], b["scale"], b["group"],
                                                b["wi_z"])))  # fmt: skip
    # float64 throughout; only summation order differs
    assert abs(float(with_mean.total - plain.total) - ref) <= 1e-12 * max(1.0, ref)


def test02_constant_offset_gives_d2_over_m2_and_zero_at_the_mean() -> None:
    b = _batch()
    value, wi_z, group = b["value"], b["wi_z"], b["group"]
    m = b["scale"]
    keep = torch.ones_like(value, dtype=torch.bool)
    keep[:, :2] = (wi_z >= 0)[:, None]
    d = 0.01
    resid = torch.full_like(value, d)
    got = float(mean_term(resid, keep, m, group, wi_z))
    cells = {(int(g), bool(z < 0)) for g, z in zip(group, wi_z, strict=True)}
    ref = np.mean([d**2 / float(m[(group == g) & ((wi_z < 0) == s)][0, c]) ** 2
                   for g, s in cells for c in range(4) if not (s and c < 2)])  # fmt: skip
    assert abs(got - ref) <= 1e-12 * ref  # float64, same formula in a different order
    # zero-mean residual per cell: the term vanishes (its minimiser is the cell's mean)
    noise = torch.randn(value.shape, generator=torch.Generator().manual_seed(1), dtype=value.dtype)
    for g, s in cells:
        sel = (group == g) & ((wi_z < 0) == s)
        noise[sel] -= noise[sel].mean(dim=0)
    assert float(mean_term(noise, keep, m, group, wi_z)) <= 1e-25


def test03_mean_term_gradient_is_finite_bounded_and_analytic() -> None:
    b = _batch()
    raw = b["raw"].clone().requires_grad_(True)
    pred = linear_prediction(raw, b["wi_z"])
    keep = torch.ones_like(pred, dtype=torch.bool)
    keep[:, :2] = (b["wi_z"] >= 0)[:, None]
    resid = (pred - b["value"]).detach().requires_grad_(True)
    mt = mean_term(resid, keep, b["scale"], b["group"], b["wi_z"])
    (grad,) = torch.autograd.grad(mt, resid)
    assert torch.isfinite(grad).all()
    assert float(grad[~keep].abs().max()) == 0.0  # dropped C terms get no gradient at all
    cells = (b["group"] * 2 + (b["wi_z"] < 0).long()).numpy()
    n_cells = int(sum(keep[cells == c].any(dim=0).sum() for c in np.unique(cells)))
    for row in range(len(resid)):
        sel = cells == cells[row]
        for c in range(4):
            if not keep[row, c]:
                continue
            r = float(resid.detach()[sel, c].mean())
            ref = 2 * r / (sel.sum() * float(b["scale"][row, c]) ** 2 * n_cells)
            assert abs(float(grad[row, c]) - ref) <= 1e-10 * max(abs(ref), 1e-12)


def test04_stderr_weights_reduce_to_the_plain_loss_and_down_weight_noise() -> None:
    b = _batch()
    args = (b["raw"], b["value"], b["wi_z"], b["scale"])
    plain = relative_l2_loss(*args)
    zero = relative_l2_loss(*args, stderr=torch.zeros_like(b["stderr"]))
    assert abs(float(plain.total - zero.total)) <= 1e-15  # analytic limit se = 0
    got = relative_l2_loss(*args, stderr=b["stderr"]).per_component.numpy()
    pred = linear_prediction(b["raw"], b["wi_z"]).numpy()
    m = np.abs(b["scale"].numpy())
    m = np.maximum(m, SCALE_FLOOR * m.max(axis=1, keepdims=True))
    d = (pred - b["value"].numpy()) ** 2 / (pred**2 + m**2 + b["stderr"].numpy() ** 2 + EPS)
    keep = np.ones_like(d, dtype=bool)
    keep[b["wi_z"].numpy() < 0, :2] = False
    ref = np.where(keep, d, 0).sum(axis=0) / keep.sum(axis=0)
    np.testing.assert_allclose(got, ref, rtol=1e-12)  # float64 both ways
    # a huge standard error silences a query: its weight goes as 1 / se^2
    se = b["stderr"].clone()
    se[0] = 1e6
    w = relative_l2_loss(*args, stderr=se)
    raw = b["raw"].clone().requires_grad_(True)
    relative_l2_loss(raw, *args[1:], stderr=se).total.backward()
    assert raw.grad is not None and float(raw.grad[0].abs().max()) < 1e-10
    assert torch.isfinite(w.total)


def test05_training_with_relative_l2_mean_runs_and_needs_stderr(synthetic_materials) -> None:  # type: ignore[no-untyped-def]
    from models.fabric.networks import build_network

    mats = [
        dataclasses.replace(m, stderr=0.01 * np.abs(m.value) + 1e-4) for m in synthetic_materials
    ]
    config = FitConfig(steps=20, batch=64, materials_per_step=2, lr=0.05, momentum=0.9,
                       weight_decay=0.0, clip=1.0, loss="relative_l2_mean")  # fmt: skip
    torch.manual_seed(0)
    net = build_network(TINY, len(mats))
    curves = fit(net, TrainingSet(mats, "cpu", "relative_l2_mean"), config,
                 torch.Generator().manual_seed(5))  # fmt: skip
    assert all(np.isfinite(curves.loss))
    try:
        TrainingSet(synthetic_materials, "cpu", "relative_l2_mean")
    except Exception as exc:  # noqa: BLE001
        assert "stderr" in str(exc)
    else:
        raise AssertionError("relative_l2_mean without stderr must fail")


def test06_metrics_mean_ratio_is_the_ratio_of_sums() -> None:
    from models.fabric.report import _errors

    rng = np.random.default_rng(2)
    gt = rng.uniform(0.0, 1.0, (40, 4))
    albedos = rng.uniform(0.1, 0.9, (4, 3))
    out = _errors(1.02 * gt, gt, albedos)
    for c in ("C_warp", "C_weft", "S_warp", "S_weft", "rgb"):
        assert abs(out[c]["ratio"] - 1.02) <= 1e-12  # a uniform 2 % excess, exactly
    assert _errors(gt, np.zeros_like(gt), albedos)["S_warp"]["ratio"] == 1.0  # no target


def test07_curves_carry_the_mean_ratio_of_the_rendered_components(synthetic_materials) -> None:  # type: ignore[no-untyped-def]
    """The series follows the one curves.json schema (``jobapi.documents.check_curves``, a
    group per component), is finite at every point, is drawn, and is absent for the paper
    loss (which carries no linear targets)."""
    from jobapi.documents import check_curves
    from models.fabric.networks import build_network
    from models.fabric.report import curves_png

    config = FitConfig(steps=20, batch=64, materials_per_step=2, lr=0.05, momentum=0.9,
                       weight_decay=0.0, clip=1.0, loss="relative_l2")  # fmt: skip
    torch.manual_seed(0)
    net = build_network(TINY, len(synthetic_materials))
    data = TrainingSet(synthetic_materials, "cpu", "relative_l2")
    curves = fit(net, data, config, torch.Generator().manual_seed(5))
    doc = curves.as_dict()
    check_curves(doc)
    ratio = doc["mean_ratio"]
    assert isinstance(ratio, dict) and set(ratio) == {"C_warp", "C_weft", "S_warp", "S_weft"}
    assert all(len(v) == len(curves.step) and np.isfinite(v).all() for v in ratio.values())
    assert curves_png(curves, "t")[:8] == b"\x89PNG\r\n\x1a\n"
    net = build_network(TINY, len(synthetic_materials))
    plain = TrainingSet(synthetic_materials, "cpu")
    paper_config = dataclasses.replace(config, loss="paper")
    paper = fit(net, plain, paper_config, torch.Generator().manual_seed(5))
    assert "mean_ratio" not in paper.as_dict()
