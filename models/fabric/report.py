"""Reports of ``train.fabric``: ``metrics.json`` (held-out errors) and ``curves.png``.

Metrics, per material, on its held-out queries (:func:`models.fabric.data.holdout_split`:
never trained on), against the dataset's Monte Carlo estimates:

- per component of Eq. 7 (``C_warp, C_weft, S_warp, S_weft``, decoded as in
  :func:`models.fabric.networks.components`): ``mse`` and ``rel`` = ``sum |pred - gt| /
  sum |gt|`` (relative L1 over the queries), ``ratio`` = ``sum pred / sum gt`` (whether
  the mean holds; the goal is within +-3 %);
- ``rgb``: the same two figures of the Eq. 8 value ``f = sum_c albedo_c component_c`` with
  the material's albedos, over queries and the three channels;
- ``loss``: Eq. 11 in the training space (log-mapped specular targets), whatever loss
  trained the model;
- ``relative_l2``: the unbiased relative L2 of :mod:`models.fabric.losses` on the decoded
  components (scales: the material's training means per component and query kind), also
  whatever loss trained the model, so the two losses' models compare on both;
- ``baseline``: the same figures for a trivial model, the material's per-component mean
  over its training queries (in the training space for ``loss``, linear otherwise).

``footprints``: the network's and the baseline's RGB relative L1 per footprint-size case
(:data:`FOOTPRINT_CASES`; the tiny footprints are a failure case of issue 13), mean over
materials. ``mean``: plain means over materials of every figure. Latents are computed once per
material by the encoder in eval mode, as rendering does.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from evaluators.metrics.figures import figure_png, loss_axes
from jobapi.errors import JobFailed
from models.fabric.data import MaterialData
from models.fabric.losses import (
    component_scales,
    fabric_loss_numpy,
    log_targets_numpy,
    relative_l2_numpy,
)
from models.fabric.networks import COMPONENTS, FabricNetwork, components_numpy
from models.fabric.train import Curves

#: Queries per decoder evaluation chunk.
EVAL_CHUNK = 1 << 15


def encode_all(net: FabricNetwork, materials: Sequence[MaterialData]) -> np.ndarray:
    """``(M, L)`` float32 latents of every material (encoder in eval mode, CPU)."""
    net.eval()
    with torch.no_grad():
        maps = torch.from_numpy(np.stack([m.maps for m in materials]))
        params = torch.from_numpy(np.stack([m.params for m in materials]))
        z = [net.encoder(maps[i : i + 1], params[i : i + 1]) for i in range(len(materials))]
    return torch.cat(z).numpy().astype(np.float32)


def decode_raw(net: FabricNetwork, latent: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Raw decoder outputs ``(N, 4)`` float32 of one latent ``(L,)`` at ``(N, 8)`` queries."""
    out = np.empty((len(query), 4), np.float32)
    z = torch.from_numpy(np.asarray(latent, np.float32))[None]
    with torch.no_grad():
        for lo in range(0, len(query), EVAL_CHUNK):
            q = torch.from_numpy(np.ascontiguousarray(query[lo : lo + EVAL_CHUNK]))
            out[lo : lo + len(q)] = net.decoder(z.expand(len(q), -1), q).numpy()
    return out


def _errors(pred: np.ndarray, gt: np.ndarray, albedos: np.ndarray) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, name in enumerate(COMPONENTS):
        d = pred[:, k] - gt[:, k]
        out[name] = {
            "mse": float(np.mean(d * d)),
            "rel": float(np.sum(np.abs(d)) / max(float(np.sum(np.abs(gt[:, k]))), 1e-30)),
            "ratio": _ratio(pred[:, k], gt[:, k]),
        }
    rgb_p, rgb_g = pred @ albedos, gt @ albedos
    d = rgb_p - rgb_g
    out["rgb"] = {
        "mse": float(np.mean(d * d)),
        "rel": float(np.sum(np.abs(d)) / max(float(np.sum(np.abs(rgb_g))), 1e-30)),
        "ratio": _ratio(rgb_p, rgb_g),
    }
    return out


def _ratio(pred: np.ndarray, gt: np.ndarray) -> float:
    """Mean prediction over mean target (1 where the target sums to 0): whether the mean
    holds, the goal being within +-3 %."""
    t = float(np.sum(gt))
    return float(np.sum(pred)) / t if abs(t) > 1e-30 else 1.0


#: Footprint-size cases (tile units, half-open ``[lo, hi)``): the tiny footprints of
#: issue 13's failure families (a tenth of a tile: the first of the paper's size strata,
#: where single yarns are resolved), sub-tile and tile-sized or larger.
FOOTPRINT_CASES: tuple[tuple[str, float, float], ...] = (
    ("footprint < 0.1 tile", 0.0, 0.1),
    ("footprint 0.1-1 tile", 0.1, 1.0),
    ("footprint >= 1 tile", 1.0, float("inf")),
)


def _rgb_rel(pred: np.ndarray, gt: np.ndarray, albedos: np.ndarray) -> float:
    rgb_g = gt @ albedos
    return float(np.sum(np.abs(pred @ albedos - rgb_g)) / max(float(np.sum(np.abs(rgb_g))), 1e-30))


def footprint_errors(
    size: np.ndarray, pred: np.ndarray, base: np.ndarray, gt: np.ndarray, albedos: np.ndarray
) -> dict[str, dict[str, Any]]:
    """Per :data:`FOOTPRINT_CASES` case: held-out ``queries`` and the RGB relative L1 of the
    network (``rgb_rel``) and of the mean baseline (``baseline_rgb_rel``); ``None`` where a
    case has no query. ``size`` ``(N,)`` footprint sizes, the rest as in ``_errors``."""
    out: dict[str, dict[str, Any]] = {}
    for name, lo, hi in FOOTPRINT_CASES:
        k = (size >= lo) & (size < hi)
        n = int(k.sum())
        out[name] = {
            "queries": n,
            "rgb_rel": _rgb_rel(pred[k], gt[k], albedos) if n else None,
            "baseline_rgb_rel": _rgb_rel(base[k], gt[k], albedos) if n else None,
        }
    return out


def _material(
    net: FabricNetwork, m: MaterialData, latent: np.ndarray
) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
    """A material's row and its :func:`footprint_errors`."""
    q, gt = m.query[m.test], m.value[m.test].astype(np.float64)
    raw = decode_raw(net, latent, q)
    if not np.all(np.isfinite(raw)):
        raise JobFailed(f"material {m.name!r}: the trained model gives non-finite values")
    pred = components_numpy(raw, q[:, 5]).astype(np.float64)
    albedos = m.albedos()
    target = log_targets_numpy(gt, q[:, 5])
    train_target = log_targets_numpy(m.value[m.train], m.query[m.train, 5])
    base_lin = np.broadcast_to(m.value[m.train].astype(np.float64).mean(axis=0), gt.shape)
    base_log = np.broadcast_to(train_target.mean(axis=0), gt.shape)
    scale = component_scales(m.value[m.train], m.query[m.train, 5])[(q[:, 5] < 0).astype(np.int64)]
    sizes = footprint_errors(q[:, 2].astype(np.float64), pred, base_lin, gt, albedos)
    return {
        "name": m.name,
        "pattern": m.pattern,
        "queries": int(len(q)),
        "loss": fabric_loss_numpy(raw, target),
        "relative_l2": relative_l2_numpy(pred, gt, scale, q[:, 5]),
        **_errors(pred, gt, albedos),
        "baseline": {
            "loss": fabric_loss_numpy(base_log, target),
            "relative_l2": relative_l2_numpy(base_lin, gt, scale, q[:, 5]),
            **_errors(base_lin, gt, albedos),
        },
    }, sizes


def _footprint_means(per_material: Sequence[dict[str, dict[str, Any]]]) -> list[dict[str, Any]]:
    """Per footprint case, in :data:`FOOTPRINT_CASES` order: ``queries`` summed, errors
    averaged over the materials that have queries in it (``None`` when none has)."""
    out = []
    for name, lo, hi in FOOTPRINT_CASES:
        cases = [m[name] for m in per_material if m[name]["queries"]]
        entry: dict[str, Any] = {"case": name, "range": [lo, hi if math.isfinite(hi) else None]}
        entry["queries"] = sum(c["queries"] for c in cases)
        entry["materials"] = len(cases)
        for key in ("rgb_rel", "baseline_rgb_rel"):
            entry[key] = float(np.mean([c[key] for c in cases])) if cases else None
        out.append(entry)
    return out


def _mean_tree(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Means over rows of every numeric leaf (nested dicts follow the first row)."""
    out: dict[str, Any] = {}
    for key, v in rows[0].items():
        if isinstance(v, dict):
            out[key] = _mean_tree([r[key] for r in rows])
        elif isinstance(v, float):
            out[key] = float(np.mean([r[key] for r in rows]))
    return out


def evaluate(
    net: FabricNetwork, materials: Sequence[MaterialData], latents: np.ndarray
) -> dict[str, Any]:
    """``metrics.json`` of every material with held-out queries (see the module docstring)."""
    done = [_material(net, m, z) for m, z in zip(materials, latents, strict=True) if len(m.test)]
    rows = [row for row, _ in done]
    return {
        "materials": rows,
        "mean": {"count": len(rows), **(_mean_tree(rows) if rows else {})},
        "footprints": _footprint_means([sizes for _, sizes in done]),
        "settings": {
            "queries": "held-out queries of each material (fixed seed, never trained on)",
            "mse": "mean squared error of the decoded component (Eq. 7), or of the Eq. 8 RGB "
            "value with the material's albedos",
            "rel": "sum |pred - gt| / sum |gt| over the held-out queries (and RGB channels)",
            "ratio": "sum pred / sum gt over the held-out queries (and RGB channels)",
            "loss": "Eq. 11 in the training space (specular log-mapped, Eq. 9)",
            "relative_l2": "mean over components and queries of (p - y)^2 / (p^2 + m^2 + "
            "1e-8), p the decoded component, m the material's mean training target per "
            "component and query kind (BRDF, BTDF)",
            "baseline": "per-component mean of the material's training queries",
            "footprints": "rgb rel per footprint-size case (tile units, [lo, hi)), mean over "
            "the materials with held-out queries in the case; queries summed",
        },
    }


#: A material's beta matches a ``held_out_beta`` value within this (the ``beta`` preset's
#: values are ``0.1 + 0.9 k / (n - 1)`` in float64; specs give decimals).
BETA_MATCH = 1e-6


def held_out_materials(materials: Sequence[MaterialData], betas: Sequence[float]) -> list[int]:
    """Indices of the materials whose beta (warp and weft alike) is one of ``betas``.

    Raises :class:`JobFailed` naming ``held_out_beta`` when a value matches no material or
    every material would be held out.
    """
    held = []
    for i, m in enumerate(materials):
        warp, weft = (float(b) for b in m.record["beta"])
        if abs(warp - weft) <= BETA_MATCH and any(abs(warp - b) <= BETA_MATCH for b in betas):
            held.append(i)
    for b in betas:
        if not any(abs(float(materials[i].record["beta"][0]) - b) <= BETA_MATCH for i in held):
            raise JobFailed(f"held_out_beta: no material of the dataset has beta {b:g}")
    if len(held) == len(materials):
        raise JobFailed("held_out_beta: every material would be held out; none left to train")
    return held


def response_slope(beta: np.ndarray, mean: np.ndarray) -> np.ndarray:
    """Least-squares slopes ``d mean / d beta``: ``beta`` ``(M,)``, ``mean`` ``(M, K)``."""
    b = np.asarray(beta, np.float64) - np.mean(beta)
    y = np.asarray(mean, np.float64)
    return (b @ (y - y.mean(axis=0))) / float(b @ b)


def _slope_weights(beta: np.ndarray) -> np.ndarray:
    """``c`` with ``slope = c @ means`` (the least-squares slope is linear in the means)."""
    b = np.asarray(beta, np.float64) - np.mean(beta)
    return b / float(b @ b)


def slope_with_stderr(
    beta: np.ndarray, values: Sequence[np.ndarray], paired: bool
) -> tuple[np.ndarray, np.ndarray]:
    """The least-squares slope of the means against ``beta`` and its standard error.

    ``values`` holds per material ``(Q_m, K)`` values at its queries. ``paired``: every
    material has the same ``Q`` queries, row by row; the slope is then the mean of the
    per-query slopes and its standard error their spread over ``sqrt(Q)``. Otherwise the
    materials' means are independent, each with its variance over its queries / ``Q_m``.
    """
    c = _slope_weights(beta)
    means = np.array([np.mean(v, axis=0) for v in values])
    if paired:
        per_query = np.einsum("m,mqk->qk", c, np.stack([np.asarray(v) for v in values]))
        return c @ means, per_query.std(axis=0, ddof=1) / math.sqrt(len(per_query))
    var = np.array([np.var(v, axis=0, ddof=1) / len(v) for v in values])
    return c @ means, np.sqrt(c**2 @ var)


def _held_out_rows(materials: Sequence[MaterialData], idx: Sequence[int]) -> list[np.ndarray]:
    """Rows of each held-out material to score, in shard order: all its kept rows (it was
    never trained on), restricted to the shard rows every one of them kept, so that
    materials with one query set are scored query by query on the same queries."""
    rows = [materials[i].rows for i in idx]
    known = [r for r in rows if r is not None]
    if len(known) < len(rows):
        return [np.arange(len(materials[i].query)) for i in idx]
    common = known[0]
    for r in known[1:]:
        common = np.intersect1d(common, r)
    out = []
    for r in known:
        pos = np.argsort(r)
        out.append(pos[np.searchsorted(r, common, sorter=pos)])
    return out


def material_beta(m: MaterialData, beta: str = "warp") -> float:
    """A material's beta for :func:`beta_response`: the warp yarn's (``"warp"``; the ``beta``
    preset's materials have warp = weft) or the mean of warp and weft (``"mean"``)."""
    warp, weft = (float(b) for b in m.record["beta"])
    return warp if beta == "warp" else 0.5 * (warp + weft)


def beta_response(
    net: FabricNetwork,
    materials: Sequence[MaterialData],
    latents: np.ndarray,
    held: Sequence[int],
    beta: str = "warp",
) -> list[dict[str, Any]]:
    """Per pattern with two or more held-out betas: each component's (and the Eq. 8 RGB
    value's, mean of channels) mean over the held-out materials' queries against beta,
    network and Monte Carlo on the same queries; the least-squares slopes, their ratio, and
    whether the network has Monte Carlo's sign and at least half its size (the goal).

    Queries: a held-out material was never trained on, so all its queries are scored. When
    the materials share one query set (the ``beta`` preset), ``paired`` is true and the
    slope is the mean over queries of each query's own slope; its standard error
    (``se_slope_monte_carlo``, ``se_slope_model``) is the spread of those per-query slopes
    over sqrt(queries). Otherwise (each material its own queries) the standard error comes
    from each material's spread over its queries, as independent samples. Either way it
    counts both the choice of queries and the Monte Carlo noise. ``se_slope_noise`` is the
    Monte Carlo noise alone, from the stored standard errors (materials and components
    taken as independent: with shared footprint samples the true noise of a difference
    is smaller). ``sign_resolved``: ``|slope_monte_carlo| > 2 se_slope_monte_carlo``.
    """
    by_pattern: dict[str, list[int]] = {}
    for i in held:
        if len(materials[i].query):
            by_pattern.setdefault(materials[i].pattern, []).append(i)
    out = []
    for pattern, idx in sorted(by_pattern.items()):
        betas = np.array([material_beta(materials[i], beta) for i in idx])
        if len(idx) < 2 or np.ptp(betas) <= 0.0:
            continue
        rows = _held_out_rows(materials, idx)
        gts, preds, noise = [], [], []
        for i, r in zip(idx, rows, strict=True):
            m = materials[i]
            q = m.query[r]
            pred = components_numpy(decode_raw(net, latents[i], q), q[:, 5]).astype(np.float64)
            gt = m.value[r].astype(np.float64)
            rgb = m.albedos().mean(axis=1)  # the RGB mean is linear in the components
            gts.append(np.concatenate([gt, (gt @ rgb)[:, None]], axis=1))
            preds.append(np.concatenate([pred, (pred @ rgb)[:, None]], axis=1))
            if m.stderr is not None:
                se = m.stderr[r].astype(np.float64)
                var = np.concatenate([se**2, ((se**2) @ rgb**2)[:, None]], axis=1)
                noise.append(var.sum(axis=0) / len(r) ** 2)  # variance of each mean
        first = materials[idx[0]].query[rows[0]]
        paired = all(
            len(r) == len(rows[0]) and np.array_equal(materials[i].query[r], first)
            for i, r in zip(idx, rows, strict=True)
        )
        c = _slope_weights(betas)
        mc = np.array([g.mean(axis=0) for g in gts])
        nn = np.array([p.mean(axis=0) for p in preds])
        s_mc, se_mc = slope_with_stderr(betas, gts, paired)
        s_nn, se_nn = slope_with_stderr(betas, preds, paired)
        se_noise = np.sqrt(c**2 @ np.array(noise)) if len(noise) == len(idx) else None
        entry: dict[str, Any] = {
            "pattern": pattern,
            "materials": [materials[i].name for i in idx],
            "beta": betas.tolist(),
            "queries": [len(r) for r in rows],
            "paired": paired,
        }
        for k, name in enumerate([*COMPONENTS, "rgb"]):
            ratio = float(s_nn[k] / s_mc[k]) if s_mc[k] != 0.0 else None
            entry[name] = {
                "monte_carlo": [float(r[k]) for r in mc],
                "model": [float(r[k]) for r in nn],
                "slope_monte_carlo": float(s_mc[k]),
                "slope_model": float(s_nn[k]),
                "se_slope_monte_carlo": float(se_mc[k]),
                "se_slope_model": float(se_nn[k]),
                "se_slope_noise": None if se_noise is None else float(se_noise[k]),
                "sign_resolved": bool(abs(s_mc[k]) > 2.0 * se_mc[k]),
                "slope_ratio": ratio,
                "goal": ratio is not None and ratio >= 0.5,
            }
        out.append(entry)
    return out


def _spread(values: Sequence[float]) -> dict[str, Any]:
    """Mean, sample standard deviation (``None`` for one value), min and max."""
    v = np.asarray(values, np.float64)
    return {
        "mean": float(v.mean()),
        "std": float(v.std(ddof=1)) if len(v) >= 2 else None,
        "min": float(v.min()),
        "max": float(v.max()),
    }


#: Light sides of a query: BRDF (light above, ``wi_z > 0``) and BTDF (light below).
SIDES: tuple[str, ...] = ("brdf", "btdf")


def _set_row(net: FabricNetwork, m: MaterialData, latent: np.ndarray) -> dict[str, Any]:
    """One material's figures for :func:`split_sets` on its held-out queries: the Eq. 8 RGB
    value's relative L1 (``rgb_rel``) and mean ratio (``rgb_ratio``), overall and per light
    side (``None`` where a side has no query)."""
    q, gt = m.query[m.test], m.value[m.test].astype(np.float64)
    pred = components_numpy(decode_raw(net, latent, q), q[:, 5]).astype(np.float64)
    albedos = m.albedos()
    below = q[:, 5] < 0
    row: dict[str, Any] = {
        "rgb_rel": _rgb_rel(pred, gt, albedos),
        "rgb_ratio": _ratio(pred @ albedos, gt @ albedos),
    }
    for side, k in (("brdf", ~below), ("btdf", below)):
        n = int(k.sum())
        row[side] = {
            "queries": n,
            "rgb_rel": _rgb_rel(pred[k], gt[k], albedos) if n else None,
            "rgb_ratio": _ratio(pred[k] @ albedos, gt[k] @ albedos) if n else None,
        }
    return row


def split_sets(
    net: FabricNetwork,
    materials: Sequence[MaterialData],
    latents: np.ndarray,
    splits: Sequence[str],
) -> list[dict[str, Any]]:
    """Per split of the dataset (``splits`` in order, those with materials scored): its
    materials and patterns, and the spread over its materials (mean, std, min, max) of the
    held-out queries' RGB relative L1, the cloth mean error (``sum pred / sum gt - 1`` of
    the RGB value) and both per light side; then the beta response of the split's materials
    (:func:`beta_response` per pattern, against the mean of the warp and weft betas) for the
    splits never trained on."""
    out = []
    for split in splits:
        idx = [i for i, m in enumerate(materials) if m.split == split and len(m.test)]
        if not idx:
            continue
        rows = [_set_row(net, materials[i], latents[i]) for i in idx]
        entry: dict[str, Any] = {
            "split": split,
            "materials": len(idx),
            "patterns": sorted({materials[i].pattern for i in idx}),
            "queries": int(sum(len(materials[i].test) for i in idx)),
            "rgb_rel": _spread([r["rgb_rel"] for r in rows]),
            "cloth_mean_error": _spread([r["rgb_ratio"] - 1.0 for r in rows]),
        }
        for side in SIDES:
            scored = [r[side] for r in rows if r[side]["queries"]]
            entry[side] = {
                "materials": len(scored),
                "queries": int(sum(r["queries"] for r in scored)),
                "rgb_rel": _spread([r["rgb_rel"] for r in scored]) if scored else None,
                "cloth_mean_error": (
                    _spread([r["rgb_ratio"] - 1.0 for r in scored]) if scored else None
                ),
            }
        if split != "train":
            entry["beta_response"] = beta_response(net, materials, latents, idx, beta="mean")
        out.append(entry)
    return out


def curves_png(curves: Curves, title: str) -> bytes:
    """Loss and per-component MSE against step (log scale), as deterministic PNG bytes;
    with the relative L2 losses also each component's training mean ratio (right axis, the
    +-3 % goal shaded)."""

    def draw(fig: Any, ax: Any) -> None:
        paper = curves.loss_name == "paper"
        total = "Eq. 11 total" if paper else "relative L2 (mean of 4)"
        ax.plot(curves.step, curves.loss, label=total, color="black")
        for name, values in curves.components.items():
            label = f"MSE {name}" if paper else f"rel. L2 {name}"
            ax.plot(curves.step, values, "--", label=label, linewidth=0.8)
        loss_axes(ax, "loss (mean per query)", title)
        if curves.mean_ratio is not None:
            right = ax.twinx()
            right.axhspan(0.97, 1.03, color="0.9", zorder=0)
            for name, values in curves.mean_ratio.items():
                right.plot(curves.step, values, ":", label=f"mean ratio {name}", linewidth=1.0)
            right.set_ylabel("sum pred / sum target (goal 1 +- 3 %)")
            right.legend(loc="lower left", fontsize="x-small")

    return figure_png(draw)
