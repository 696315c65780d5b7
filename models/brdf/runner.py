"""The body of the ``train.brdf`` runner: data, fitting phases, reports and artifacts.

Kept apart from :mod:`models.brdf.kind` so that registering the kind (every CLI call)
does not import torch. The phases, seeds and artifacts are described in
:mod:`models.brdf.kind`.
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import asdict
from typing import TYPE_CHECKING, Any

import torch

from models.brdf.data import load_dataset, split_by_family, stack_tables
from models.brdf.kind import SPEED_REPEATS, TrainBrdfParams, architecture, load_init
from models.brdf.networks import BrdfModel, build_model, copy_materials, copy_network
from models.brdf.portable import checkpoint_bytes, to_portable
from models.brdf.report import curves_png, evaluate
from models.brdf.train import Curves, FitConfig, curves_document, deterministic_torch, fit
from models.device import pick_device

if TYPE_CHECKING:
    from jobapi.context import JobContext

log = logging.getLogger(__name__)

#: Progress fractions: dataset loaded, fitting done, metrics done.
P_LOADED, P_FITTED, P_SCORED = 0.05, 0.85, 0.97


def _resolved(params: TrainBrdfParams) -> dict[str, Any]:
    # Every tunable field's effective value, in the preset's field order (no summary line).
    values = asdict(params.effective())
    del values["summary"]
    return values


def train_and_report(params: TrainBrdfParams, ctx: JobContext) -> None:
    """Run a ``train.brdf`` job end to end."""
    started = time.perf_counter()
    device = pick_device(params.device, ctx)
    ctx.progress(0.0, "loading tables")
    materials = load_dataset(params.dataset, ctx)
    train_set, held = split_by_family(materials, params.holdout_families)
    init = load_init(params.init, ctx) if params.init is not None else None
    arch = architecture(params, init[0].arch if init else None)
    eff = params.effective()
    steps = eff.steps
    held_steps = params.holdout_steps or steps
    total = steps + (held_steps if held else 0)
    ctx.progress(P_LOADED, f"{len(materials)} tables, {arch.model} model")

    def phase_progress(offset: int) -> Any:
        def report(step: int, n: int, loss: float) -> None:
            frac = P_LOADED + (P_FITTED - P_LOADED) * (offset + step) / total
            ctx.progress(frac, f"step {offset + step}/{total}, loss {loss:.4g}")

        return report

    def config(n_steps: int, train_network: bool) -> FitConfig:
        return FitConfig(
            steps=n_steps,
            batch_pairs=eff.batch_pairs,
            lr=float(eff.lr),
            weight_decay=float(eff.weight_decay),
            clip=float(eff.clip),
            train_network=train_network,
        )

    def live(phase: str) -> Callable[[Curves], object]:
        """Publish the curves so far (earlier phases and this one's points), for the page."""
        return lambda c: ctx.publish("curves.json", curves_document({**curves, phase: c}))

    init_gen = torch.Generator().manual_seed(ctx.sub_seed("train.brdf/init"))
    pair_gen = torch.Generator().manual_seed(ctx.sub_seed("train.brdf/pairs"))
    curves: dict[str, Curves | None] = {"train": None, "heldout": None}
    with deterministic_torch():
        model = build_model(arch, len(train_set), init_gen)
        if init is not None:
            _start_from(model, [m.name for m in train_set], init)
        model.to(device)
        tables = stack_tables(train_set, device)
        curves["train"] = fit(
            model,
            tables,
            config(steps, not params.freeze_network),
            pair_gen,
            on_progress=phase_progress(0),
            on_curves=live("train"),
            phase="train",
        )
        del tables
        final = model
        if held:
            held_model = build_model(arch, len(held), init_gen).to(device)
            copy_network(held_model, model)
            curves["heldout"] = fit(
                held_model,
                stack_tables(held, device),
                config(held_steps, False),
                pair_gen,
                on_progress=phase_progress(steps),
                on_curves=live("heldout"),
                phase="heldout",
            )
            final = _merge(model, held_model, materials, {m.name for m in held}, arch)
        final = final.to("cpu")
        fit_seconds = time.perf_counter() - started
        ctx.progress(P_FITTED, "scoring")
        held_names = {m.name for m in held}
        splits = ["heldout" if m.name in held_names else "train" for m in materials]
        # Without held-out families train_set is materials; with them _merge keeps its order.
        ordered = materials
        metrics = evaluate(
            final,
            ordered,
            splits,
            eff.eval_pairs,
            check_cancelled=ctx.check_cancelled,
        )
    ctx.progress(P_SCORED, "writing artifacts")
    doc = _write(ctx, params, final, ordered, metrics, curves)
    if params.speed != "off":
        ctx.progress(P_SCORED, f"timing the model (speed: {params.speed})")
        ctx.measure("speed", measure_speed(params, doc))
    train_curve = curves["train"]
    ms = 1000.0 * train_curve.seconds / steps if train_curve is not None else 0.0
    log.info(
        "train.brdf %s: %s %dx%d, %d materials, %d steps, fit %.1f s (%.1f ms/step), total %.1f s",
        ctx.job_id, arch.model, arch.width, arch.depth, len(ordered), total, fit_seconds, ms,
        time.perf_counter() - started,
    )  # fmt: skip
    ctx.progress(1.0, f"{arch.model} {arch.width}x{arch.depth}: {headline(metrics)}; "
                      f"{total} steps in {fit_seconds:.0f} s ({ms:.1f} ms/step)")  # fmt: skip


def headline(metrics: dict[str, Any]) -> str:
    """The job's one-line error: the mean SMAPE over the held-out (test) materials where
    there are some, with the training materials' beside it; else over the training
    materials, said so."""
    splits, n = metrics["splits"], Counter(m["split"] for m in metrics["materials"])
    if "heldout" in splits:
        return (f"test SMAPE {splits['heldout']['smape']:.4f} over {n['heldout']} held-out "
                f"materials (train {splits['train']['smape']:.4f} over {n['train']})"
                if "train" in splits else
                f"test SMAPE {splits['heldout']['smape']:.4f} over {n['heldout']} materials "
                "fitted against a frozen network")  # fmt: skip
    return f"train SMAPE {metrics['mean']['smape']:.4f} over {n['train']} training materials"


def _start_from(
    model: BrdfModel, names: list[str], init: tuple[BrdfModel, list[str], list[str]]
) -> None:
    """Copy the init model's network, and the ``(z, p)`` of materials of the same name."""
    src, src_names, _ = init
    copy_network(model, src)
    pairs = [(i, src_names.index(n)) for i, n in enumerate(names) if n in src_names]
    if pairs:
        copy_materials(model, [a for a, _ in pairs], src, [b for _, b in pairs])


def _merge(
    trained: BrdfModel, held_model: BrdfModel, materials: list[Any], held: set[str], arch: Any
) -> BrdfModel:
    """One model of every material in dataset order: the shared network and both phases'
    ``(z, p)``."""
    merged = BrdfModel(arch, len(materials)).to(next(trained.parameters()).device)
    copy_network(merged, trained)
    train_rows = [i for i, m in enumerate(materials) if m.name not in held]
    held_rows = [i for i, m in enumerate(materials) if m.name in held]
    copy_materials(merged, train_rows, trained, list(range(len(train_rows))))
    copy_materials(merged, held_rows, held_model, list(range(len(held_rows))))
    return merged


def _write(
    ctx: JobContext,
    params: TrainBrdfParams,
    model: BrdfModel,
    materials: list[Any],
    metrics: dict[str, Any],
    curves: dict[str, Curves | None],
) -> dict[str, Any]:
    """Store every deterministic artifact; returns the ``model.json`` document."""
    names = [m.name for m in materials]
    families = [m.family for m in materials]
    splits = {r["name"]: r["split"] for r in metrics["materials"]}
    training = {
        "params": params.model_dump(mode="json"),
        "resolved": _resolved(params),
        "seed": ctx.seed,
        "materials": [{"name": m.name, "family": m.family, "ref": m.ref} for m in materials],
    }
    doc = to_portable(model, names, families, training)
    ctx.put_bytes("model.pt", checkpoint_bytes(model, names, families))
    ctx.put_json("model.json", doc)
    ctx.put_json(
        "materials.json",
        {
            "model": model.arch.model,
            "architecture": model.arch.as_dict(),
            "per_material_params": model.arch.per_material_params,
            "materials": [
                {**{k: m[k] for k in ("name", "family", "kd", "eta", "alpha", "z")},
                 "split": splits[m["name"]]}
                for m in doc["materials"]
            ],
        },
    )  # fmt: skip
    ctx.put_json("curves.json", curves_document(curves))
    arch = model.arch
    size = f" {arch.width}x{arch.depth}, l={arch.latent_dim}" if arch.model != "analytic" else ""
    ctx.put_bytes("curves.png", curves_png(curves, f"train.brdf: {arch.model}{size}"), "image/png")
    ctx.put_json("metrics.json", {"model": arch.model, **metrics})
    return doc


def measure_speed(params: TrainBrdfParams, doc: dict[str, Any]) -> dict[str, Any]:
    """The speed document of a trained model, kept in the manifest as
    ``timings.measured.speed`` (see :mod:`models.brdf.kind`).

    ``speed: trained`` times the model at its own size and the analytic baseline; ``full``
    adds the paper's Table 4 sizes. Without a vectorised Mitsuba variant (LLVM or CUDA)
    nothing is timed and the document says why (``skipped``), so that the job still
    succeeds.
    """
    from materials.backend import load_mitsuba
    from models.speed import SIZES, SPEED_FORMAT, speed_report

    mi = load_mitsuba()
    if not mi.variant().startswith(("llvm_", "cuda_")):
        return {
            "format": SPEED_FORMAT,
            "skipped": "needs a vectorised Mitsuba variant (llvm_ad_rgb or cuda_ad_rgb) for "
            f"the fused kernel; got {mi.variant()}",
            "rows": [],
        }
    latent = params.effective().latent_dim if params.model != "analytic" else 4
    report = speed_report(
        mi,
        doc,
        sizes=SIZES if params.speed == "full" else (),
        latent_dim=latent,
        batch=params.speed_batch,
        repeats=SPEED_REPEATS,
    )
    report["mode"] = params.speed
    return report
