"""The stability checks of learned BRDFs (:mod:`models.brdf.stability`) against BRDFs with
known answers: a constant ``c / pi`` (albedo ``c``, reciprocal), one that is NaN below the
horizon, one that depends on ``wi`` only (not reciprocal), and a fitted analytic model."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
import torch

from models.brdf import stability
from models.brdf.networks import Architecture, BrdfModel


def fake(fn: Any) -> Any:
    def values(model: Any, index: int, wi: np.ndarray, wo: np.ndarray) -> tuple[Any, None]:
        return fn(wi, wo), None

    return values


def test01_constant_brdf(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(
        stability, "model_values", fake(lambda wi, wo: np.full((len(wi), 3), 1.2 / math.pi))
    )
    out = stability.material_checks(None, 0)  # type: ignore[arg-type]
    assert all(a == pytest.approx(1.2, rel=1e-12) for a in out["albedo"].values())
    assert out["energy_gain"] is True and out["albedo_max"] == pytest.approx(1.2)
    assert out["reciprocity_error"] == 0.0 and out["nonfinite_total"] == 0


def test02_nan_below_the_horizon_and_not_reciprocal(monkeypatch: pytest.MonkeyPatch) -> None:
    def f(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        v = np.where((wi[:, 2] < 0) | (wo[:, 2] < 0), np.nan, 0.1 * wi[:, 2] / math.pi)
        return np.repeat(v[:, None], 3, axis=1)

    monkeypatch.setattr(stability, "model_values", fake(f))
    out = stability.material_checks(None, 0)  # type: ignore[arg-type]
    assert out["nonfinite"] == {
        "grazing": 0,
        "tangent": 0,
        "wi_eq_wo": 0,
        "normal": 0,
        "wi_below": 8,
        "wo_below": 8,
        "both_below": 8,
    }
    # albedo = 0.1 cos(theta_i): largest at normal incidence
    assert out["albedo_max_theta"] == 0.0 and out["albedo_max"] == pytest.approx(0.1)
    assert out["energy_gain"] is False
    # |a - b| / (a + b) for independent cosine-distributed cosines: clearly non-zero
    assert 0.1 < out["reciprocity_error"] < 0.6


def test03_analytic_model_is_finite_and_reciprocal() -> None:
    """GGX + Lambert (Smith G, Fresnel at the half vector) is reciprocal; its albedo is
    whatever its initial kd and Fresnel give (Lambert plus specular need not conserve
    energy), so only its agreement with the same estimate computed here is checked."""
    torch.manual_seed(0)
    model = BrdfModel(Architecture("analytic", 0, 0, 0), 1).double()
    model.eval()
    out = stability.material_checks(model, 0)
    assert out["nonfinite_total"] == 0
    assert out["reciprocity_error"] < 1e-6
    rng = np.random.default_rng(1)
    wo = stability.cosine_directions(128, rng)
    wi = np.tile(stability.direction(30.0), (len(wo), 1))
    f, _ = stability.model_values(model, 0, wi, wo)
    assert out["albedo"]["30"] == pytest.approx(float(np.max(math.pi * f.mean(axis=0))), rel=0.01)
