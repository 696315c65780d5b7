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
LOSSES: tuple[str, ...] = ("paper", "relative_l2")
#: Floor of the relative L2's denominator (squared component units).
EPS = 1e-8
#: Largest raw specular output the relative L2 exponentiates (``expm1(30) / 100`` = 1e11).
RAW_MAX = 30.0


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


def relative_l2_loss(raw: Tensor, value: Tensor, wi_z: Tensor, scale: Tensor) -> LossParts:
    """The relative L2 (module docstring) of raw outputs ``(N, 4)`` against linear targets
    ``value`` ``(N, 4)``; ``scale`` ``(N, 4)`` the material's mean target per component for
    each query's kind. ``per_component`` holds the four ``L_c``; ``total`` their mean."""
    pred = linear_prediction(raw, wi_z)
    denom = pred.detach().square() + scale.square() + EPS
    per = ((pred - value).square() / denom).mean(dim=0)
    return LossParts(total=per.mean(), per_component=per.detach())


def relative_l2_numpy(pred: np.ndarray, value: np.ndarray, scale: np.ndarray) -> float:
    """The relative L2 in float64 (for metrics): decoded components ``pred``, targets and
    scales ``(N, 4)`` each."""
    p = np.asarray(pred, np.float64)
    d = (p - np.asarray(value, np.float64)) ** 2 / (p**2 + np.asarray(scale, np.float64) ** 2 + EPS)
    return float(np.mean(d))


def component_scales(value: np.ndarray, wi_z: np.ndarray) -> np.ndarray:
    """``(2, 4)`` float32 mean targets per component of one material's training queries:
    row 0 its BRDF queries (``wi.z >= 0``), row 1 its BTDF queries (the overall mean where a
    kind has none)."""
    v = np.asarray(value, np.float64)
    below = np.asarray(wi_z) < 0
    overall = np.abs(v).mean(axis=0) if len(v) else np.zeros(4)
    rows = [np.abs(v[m]).mean(axis=0) if m.any() else overall for m in (~below, below)]
    return np.stack(rows).astype(np.float32)
