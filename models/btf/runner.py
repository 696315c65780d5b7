"""The body of the ``train.btf`` runner: data, fitting, metrics and artifacts.

Kept apart from :mod:`models.btf.kind` so that registering the kind does not import torch.
Seeds: initial weights from ``ctx.sub_seed("train.btf/init")``, texture jitter from
``"train.btf/jitter"``, the slice order from ``"train.btf/order"``.
"""

from __future__ import annotations

import json
import logging
import math
import time
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from evaluators.metrics.figures import figure_png, loss_axes
from evaluators.metrics.tonemap import magma, tonemap
from jobapi.errors import JobFailed
from jobapi.params import job_id_of
from materials.btf.lafortune import PARAMS_PER_TEXEL, initial_params
from models.brdf.train import deterministic_torch
from models.btf.cases import (
    case_errors,
    detail_slices,
    fine_detail_error,
    predicted_slice_l1,
    slice_mean_abs,
)
from models.btf.data import BtfDataset
from models.btf.lafortune import fit_lafortune
from models.btf.networks import Architecture, build_network
from models.btf.portable import (
    PortableBtf,
    model_document,
    network_layers,
    network_textures,
    read_model,
    read_textures,
    textures_bytes,
    torch_network,
)
from models.btf.train import Curves, Distillation, FitConfig, fit, slice_l1
from models.device import pick_device

if TYPE_CHECKING:
    from jobapi.context import JobContext
    from models.btf.kind import TrainBtfParams

log = logging.getLogger(__name__)

P_LOADED, P_FITTED, P_SCORED = 0.05, 0.9, 0.97
#: Held-out slices shown in ``reconstructions.png``.
SHOWN = 4


def label_of(params: TrainBtfParams) -> str:
    """``c2f+distill``, ``neumip (8)`` style name of the trained variant."""
    if params.model == "lafortune":
        return "lafortune"
    label = params.model + ("+distill" if params.distill else "")
    width = params.network_width()
    from models.btf.kind import WIDTHS

    return label if width == WIDTHS[params.model] else f"{label} ({width})"


def load_teacher(ref: str, ctx: JobContext, resolution: tuple[int, int]) -> torch.nn.Module:
    """The frozen teacher network of a ``train.btf`` job."""
    job_id = job_id_of(ref)
    ctx.input_job(job_id, "distill.teacher", "train.btf")
    try:
        doc = json.loads(ctx.read_ref(f"job:{job_id}/model.json"))
        model = read_model(doc, read_textures(ctx.read_ref(f"job:{job_id}/textures.npz")))
    except (ValueError, OSError) as exc:
        raise JobFailed(f"distill.teacher: {exc}") from None
    if model.kind != "neumip":
        raise JobFailed(f"distill.teacher: job {job_id} trained {model.model}, not a NeuMIP")
    if model.resolution != resolution:
        raise JobFailed(f"distill.teacher: trained at {model.resolution}, the data is {resolution}")
    net = torch_network(model)
    for p in net.parameters():
        p.requires_grad_(False)
    return net


def _fit_network(
    params: TrainBtfParams, ctx: JobContext, data: BtfDataset, train: np.ndarray, test: np.ndarray
) -> tuple[torch.nn.Module, Curves]:
    kind = "c2f" if params.model == "c2f" else "neumip"
    h, w = data.resolution
    if kind == "c2f" and (h % 2 or w % 2):
        raise JobFailed(f"model: c2f needs an even slice resolution, the data is {w}x{h}")
    arch = Architecture(model=kind, width=params.network_width(), resolution=(h, w))
    # Weights are drawn on the CPU (the same initial network on any device), then moved.
    device = pick_device(params.device, ctx)
    net = build_network(arch, ctx.sub_seed("train.btf/init")).to(device)
    distill = None
    if params.distill is not None:
        d = params.distill
        teacher = load_teacher(d.teacher, ctx, (h, w)).to(device)
        distill = Distillation(
            teacher, sigma=d.sigma, lambda1=d.lambda1, lambda2=d.lambda2, hint=d.hint
        )
    epochs = params.effective().epochs

    def report(step: int, n: int, train_l1: float, test_l1: float) -> None:
        frac = P_LOADED + (P_FITTED - P_LOADED) * step / n
        ctx.progress(frac, f"step {step}/{n}: train L1 {train_l1:.4g}, held-out {test_l1:.4g}")

    gen = torch.Generator().manual_seed(ctx.sub_seed("train.btf/jitter"))
    order = ctx.rng("train.btf/order")
    cfg = FitConfig(
        epochs=epochs,
        check_steps=params.check_steps,
        plateau_steps=params.effective().plateau_steps,
    )
    curves = fit(net, data, train, test, cfg, gen, order,
                 distill=distill, on_progress=report,
                 on_curves=lambda c: ctx.publish("curves.json", c.as_dict()))  # fmt: skip
    return net.eval(), curves


def _fit_lafortune(
    params: TrainBtfParams, ctx: JobContext, data: BtfDataset, train: np.ndarray
) -> PortableBtf:
    eff = params.effective()
    limit = eff.lafortune_slices
    use = train
    if limit is not None and len(train) > limit:
        use = train[np.linspace(0, len(train) - 1, limit).round().astype(int)]
    h, w = data.resolution
    values = np.empty((h * w, len(use), 3), np.float32)
    for k, (_, rgb) in enumerate(data.iter_slices(use)):
        values[:, k, :] = rgb.reshape(-1, 3)
    wi, wo = data.wi[use].astype(np.float64), data.wo[use].astype(np.float64)
    mean = (values / np.maximum(wi[None, :, 2:3], 1e-3)).mean(axis=1)
    iters = eff.lafortune_iterations

    def progress(f: float) -> None:
        ctx.progress(P_LOADED + (P_FITTED - P_LOADED) * f, f"Levenberg-Marquardt: {100 * f:.0f} %")

    result = fit_lafortune(values, wi, wo, iterations=iters, init=initial_params(mean),
                           progress=progress)  # fmt: skip
    tex = {"params": result.params.reshape(h, w, PARAMS_PER_TEXEL).astype(np.float32)}
    arch = {"model": "lafortune", "width": 0, "resolution": [h, w], "lobes": 4,
            "params_per_texel": PARAMS_PER_TEXEL, "fit_slices": int(len(use))}  # fmt: skip
    doc = model_document("lafortune", arch, {}, tex, {})
    return read_model(doc, tex)


def _portable_slice_l1(model: PortableBtf, data: BtfDataset, indices: np.ndarray) -> np.ndarray:
    """Per-slice mean absolute error of the portable model (as :func:`slice_l1`)."""
    return predicted_slice_l1(model.slice, data, indices)


def _mean_of(values: np.ndarray, indices: np.ndarray) -> float:
    return float(np.mean(values[indices])) if len(indices) else float("nan")


def train_and_report(params: TrainBtfParams, ctx: JobContext) -> None:
    """Run a ``train.btf`` job end to end."""
    started = time.perf_counter()
    ctx.progress(0.0, "loading the BTF")
    data = BtfDataset.open(params.data, ctx)
    eff = params.effective()
    holdout = float(eff.holdout)
    train, test = data.split(holdout)
    h, w = data.resolution
    ctx.progress(
        P_LOADED, f"{len(data)} slices of {w}x{h}: {len(train)} train, {len(test)} held out"
    )
    label = label_of(params)
    training = {
        "params": params.model_dump(mode="json"),
        "resolved": {"epochs": eff.epochs, "check_steps": params.check_steps,
                     "plateau_steps": eff.plateau_steps, "holdout": eff.holdout,
                     "lafortune_iterations": eff.lafortune_iterations,
                     "lafortune_slices": eff.lafortune_slices},
        "seed": ctx.seed, "data": params.data, "label": label,
    }  # fmt: skip
    curves: Curves | None = None
    with deterministic_torch():
        if params.model == "lafortune":
            pick_device(params.device)  # 'cuda' on a worker without one still fails here
            ctx.use_device("cpu")  # Levenberg-Marquardt runs in float64 on the CPU
            model = _fit_lafortune(params, ctx, data, train)
            model.doc["training"] = training
        else:
            net, curves = _fit_network(params, ctx, data, train, test)
            tex = network_textures(net)
            arch = dict(getattr(net, "arch").as_dict())  # noqa: B009 (a Module attribute)
            doc = model_document(params.model, arch, network_layers(net), tex, training)
            model = read_model(doc, tex)
        fit_seconds = time.perf_counter() - started
        ctx.progress(P_FITTED, "scoring the whole BTF")
        everything = np.arange(len(data))
        if params.model == "lafortune":
            per_slice = _portable_slice_l1(model, data, everything)
        else:
            per_slice = slice_l1(net, data, everything)
    l1_train, l1_test = _mean_of(per_slice, train), _mean_of(per_slice, test)
    n_all = len(train) + len(test)
    l1 = float(np.mean(per_slice))
    slice_scale = slice_mean_abs(data)
    scale = float(np.mean(slice_scale))
    storage = model.doc["storage"]
    metrics = {
        "model": params.model,
        "label": label,
        "l1": l1,
        "l1_train": l1_train,
        "l1_heldout": l1_test if len(test) else None,
        "relative_l1": l1 / max(scale, 1e-12),
        "mean_abs_btf": scale,
        "slices": {"total": n_all, "train": int(len(train)), "heldout": int(len(test))},
        "storage": {k: storage[k] for k in ("texture_bytes", "network_bytes", "total_bytes")},
        "storage_at_400": _storage_at(model, (400, 400)),
        "cases": case_errors(data.wi, data.wo, per_slice, slice_scale)
        + [fine_detail_error(model.slice, data, detail_slices(len(data), test))],
        "definition": "l1: mean absolute error over every slice, texel and channel of the "
        "BTF (Table 1), in BTF units (1/sr); l1_train / l1_heldout over those slices only; "
        "cases: the same over the slices of each failure case (models.btf.cases), "
        "relative_l1 over their own mean |BTF|; fine_detail: the error of the detail "
        "within 2 x 2 blocks (the paper's Fig. 15 failure) over the held-out slices",
    }
    ctx.progress(P_SCORED, "writing artifacts")
    ctx.put_json("model.json", model.doc)
    ctx.put_bytes("textures.npz", textures_bytes(model.textures), "application/x-npz")
    ctx.put_json("metrics.json", metrics)
    if curves is not None:
        ctx.put_json("curves.json", curves.as_dict())
        ctx.put_bytes("curves.png", curves_png(curves, f"train.btf: {label}"), "image/png")
    shown = (test if len(test) else train)[:SHOWN]
    ctx.put_bytes("reconstructions.png", reconstructions_png(model, data, shown, label),
                  "image/png")  # fmt: skip
    log.info("train.btf %s: %s, %d slices, fit %.1f s", ctx.job_id, label, n_all, fit_seconds)
    rel = l1 / max(scale, 1e-12)
    ctx.progress(1.0, f"{label}: L1 {l1:.4g} ({100 * rel:.1f} % of the mean), "
                      f"{storage['total_bytes'] / 1e6:.2f} MB; {fit_seconds:.0f} s")  # fmt: skip


def _storage_at(model: PortableBtf, res: tuple[int, int]) -> dict[str, int]:
    """Storage the same model would need at ``res`` texels (Table 1 is at 400^2)."""
    h, w = model.resolution
    per_texel = float(model.doc["storage"]["texture_bytes"]) / (h * w)
    tex = int(round(per_texel * res[0] * res[1]))
    net = int(model.doc["storage"]["network_bytes"])
    return {"texture_bytes": tex, "network_bytes": net, "total_bytes": tex + net}


def curves_png(curves: Curves, title: str) -> bytes:
    """Training L1 and held-out L1 against step (log scale); a short run's checks as dots
    too (a run of one check is a point, which a line alone does not show)."""
    marker = "o" if len(curves.step) <= 30 else None

    def draw(fig: Any, ax: Any) -> None:
        ax.plot(curves.step, curves.train_l1, label="train L1 (jittered)", marker=marker)
        ax.plot(curves.step, curves.test_l1, label="held-out L1", marker=marker)
        if curves.train_loss != curves.train_l1:
            ax.plot(curves.step, curves.train_loss, label="Eq. 5 loss", alpha=0.6, marker=marker)
        loss_axes(ax, "L1", title)

    return figure_png(draw)


def reconstructions_png(
    model: PortableBtf, data: BtfDataset, indices: np.ndarray, label: str
) -> bytes:
    """Fig. 8: for each slice, the truth, the model and the absolute error (magma, scaled
    to the slice's largest truth value)."""
    rows = []
    for i, rgb in data.iter_slices(indices):
        pred = model.slice(data.wi[i], data.wo[i])
        err = np.abs(pred - rgb).mean(axis=2) / max(float(rgb.max()), 1e-12)
        rows.append((i, rgb, pred, err))
    exposure = math.log2(math.pi)

    def draw(fig: Any, ax: Any) -> None:
        fig.clf()
        axes = fig.subplots(len(rows), 3, squeeze=False)
        for r, (i, rgb, pred, err) in enumerate(rows):
            wi, wo = data.wi[i], data.wo[i]
            ti, to = math.degrees(math.acos(wi[2])), math.degrees(math.acos(wo[2]))
            axes[r, 0].imshow(tonemap(rgb, exposure=exposure), origin="lower")
            axes[r, 0].set_ylabel(f"slice {i}\nθi {ti:.0f}° θo {to:.0f}°", fontsize=7)
            axes[r, 1].imshow(tonemap(pred, exposure=exposure), origin="lower")
            axes[r, 2].imshow(magma(np.clip(err * 4.0, 0, 1)), origin="lower")
            for c in range(3):
                axes[r, c].set_xticks([])
                axes[r, c].set_yticks([])
        for c, name in enumerate(("truth", label, "|error| x4 (of max)")):
            axes[0, c].set_title(name, fontsize=8)

    return figure_png(draw, size=(6.0, 2.0 * len(rows) + 0.4))
