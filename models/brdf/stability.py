"""Where a learned BRDF misbehaves: non-finite values at extreme inputs, directional albedo
above 1 (energy gain: the exp head of the hybrid and neural models is unbounded) and
reciprocity error. Directions in the local shading frame, z up, ``(N, 3)`` float64.

- *Extreme inputs*: grazing (``theta = 89.9``), exactly tangent (``z = 0``), ``wi = wo``,
  normal incidence, and below the horizon (``z < 0`` for ``wi``, ``wo`` or both); a value is
  counted when any RGB channel is NaN or infinite.
- *Energy*: ``a(wi) = int f(wi, wo) cos(theta_o) dwo``, estimated as ``pi * mean f`` over
  :data:`ALBEDO_SAMPLES` cosine-weighted ``wo`` (a fixed stratified set, the same for every
  model), at :data:`ALBEDO_THETAS`; reported per material as the largest over angles and
  channels. Passive materials have ``a <= 1``; above ``1 + ENERGY_TOLERANCE`` (the
  estimate's noise) it is flagged as an energy gain.
- *Reciprocity*: over :data:`RECIPROCITY_PAIRS` cosine-weighted pairs, the mean of
  ``|f(wi, wo) - f(wo, wi)| / (|f(wi, wo)| + |f(wo, wi)|)`` (0: reciprocal; 1: one side
  zero), channels averaged, pairs where both are 0 left out.
"""

from __future__ import annotations

import math
import statistics
from typing import TYPE_CHECKING, Any

import numpy as np

from jobapi.errors import JobFailed
from models.brdf.networks import BrdfModel
from models.brdf.report import model_values

if TYPE_CHECKING:
    from jobapi.context import JobContext

#: Incident angles (degrees) of the albedo check, and ``wo`` samples per angle.
ALBEDO_THETAS = (0.0, 30.0, 60.0, 75.0, 85.0, 89.0)
ALBEDO_SAMPLES = 64 * 64
RECIPROCITY_PAIRS = 64 * 64
#: Albedo above 1 by more than this (the estimate's noise) is an energy gain.
ENERGY_TOLERANCE = 0.01
#: Seed of the fixed direction sets (never a job's seed: every model sees the same ones).
SEED = 13


def direction(theta_deg: float, phi_deg: float = 0.0) -> np.ndarray:
    """The unit vector at polar ``theta`` and azimuth ``phi`` (degrees), ``(3,)``."""
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def extreme_inputs() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Named ``(wi, wo)`` sets of extreme inputs, each ``(N, 3)`` float64 (N = 8)."""
    phis = np.linspace(0.0, 315.0, 8)
    pick = np.array([direction(45.0, p) for p in phis])
    grazing = np.array([direction(89.9, p) for p in phis])
    tangent = np.array([direction(90.0, p) for p in phis])
    below = pick * np.array([1.0, 1.0, -1.0])
    normal = np.tile([0.0, 0.0, 1.0], (8, 1))
    return {
        "grazing": (grazing, grazing[::-1].copy()),
        "tangent": (tangent, pick),
        "wi_eq_wo": (pick, pick.copy()),
        "normal": (normal, normal.copy()),
        "wi_below": (below, pick),
        "wo_below": (pick, below),
        "both_below": (below, below[::-1].copy()),
    }


def cosine_directions(n_side: int, rng: np.random.Generator) -> np.ndarray:
    """``n_side**2`` stratified cosine-weighted directions, ``(n, 3)`` float64."""
    i, j = np.meshgrid(np.arange(n_side), np.arange(n_side), indexing="ij")
    u = (i.ravel() + rng.random(i.size)) / n_side
    v = (j.ravel() + rng.random(j.size)) / n_side
    r, phi = np.sqrt(u), 2.0 * math.pi * v
    return np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(1.0 - u, 0.0))], 1)


def material_checks(model: BrdfModel, index: int) -> dict[str, Any]:
    """The checks of material ``index`` (see the module docstring)."""
    rng = np.random.default_rng(SEED)
    nonfinite = {}
    for name, (wi, wo) in extreme_inputs().items():
        f, _ = model_values(model, index, wi, wo)
        nonfinite[name] = int(np.count_nonzero(~np.all(np.isfinite(f), axis=1)))
    wo = cosine_directions(int(math.isqrt(ALBEDO_SAMPLES)), rng)
    albedo = {}
    for theta in ALBEDO_THETAS:
        wi = np.tile(direction(theta), (len(wo), 1))
        f, _ = model_values(model, index, wi, wo)
        albedo[f"{theta:g}"] = float(np.max(math.pi * np.nanmean(f, axis=0)))
    side = int(math.isqrt(RECIPROCITY_PAIRS))
    # shuffled: both sets are stratified alike, so unshuffled pairs would nearly coincide
    a, b = cosine_directions(side, rng), rng.permutation(cosine_directions(side, rng))
    f_ab, _ = model_values(model, index, a, b)
    f_ba, _ = model_values(model, index, b, a)
    den = np.abs(f_ab) + np.abs(f_ba)
    ok = (den > 0) & np.isfinite(den)
    recip = float(np.mean(np.abs(f_ab - f_ba)[ok] / den[ok])) if ok.any() else 0.0
    worst = max(albedo, key=lambda k: albedo[k])
    return {
        "nonfinite": nonfinite,
        "nonfinite_total": sum(nonfinite.values()),
        "albedo": albedo,
        "albedo_max": albedo[worst],
        "albedo_max_theta": float(worst),
        "energy_gain": albedo[worst] > 1.0 + ENERGY_TOLERANCE,
        "reciprocity_error": recip,
    }


def trained_checks(ctx: JobContext, job_id: str) -> dict[str, Any]:
    """The checks of a finished ``train.brdf`` job's model (its ``model.pt``), for
    ``report.stability`` (:attr:`jobapi.reports.ReportFacts.checks`): ``materials`` (per
    material: name, family and :func:`material_checks`), and over them ``nonfinite_total``,
    ``albedo_max``, ``energy_gain`` (names) and the mean ``reciprocity_error``.
    :class:`~jobapi.errors.JobFailed` when the model does not load."""
    from models.brdf.portable import load_checkpoint

    try:
        model, names, families = load_checkpoint(ctx.read_ref(f"job:{job_id}/model.pt"))
    except (ValueError, KeyError, RuntimeError) as exc:
        raise JobFailed(f"job {job_id}: model.pt does not load: {exc}") from None
    model.eval()
    mats = [
        {"name": n, "family": f, **material_checks(model, i)}
        for i, (n, f) in enumerate(zip(names, families, strict=True))
    ]
    return {
        "materials": mats,
        "nonfinite_total": sum(m["nonfinite_total"] for m in mats),
        "albedo_max": max(m["albedo_max"] for m in mats),
        "energy_gain": [m["name"] for m in mats if m["energy_gain"]],
        "reciprocity_error": statistics.fmean(m["reciprocity_error"] for m in mats),
    }
