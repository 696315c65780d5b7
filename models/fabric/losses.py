"""The training loss of Chen, Wang & Wang 2024, Eq. 9-11.

Eq. 9 (specular): the targets are log-mapped, ``g(x) = ln(k x + 1)`` (as NeuMIP), with
``k = 100`` for BRDF queries and ``k = 1000`` for BTDF queries (``wi.z < 0``), and the
network output is compared with ``g(S)`` directly: ``Loss_S = mean (f_pred - g(f_gt))^2``.
Eq. 10 (diffuse): ``Loss_C = mean (f_pred - f_gt)^2`` in linear units.
Eq. 11: ``Loss = sum_{i in warp, weft} lambda_S Loss_S^i + lambda_C Loss_C^i`` with
``lambda_S = 0.4``, ``lambda_C = 0.1``; each term is a mean over the batch's queries.

Targets are the Monte Carlo estimates of ``generate.fabric`` (unit albedos, incident cosine
included, Eq. 3); specular estimates are clamped at 0 before the log (they are ratios of
non-negative sums, so this only guards against corrupt data).

Eq. 9 fits ``E[ln(1 + k S)]``; mapped back, ``expm1(E[ln(1 + k S)]) / k <= E[S]`` (Jensen),
so the paper's loss biases the specular components low wherever the target varies within
what the inputs resolve (issue 12). ``loss: "relative_l2"`` (:func:`relative_l2_loss`) is
unbiased in linear units: per component ``c``,

    L_c = mean_n (p_c - y_c)^2 / (sg(p_c)^2 + m_c^2 + EPS),

with ``p`` the decoded components (C raw, S ``expm1(raw) / k``: the inverse of Eq. 9
without the clamps, so no gradient is cut), ``sg`` a stop-gradient and ``m_c`` the
material's mean training target of component ``c`` for the query's kind (BRDF or BTDF):
a constant per material, independent of the batch. Its gradient in ``p`` is
``2 (p - y) / (sg(p)^2 + m^2 + EPS)``, whose denominator does not depend on ``y``, so for
a fixed input the stationary point is ``p = E[y | input]``, the conditional mean (the
relative L2 of Lehtinen et al. 2018 and Mueller et al. 2021, with the material's scale
``m`` in place of a small constant so that near-zero targets do not dominate). Each term
is dimensionless, so the four are weighted equally (``mean_c L_c``): C and S balanced.

Two guards keep every term fittable. The diffuse components are exactly 0 for light from
below the macro surface (``wi.z < 0``: :func:`materials.fabric.shading.diffuse_response`),
and so is the material's scale ``m`` there; with ``y = m = 0`` the term would be
``p^2 / (p^2 + EPS)``, near 1 whatever ``p`` is, with a gradient ``~2 / p`` that grows as
``p`` goes to 0 and took ~99 % of every clipped update. Those C terms are dropped
(:func:`fittable_mask`; the decoders output C = 0 there, see
:func:`models.fabric.networks.components`), and each ``L_c`` is the mean over the rows that
keep it. And no scale is zero: ``m_c`` is floored at :data:`SCALE_FLOOR` of the row's
largest component scale, so ``|dL/dp| <= 2 |p - y| / (N m_floor^2)``, bounded and 0 at the
target.

``loss: "relative_l2_mean"`` adds two things to the relative L2 (:func:`relative_l2_loss`
with ``stderr`` and ``group``). Monte Carlo weights: each term's denominator gains the
query's stored squared standard error ``se_c^2`` (``generate.fabric``'s ``stderr``), so a
noisy estimate weighs less, ``(p - y)^2 / (sg(p)^2 + m^2 + se^2 + EPS)``; the weight does not
depend on ``p``, so a query's stationary point stays its target. A mean-preserving term:
the relative L2 weights a query by ``1 / (p^2 + m^2)``, so where the network cannot fit
everything, bright queries lose and the material's mean drifts. Per group ``g`` (a material
of the batch and its light side, BRDF or BTDF) and component ``c``,

    M_gc = (mean_{n in g} (p_nc - y_nc))^2 / m_gc^2,

is 0 exactly when the batch's mean prediction of that group equals its mean target, and
``MEAN_WEIGHT * mean_{g, c} M_gc`` joins the total (the C terms of light from below are
left out, as above). Its gradient is ``2 r_gc / (n_g m_gc^2)`` per row, bounded by the
floored scale.

Each addition alone, to measure them apart: ``loss: "relative_l2_stderr"`` (the Monte
Carlo weights only) and ``loss: "relative_l2_meanterm"`` (the mean-preserving term only);
``relative_l2_mean`` has both (:data:`STDERR_LOSSES`, :data:`MEAN_TERM_LOSSES`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from models.fabric.networks import K_BRDF, K_BTDF, log_k

#: Eq. 11 weights (Sec. 4.2: "set as 0.4 and 0.1 in practice").
LAMBDA_S, LAMBDA_C = 0.4, 0.1
#: Training losses: Eq. 9-11 and the unbiased relative L2.
LOSSES: tuple[str, ...] = (
    "paper",
    "relative_l2",
    "relative_l2_mean",
    "relative_l2_stderr",
    "relative_l2_meanterm",
)
#: The relative L2 losses with the Monte Carlo weights (stored standard errors).
STDERR_LOSSES: tuple[str, ...] = ("relative_l2_mean", "relative_l2_stderr")
#: The relative L2 losses with the mean-preserving term.
MEAN_TERM_LOSSES: tuple[str, ...] = ("relative_l2_mean", "relative_l2_meanterm")
#: Weight of the mean-preserving term of ``relative_l2_mean`` against the relative L2.
MEAN_WEIGHT = 1.0
#: Floor of the relative L2's denominator (squared component units).
EPS = 1e-8
#: Largest raw specular output the relative L2 exponentiates (``expm1(30) / 100`` = 1e11).
RAW_MAX = 30.0
#: Floor of a component's scale, as a fraction of the row's largest component scale.
SCALE_FLOOR = 0.01


def log_targets(value: Tensor, wi_z: Tensor) -> Tensor:
    """``(N, 4)`` targets of the raw outputs: ``C`` as is, ``S`` through Eq. 9's ``g``."""
    k = log_k(wi_z)[:, None]
    return torch.cat([value[:, :2], torch.log1p(k * value[:, 2:].clamp_min(0.0))], dim=1)


def log_targets_numpy(value: np.ndarray, wi_z: np.ndarray) -> np.ndarray:
    """numpy twin of :func:`log_targets`, float64."""
    k = np.where(np.asarray(wi_z) < 0, K_BTDF, K_BRDF)[:, None]
    v = np.asarray(value, dtype=np.float64)
    return np.concatenate([v[:, :2], np.log1p(k * np.maximum(v[:, 2:], 0.0))], axis=1)


@dataclass
class LossParts:
    """Eq. 11 and its four per-component mean squared errors (C_warp, C_weft, S_warp, S_weft)."""

    total: Tensor
    per_component: Tensor


def fabric_loss(raw: Tensor, target: Tensor) -> LossParts:
    """Eq. 11 of raw outputs ``(N, 4)`` against :func:`log_targets` ``(N, 4)``."""
    mse = (raw - target).square().mean(dim=0)
    total = LAMBDA_C * (mse[0] + mse[1]) + LAMBDA_S * (mse[2] + mse[3])
    return LossParts(total=total, per_component=mse.detach())


def fabric_loss_numpy(raw: np.ndarray, target: np.ndarray) -> float:
    """Eq. 11 in float64 (for metrics): raw outputs and log targets, ``(N, 4)`` each."""
    mse = np.mean((np.asarray(raw, np.float64) - target) ** 2, axis=0)
    return float(LAMBDA_C * (mse[0] + mse[1]) + LAMBDA_S * (mse[2] + mse[3]))


def linear_prediction(raw: Tensor, wi_z: Tensor) -> Tensor:
    """``(N, 4)`` components of raw outputs for the relative L2: C raw, S ``expm1(raw) / k``
    (no clamp at 0, so the gradient is never cut; rendering clamps, see
    :func:`models.fabric.networks.components`)."""
    k = log_k(wi_z)[:, None]
    return torch.cat([raw[:, :2], torch.expm1(raw[:, 2:].clamp_max(RAW_MAX)) / k], dim=1)


def fittable_mask(wi_z: np.ndarray) -> np.ndarray:
    """``(N, 4)`` bool: the relative L2 terms a query keeps. C_warp and C_weft are dropped
    for light from below (``wi.z < 0``), where the diffuse component is 0 by definition."""
    below = np.asarray(wi_z) < 0
    keep = np.ones((len(below), 4), dtype=bool)
    keep[below, :2] = False
    return keep


def floored_scale(scale: np.ndarray) -> np.ndarray:
    """Scales ``(N, 4)`` floored at :data:`SCALE_FLOOR` of each row's largest one."""
    s = np.abs(np.asarray(scale, np.float64))
    return np.maximum(s, SCALE_FLOOR * s.max(axis=1, keepdims=True))


def relative_l2_loss(
    raw: Tensor,
    value: Tensor,
    wi_z: Tensor,
    scale: Tensor,
    *,
    stderr: Tensor | None = None,
    group: Tensor | None = None,
    mean_weight: float = MEAN_WEIGHT,
) -> LossParts:
    """The relative L2 (module docstring) of raw outputs ``(N, 4)`` against linear targets
    ``value`` ``(N, 4)``; ``scale`` ``(N, 4)`` the material's mean target per component for
    each query's kind (floored as :func:`floored_scale`). The C terms of light from below
    are dropped (:func:`fittable_mask`); each ``L_c`` is the mean over the rows that keep
    it (0 where none does). ``per_component`` holds the four ``L_c``; ``total`` their
    mean.

    ``stderr`` ``(N, 4)``: the targets' Monte Carlo standard errors, added in quadrature to
    each denominator. ``group`` ``(N,)`` int64: the row's material slot in the batch; with
    it the mean-preserving term (per slot and light side, module docstring) times
    ``mean_weight`` joins ``total``."""
    pred = linear_prediction(raw, wi_z)
    keep = torch.ones_like(pred, dtype=torch.bool)
    keep[:, :2] = (wi_z >= 0)[:, None]
    m = scale.abs()
    m = torch.maximum(m, SCALE_FLOOR * m.amax(dim=1, keepdim=True))
    denom = pred.detach().square() + m.square() + EPS
    if stderr is not None:
        denom = denom + stderr.square()
    resid = pred - value
    term = torch.where(keep, resid.square() / denom, torch.zeros_like(pred))
    per = term.sum(dim=0) / keep.sum(dim=0).clamp_min(1).to(pred.dtype)
    total = per.mean()
    if group is not None:
        total = total + mean_weight * mean_term(resid, keep, m, group, wi_z)
    return LossParts(total=total, per_component=per.detach())


def mean_term(resid: Tensor, keep: Tensor, m: Tensor, group: Tensor, wi_z: Tensor) -> Tensor:
    """``mean_{g, c} (mean_{n in g} resid_nc)^2 / m_gc^2`` over the (group, light side,
    component) cells that hold a kept row; ``resid``, ``keep``, ``m`` ``(N, 4)`` (``m``
    floored, constant within a cell), ``group`` ``(N,)``."""
    cell = group.long() * 2 + (wi_z < 0).long()
    n_cells = int(cell.max()) + 1 if len(cell) else 1
    k = keep.to(resid.dtype)
    zeros = torch.zeros((n_cells, 4), dtype=resid.dtype, device=resid.device)
    rsum = zeros.index_add(0, cell, resid * k)
    cnt = zeros.index_add(0, cell, k)
    msum = zeros.index_add(0, cell, m.detach() * k)
    used = cnt > 0
    c = cnt.clamp_min(1)
    cell_term = (rsum / c).square() / (msum / c).square().clamp_min(EPS)
    return torch.where(used, cell_term, zeros).sum() / used.sum().clamp_min(1)


def relative_l2_numpy(
    pred: np.ndarray, value: np.ndarray, scale: np.ndarray, wi_z: np.ndarray
) -> float:
    """The relative L2 in float64 (for metrics): decoded components ``pred``, targets and
    scales ``(N, 4)`` each, the queries' ``wi_z`` ``(N,)``: the training loss's terms
    (:func:`relative_l2_loss`), the mean of the four per-component means."""
    p = np.asarray(pred, np.float64)
    m = floored_scale(scale)
    d = (p - np.asarray(value, np.float64)) ** 2 / (p**2 + m**2 + EPS)
    keep = fittable_mask(wi_z)
    per = np.where(keep, d, 0.0).sum(axis=0) / np.maximum(keep.sum(axis=0), 1)
    return float(np.mean(per))


def component_scales(value: np.ndarray, wi_z: np.ndarray) -> np.ndarray:
    """``(2, 4)`` float32 mean targets per component of one material's training queries:
    row 0 its BRDF queries (``wi.z >= 0``), row 1 its BTDF queries (the overall mean where a
    kind has none)."""
    v = np.asarray(value, np.float64)
    below = np.asarray(wi_z) < 0
    overall = np.abs(v).mean(axis=0) if len(v) else np.zeros(4)
    rows = [np.abs(v[m]).mean(axis=0) if m.any() else overall for m in (~below, below)]
    return np.stack(rows).astype(np.float32)
