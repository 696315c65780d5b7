"""Whole documents of ``train.brdf``, ``train.btf``, ``train.fabric``, ``evaluate.tss``,
``generate.merl`` and ``generate.fabric`` (their types: ``models.*.document``,
``evaluators.tss.document``, ``generators.*.document``) for tests of their readers: each
builder gives a document its type accepts (``tests/unit/jobapi/test_typed_documents.py``
checks that), with the values a test cares about passed in."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

BRDF_SCORES = ("smape", "smape_floor", "mae", "smape_analytic", "smape_floor_analytic",
               "mae_analytic")  # fmt: skip


def brdf_scores(name: str, family: str, split: str = "train", **scores: float | None) -> dict:
    """One material's scores of ``train.brdf``'s ``metrics.json``; unnamed scores ``None``
    (``smape``, ``smape_floor``, ``mae`` 0.0: they are always numbers)."""
    always = {"smape": 0.0, "smape_floor": 0.0, "mae": 0.0}
    return {"name": name, "family": family, "split": split, "pairs": 2048,
            **{k: scores.get(k, always.get(k)) for k in BRDF_SCORES}}  # fmt: skip


def brdf_metrics(materials: Sequence[Mapping[str, Any]], model: str = "hybrid",
                 **mean: float | None) -> dict[str, Any]:  # fmt: skip
    """``train.brdf``'s ``metrics.json`` of ``materials`` (:func:`brdf_scores`) whose means
    are ``mean`` (unnamed means ``None``)."""
    means = {"count": len(materials), **{k: mean.get(k) for k in BRDF_SCORES}}
    return {"model": model, "materials": [dict(m) for m in materials], "mean": means,
            "families": {}, "splits": {}, "settings": {"pairs": 2048}}  # fmt: skip


def brdf_materials(names: Sequence[tuple[str, str, str]], model: str = "hybrid", width: int = 32,
                   depth: int = 3, latent_dim: int = 4) -> dict[str, Any]:  # fmt: skip
    """``train.brdf``'s ``materials.json`` of ``(name, family, split)`` materials."""
    analytic = model != "neural"
    per = 7 + latent_dim if analytic else latent_dim
    return {
        "model": model,
        "architecture": {"model": model, "width": width, "depth": depth, "latent_dim": latent_dim},
        "per_material_params": per,
        "materials": [
            {"name": n, "family": f, "split": s, "kd": [0.1] * 3 if analytic else None,
             "eta": [1.5] * 3 if analytic else None, "alpha": 0.2 if analytic else None,
             "z": [0.0] * latent_dim}
            for n, f, s in names
        ],
    }  # fmt: skip


def btf_metrics(label: str = "c2f", *, l1: float = 0.02, l1_train: float = 0.019,
                l1_heldout: float | None = None, relative_l1: float = 0.1,
                texture_bytes: int = 1000, network_bytes: int = 200,
                cases: Sequence[Mapping[str, Any]] = ()) -> dict[str, Any]:  # fmt: skip
    """``train.btf``'s ``metrics.json``."""
    storage = {"texture_bytes": texture_bytes, "network_bytes": network_bytes,
               "total_bytes": texture_bytes + network_bytes}  # fmt: skip
    return {
        "model": label.split("+")[0], "label": label, "l1": l1, "l1_train": l1_train,
        "l1_heldout": l1_heldout, "relative_l1": relative_l1, "mean_abs_btf": l1 / relative_l1,
        "slices": {"total": 12, "train": 12 if l1_heldout is None else 9,
                   "heldout": 0 if l1_heldout is None else 3},
        "storage": storage, "storage_at_400": storage, "cases": [dict(c) for c in cases],
        "definition": "test",
    }  # fmt: skip


def fabric_metrics(materials: Sequence[Mapping[str, Any]], mean: Mapping[str, Any],
                   footprints: Sequence[Mapping[str, Any]] = ()) -> dict[str, Any]:  # fmt: skip
    """``train.fabric``'s ``metrics.json`` of per-material error trees."""
    return {"materials": [dict(m) for m in materials], "mean": dict(mean),
            "footprints": [dict(f) for f in footprints], "settings": {}}  # fmt: skip


def tss_row(resolution: int, interval: int, *, flip_mean: float, flip_max: float,
            psnr_mean: float | None, psnr_min: float | None,
            shading_passes: int = 2) -> dict[str, Any]:  # fmt: skip
    """One row of ``evaluate.tss``'s ``metrics.json``."""
    return {"label": f"{resolution}/N={interval}", "resolution": resolution,
            "interval": interval, "pass": "amortised", "flip_mean": flip_mean,
            "flip_max": flip_max, "psnr_mean": psnr_mean, "psnr_min": psnr_min,
            "shading_passes": shading_passes}  # fmt: skip


def tss_metrics(rows: Sequence[Mapping[str, Any]], frames: int = 6,
                model_job: str | None = "job:" + "c" * 32) -> dict[str, Any]:  # fmt: skip
    """``evaluate.tss``'s ``metrics.json`` of ``rows`` (:func:`tss_row`)."""
    motion = {"translation_mm_mean": 1.0, "translation_mm_max": 2.0, "rotation_deg_mean": 0.1,
              "rotation_deg_max": 0.2}  # fmt: skip
    return {
        "format": "matforge.tss/1",
        "model": {"job": model_job, "external": None, "runtime": "drjit-fused",
                  "model": "c2f", "kind": "c2f", "resolution": [8, 8]},
        "rows": [dict(r) for r in rows],
        "per_frame": {r["label"]: {"flip": [r["flip_mean"]] * frames,
                                   "psnr": [r["psnr_mean"]] * frames} for r in rows},
        "motion": motion, "figure": {"frame": 0, "interval": rows[0]["interval"]},
        "settings": {"frames": frames},
    }  # fmt: skip


def tss_timing(costs: Mapping[str, tuple[float, float | None]]) -> dict[str, Any]:
    """``evaluate.tss``'s ``timing.json``: ``{label: (seconds_per_frame, relative_cost)}``."""
    times = {"kernel_s": 0.008, "wall_s": 0.01, "count": 6}
    return {
        "format": "matforge.tss-timing/1",
        "rows": {label: {"seconds_per_frame": spf, "relative_cost": rel,
                         "wall_seconds_per_frame": spf, "wall_relative_cost": rel}
                 for label, (spf, rel) in costs.items()},
        "passes": {"screen_space": times, "shading": {"64": times}, "lookup": {"64": times}},
        "environment": {"threads": 1}, "units": {}, "note": "test",
    }  # fmt: skip


def merl_materials(materials: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """``generate.merl``'s ``materials.json`` of ``{"name", "family", "source",
    "tabulation"}`` materials (no measurement, one source)."""
    return {
        "materials": [
            {"params": {}, "measurement": None, **m,
             "artifacts": {"table": f"{m['name']}.binary", "picture": f"{m['name']}.png"}}
            for m in materials
        ],
        "phi_d_bins": 180, "preset": None, "families": None, "distributions": None,
        "allow_anisotropic": False, "anisotropy_tol": 0.01,
    }  # fmt: skip


def fabric_stats(backend: str = "numpy", **legacy: float) -> dict[str, Any]:
    """``generate.fabric``'s ``stats.json``; ``legacy`` adds the ``seconds`` and
    ``samples_per_second`` of a job made before timings moved to the manifest."""
    return {"materials": 3, "queries": 3 * 1280, "samples_per_query": 2048,
            "samples": 3 * 1280 * 2048, "backend": backend, "note": "test", **legacy}  # fmt: skip
