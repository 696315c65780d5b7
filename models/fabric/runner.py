"""The body of the ``train.fabric`` runner: data, fitting, reports and artifacts.

Kept apart from :mod:`models.fabric.kind` so that registering the kind (every CLI call)
does not import torch. Seeds: the network's initial weights from ``ctx.sub_seed
("train.fabric/init")``, the batches from ``"train.fabric/batches"``.
"""

from __future__ import annotations

import logging
import pickle
import time
from dataclasses import asdict
from typing import TYPE_CHECKING, Any

import torch

from jobapi.errors import JobFailed
from models.brdf.train import deterministic_torch
from models.device import pick_device
from models.fabric.data import load_dataset
from models.fabric.networks import Architecture, FabricNetwork, build_network
from models.fabric.portable import checkpoint_bytes, load_checkpoint, to_portable
from models.fabric.report import (
    beta_response,
    curves_png,
    encode_all,
    evaluate,
    held_out_materials,
    split_sets,
)
from models.fabric.train import Curves, FitConfig, TrainingSet, fit
from storage.formats.fabric_documents import FABRIC_SPLITS

if TYPE_CHECKING:
    from jobapi.context import JobContext
    from models.fabric.kind import TrainFabricParams

log = logging.getLogger(__name__)

#: ``metrics.json``'s ``settings.beta_response``.
_BETA_RESPONSE_NOTE = (
    "per pattern with >= 2 held-out betas: each component's mean (and the RGB "
    "value's, mean of channels) over all the held-out materials' queries (never "
    "trained on), Monte Carlo and model on the same queries; least-squares "
    "slopes against beta, their ratio (model / Monte Carlo), goal = same sign "
    "and at least half the size; paired = the materials share one query set; "
    "se_slope_* = standard errors from the spread over queries (of per-query "
    "slopes when paired), se_slope_noise = Monte Carlo noise alone from the "
    "stored standard errors; sign_resolved = |MC slope| > 2 se_slope_monte_carlo"
)

#: Progress fractions: dataset loaded, fitting done, metrics done.
P_LOADED, P_FITTED, P_SCORED = 0.05, 0.9, 0.97


def resolved(params: TrainFabricParams) -> dict[str, Any]:
    """Every tunable field's effective value, in the preset's field order (its ``summary``
    line left out)."""
    values = asdict(params.effective())
    del values["summary"]
    return values


def _initial(params: TrainFabricParams, ctx: JobContext) -> FabricNetwork:
    eff = params.effective()
    arch = Architecture(
        encoder_width=eff.encoder_width,
        map_resolution=eff.map_resolution,
        decoder_width=eff.decoder_width,
        centre_encoding=eff.centre_encoding,
        size_encoding=eff.size_encoding,
        centre_bins=eff.centre_bins,
        phase_channels=eff.phase_channels,
        param_skip=int(eff.param_skip),
    )
    net = build_network(arch, ctx.sub_seed("train.fabric/init"))
    if params.init is None:
        return net
    try:
        src, _ = load_checkpoint(ctx.read_ref(params.init))
    except (ValueError, KeyError, TypeError, RuntimeError, OSError, EOFError,
            pickle.UnpicklingError) as exc:  # fmt: skip
        raise JobFailed(f"init {params.init}: not a train.fabric model.pt: {exc}") from None
    if src.arch != arch:
        raise JobFailed(
            f"init: its architecture {src.arch.as_dict()} differs from this job's "
            f"{arch.as_dict()}; set encoder_width, decoder_width, map_resolution and the "
            "encoding options to match"
        )
    net.load_state_dict(src.state_dict())
    return net


def train_and_report(params: TrainFabricParams, ctx: JobContext) -> None:
    """Run a ``train.fabric`` job end to end."""
    started = time.perf_counter()
    device = pick_device(params.device, ctx)
    cfg = params.effective()
    ctx.progress(0.0, "loading dataset")
    materials = load_dataset(
        params.dataset, ctx, cfg.map_resolution, float(cfg.holdout), cfg.train_queries
    )
    held = held_out_materials(materials, params.held_out_beta or [])
    # a dataset with held-out sets (generate.fabric's unseen* presets): train on 'train' only
    unseen = {i for i, m in enumerate(materials) if m.split not in (None, "train")}
    if unseen and len(unseen | set(held)) == len(materials):
        raise JobFailed("dataset: every material is held out (split or held_out_beta)")
    trained_on = [m for i, m in enumerate(materials) if i not in set(held) | unseen]
    ctx.progress(P_LOADED, f"{len(trained_on)} materials on {device}")
    steps = cfg.steps

    def report(step: int, n: int, loss: float) -> None:
        frac = P_LOADED + (P_FITTED - P_LOADED) * step / n
        ctx.progress(frac, f"step {step}/{n}, loss {loss:.4g}")

    batch_gen = torch.Generator().manual_seed(ctx.sub_seed("train.fabric/batches"))
    with deterministic_torch():
        net = _initial(params, ctx).to(device)
        curves = fit(
            net,
            TrainingSet(trained_on, device, cfg.loss),
            FitConfig(
                steps=steps,
                batch=cfg.batch,
                materials_per_step=cfg.materials_per_step,
                lr=float(cfg.lr),
                momentum=float(cfg.momentum),
                weight_decay=float(cfg.weight_decay),
                clip=float(cfg.clip),
                loss=cfg.loss,
            ),
            batch_gen,
            on_progress=report,
            on_curves=lambda c: ctx.publish("curves.json", c.as_dict()),  # live, for the page
        )
        net = net.to("cpu").eval()
        fit_seconds = time.perf_counter() - started
        ctx.progress(P_FITTED, "scoring held-out queries")
        latents = encode_all(net, materials)
        metrics = evaluate(net, materials, latents)
        if params.held_out_beta is not None:
            names = {materials[i].name for i in held}
            for row in metrics["materials"]:
                row["held_out"] = row["name"] in names
            metrics["beta_response"] = beta_response(net, materials, latents, held)
            metrics["settings"]["held_out"] = (
                "the material's beta is in held_out_beta: it was never trained on (its "
                "baseline is still the mean of its own training-split Monte Carlo values)"
            )
            metrics["settings"]["beta_response"] = _BETA_RESPONSE_NOTE
        if any(m.split is not None for m in materials):
            for row, m in zip(
                metrics["materials"], [m for m in materials if len(m.test)], strict=True
            ):
                row["split"] = m.split
            metrics["sets"] = split_sets(net, materials, latents, FABRIC_SPLITS)
            metrics["settings"]["sets"] = (
                "per split of the dataset (materials.json's split: train = trained on, "
                "unseen_material = a parameter draw of a trained pattern never trained on, "
                "unseen_pattern = a pattern never trained on), on each material's held-out "
                "queries: the spread over its materials (mean, std, min, max) of the RGB "
                "relative L1 and of the cloth mean error sum pred / sum gt - 1 (Eq. 8 RGB "
                "value), overall and per light side (brdf: light above, btdf: below); "
                "beta_response as below over the split's materials per pattern, against "
                "the mean of the warp and weft betas (the materials also differ in alpha, "
                "w and albedos, so Monte Carlo and model are regressed on the same materials)"
            )
            if "beta_response" not in metrics["settings"]:
                metrics["settings"]["beta_response"] = _BETA_RESPONSE_NOTE
    ctx.progress(P_SCORED, "writing artifacts")
    _write(ctx, params, net, materials, latents, metrics, curves)
    ms = 1000.0 * curves.seconds / steps
    log.info(
        "train.fabric %s: %d materials, %d steps on %s, fit %.1f s (%.1f ms/step), total %.1f s",
        ctx.job_id, len(materials), steps, device, fit_seconds, ms, time.perf_counter() - started,
    )  # fmt: skip
    mean = metrics["mean"]
    summary = (
        f"held-out loss {mean['loss']:.4g} (baseline {mean['baseline']['loss']:.4g}), "
        f"RGB rel. error {mean['rgb']['rel']:.3f}; "
        if metrics["materials"]
        else ""
    )
    ctx.progress(1.0, f"{summary}{steps} steps in {fit_seconds:.0f} s ({ms:.1f} ms/step)")


def _write(
    ctx: JobContext,
    params: TrainFabricParams,
    net: FabricNetwork,
    materials: list[Any],
    latents: Any,
    metrics: dict[str, Any],
    curves: Curves,
) -> None:
    names = [m.name for m in materials]
    records = [m.record for m in materials]
    training = {
        "params": params.model_dump(mode="json"),
        "resolved": resolved(params),
        "seed": ctx.seed,
        "dataset": params.dataset,
        "materials": len(materials),
    }
    doc = to_portable(net, names, [m.pattern for m in materials], records, latents, training)
    sides = {m.map_source_resolution for m in materials}
    side = sides.pop() if len(sides) == 1 else None  # one generate.fabric job: one side
    ctx.put_bytes("model.pt", checkpoint_bytes(net, names, records, latents, side))
    ctx.put_json("model.json", doc)
    ctx.put_json(
        "latents.json",
        {
            "latent_dim": net.arch.latent_dim,
            "materials": {
                m["name"]: {"latent": m["latent"], "params": m["params"], "pattern": m["pattern"]}
                for m in doc["materials"]
            },
        },
    )
    ctx.put_json("curves.json", curves.as_dict())
    a = net.arch
    title = (
        f"train.fabric: encoder {a.encoder_width}, decoder {a.decoder_width}, "
        f"{len(names)} materials"
    )
    ctx.put_bytes("curves.png", curves_png(curves, title), "image/png")
    ctx.put_json("metrics.json", metrics)
