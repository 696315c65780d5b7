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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from models.fabric.networks import K_BRDF, K_BTDF, log_k

#: Eq. 11 weights (Sec. 4.2: "set as 0.4 and 0.1 in practice").
LAMBDA_S, LAMBDA_C = 0.4, 0.1


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
