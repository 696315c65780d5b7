"""The training loop of Chen, Wang & Wang 2024, Sec. 5.2: SGD, step decay, random materials.

"using the SGD optimizer ... a learning rate of 5e-2 for all the weights, which decays by
0.2 at the sixth and ninth epoch [of 10], and we also add a regularization to all the
weights. During training, materials are randomly chosen for each iteration ... 512 queries
as one batch." Here: SGD with ``momentum`` (the paper does not say; 0 is plain SGD) and
``weight_decay`` (L2 on every weight), the rate multiplied by 0.2 after 60 % and 90 % of
``steps``. Each step draws ``materials_per_step`` distinct materials (all of them when
there are fewer) and ``batch // materials_per_step`` training queries of each, uniformly
with replacement; the encoder runs on the drawn materials' maps and the decoder on their
queries, so encoder and decoder train jointly as in the paper. Gradient norms are clipped
at ``clip`` (a guard for the early steps at the paper's rate).

Loss: ``loss`` ``"paper"`` is Eq. 9-11 (:func:`models.fabric.losses.fabric_loss`),
``"relative_l2"`` the unbiased relative L2 (:func:`models.fabric.losses.relative_l2_loss`,
with each material's per-kind component means as scales).

Stability: the loss and gradient norm are checked every step; a non-finite value or a loss
above ``max(DIVERGENCE_FACTOR * first loss, DIVERGENCE_FLOOR)`` raises
:class:`~jobapi.errors.JobFailed` naming the step; so does a non-finite weight at the end.

Determinism: run inside :func:`models.brdf.train.deterministic_torch` (one thread,
deterministic algorithms); every draw comes from the caller's ``torch.Generator`` on the
CPU, so the CPU and CUDA runs draw the same batches.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from jobapi.errors import JobFailed
from models.fabric.data import MaterialData
from models.fabric.losses import (
    MEAN_TERM_LOSSES,
    STDERR_LOSSES,
    component_scales,
    fabric_loss,
    log_targets,
    relative_l2_loss,
)
from models.fabric.networks import COMPONENTS, FabricNetwork, components

#: Divergence: a loss above max(factor * the first step's loss, floor) fails the job.
DIVERGENCE_FACTOR = 1000.0
DIVERGENCE_FLOOR = 100.0
#: Points of the loss curve; each the mean over its interval of steps.
CURVE_POINTS = 200
#: Learning-rate milestones (fractions of ``steps``) and factor (Sec. 5.2).
MILESTONES, GAMMA = (0.6, 0.9), 0.2

#: ``on_progress(step, steps, loss)``; may raise (e.g. to cancel).
ProgressFn = Callable[[int, int, float], None]


@dataclass(frozen=True)
class FitConfig:
    """Optimiser settings (see the module docstring)."""

    steps: int
    batch: int
    materials_per_step: int
    lr: float
    momentum: float
    weight_decay: float
    clip: float
    loss: str = "paper"


#: ``curves.json``'s ``loss_definition`` per loss.
LOSS_DEFINITIONS = {
    "paper": "Eq. 11: 0.4 (MSE S_warp + MSE S_weft) in log space (Eq. 9) "
    "+ 0.1 (MSE C_warp + MSE C_weft) (Eq. 10); mean per query",
    "relative_l2": "relative L2: mean over the 4 components of mean (p - y)^2 / (sg(p)^2 + "
    "m^2 + 1e-8), p linear (S = expm1(raw) / k), m the material's mean target per component "
    "and query kind; the curves' per-component values are these terms, not MSEs",
    "relative_l2_mean": "relative L2 with each denominator + se^2 (the target's Monte Carlo "
    "standard error), plus 1.0 x mean over (material, light side, component) of "
    "(batch mean residual)^2 / m^2; the curves' per-component values are the relative L2 "
    "terms",
    "relative_l2_stderr": "relative L2 with each denominator + se^2 (the target's Monte Carlo "
    "standard error), no mean term; the curves' per-component values are these terms",
    "relative_l2_meanterm": "relative L2 plus 1.0 x mean over (material, light side, "
    "component) of (batch mean residual)^2 / m^2, no standard errors; the curves' "
    "per-component values are the relative L2 terms",
}


@dataclass
class Curves:
    """Loss against step: each point is the mean over the steps since the previous one."""

    step: list[int] = field(default_factory=list)
    loss: list[float] = field(default_factory=list)
    components: dict[str, list[float]] = field(default_factory=lambda: {c: [] for c in COMPONENTS})
    lr: list[float] = field(default_factory=list)
    seconds: float = 0.0
    loss_name: str = "paper"
    #: Per component, ``sum pred / sum target`` over each interval's training batches (the
    #: decoded, rendered components: clamped, C = 0 below the horizon); the mean holds
    #: within +-3 % when it stays in [0.97, 1.03]. Only for the relative L2 losses.
    mean_ratio: dict[str, list[float]] | None = None

    def as_dict(self) -> dict[str, object]:
        """JSON-ready lists; no timing, so the same spec gives the same bytes."""
        out: dict[str, object] = {
            "step": self.step,
            "loss": self.loss,
            "mse": self.components,
            "lr": self.lr,
            "loss_definition": LOSS_DEFINITIONS[self.loss_name],
        }
        if self.mean_ratio is not None:
            out["mean_ratio"] = self.mean_ratio
        return out


def milestone_steps(steps: int) -> list[int]:
    """Steps after which the rate is multiplied by :data:`GAMMA`."""
    return sorted({max(1, int(round(f * steps))) for f in MILESTONES})


class TrainingSet:
    """Every material's maps, parameters and training queries, stacked on ``device``."""

    def __init__(self, materials: Sequence[MaterialData], device: str, loss: str = "paper") -> None:
        self.maps = torch.from_numpy(np.stack([m.maps for m in materials])).to(device)
        self.params = torch.from_numpy(np.stack([m.params for m in materials])).to(device)
        query = np.concatenate([m.query[m.train] for m in materials])
        value = np.concatenate([m.value[m.train] for m in materials])
        self.query = torch.from_numpy(query).to(device)
        self.target = log_targets(torch.from_numpy(value), torch.from_numpy(query[:, 5])).to(device)
        # The relative L2 needs linear targets and each row's scale (its material's mean
        # per component for the row's kind, BRDF or BTDF); the paper's loss neither.
        self.value: torch.Tensor | None = None
        self.scale: torch.Tensor | None = None
        self.stderr: torch.Tensor | None = None
        if loss.startswith("relative_l2"):
            scale = np.concatenate(
                [
                    component_scales(m.value[m.train], m.query[m.train, 5])[
                        (m.query[m.train, 5] < 0).astype(np.int64)
                    ]
                    for m in materials
                ]
            )
            self.value = torch.from_numpy(value).to(device)
            self.scale = torch.from_numpy(scale).to(device)
        if loss in STDERR_LOSSES:
            se = [m.stderr[m.train] if m.stderr is not None else None for m in materials]
            if any(x is None for x in se):
                raise JobFailed(f"dataset: {loss} needs the shards' stderr arrays")
            self.stderr = torch.from_numpy(np.concatenate(se)).to(device)  # type: ignore[arg-type]
        counts = [len(m.train) for m in materials]
        if min(counts) < 1:
            raise JobFailed("dataset: a material has no training queries (lower holdout)")
        self.counts = torch.tensor(counts, dtype=torch.float64)
        self.offsets = torch.tensor(np.concatenate([[0], np.cumsum(counts)[:-1]]), dtype=torch.long)
        self.n_materials = len(materials)
        self.device = device


def draw(
    data: TrainingSet, batch: int, per_step: int, generator: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(materials (B,), index (B*q,), rows (B*q,))`` of one step (CPU draws)."""
    b = min(per_step, data.n_materials)
    mats = torch.randperm(data.n_materials, generator=generator)[:b]
    q = max(1, batch // b)
    u = torch.rand((b, q), generator=generator, dtype=torch.float64)
    rows = data.offsets[mats][:, None] + (u * data.counts[mats][:, None]).long()
    index = torch.arange(b).repeat_interleave(q)
    return mats, index, rows.reshape(-1)


def _diverged(step: int, steps: int, what: str, lr: float) -> JobFailed:
    return JobFailed(
        f"training diverged at step {step}/{steps} ({what}); the model is discarded. "
        f"Lower lr (now {lr:g}) or clip, or check the dataset"
    )


def fit(
    net: FabricNetwork,
    data: TrainingSet,
    config: FitConfig,
    generator: torch.Generator,
    *,
    on_progress: ProgressFn | None = None,
    on_curves: Callable[[Curves], object] | None = None,
) -> Curves:
    """Train ``net`` in place on ``data``; returns the loss curve (see the module docstring).
    ``on_curves(curves)`` is called each time a point is added (the live chart)."""
    params = list(net.parameters())
    opt = torch.optim.SGD(
        params,
        lr=config.lr,
        momentum=config.momentum,
        weight_decay=config.weight_decay,
        foreach=False,
    )
    steps = config.steps
    sched = torch.optim.lr_scheduler.MultiStepLR(opt, milestone_steps(steps), gamma=GAMMA)
    every = max(1, math.ceil(steps / CURVE_POINTS))
    report_every = max(1, steps // 100)
    curves = Curves(loss_name=config.loss)
    loss_sum, comp_sum, n_sum = 0.0, torch.zeros(4, dtype=torch.float64), 0
    pred_sum, value_sum = torch.zeros(4, dtype=torch.float64), torch.zeros(4, dtype=torch.float64)
    if data.value is not None:
        curves.mean_ratio = {c: [] for c in COMPONENTS}
    limit = math.inf
    dev = data.device
    started = time.perf_counter()
    net.train()
    for step in range(1, steps + 1):
        lr = opt.param_groups[0]["lr"]
        mats, index, rows = draw(data, config.batch, config.materials_per_step, generator)
        mats, index, rows = mats.to(dev), index.to(dev), rows.to(dev)
        query = data.query[rows]
        raw = net(data.maps[mats], data.params[mats], index, query)
        if config.loss.startswith("relative_l2"):
            if data.value is None or data.scale is None:
                raise ValueError(f"{config.loss} needs TrainingSet(..., loss={config.loss!r})")
            weighted = config.loss in STDERR_LOSSES
            if weighted and data.stderr is None:
                raise ValueError(f"{config.loss} needs TrainingSet(..., loss={config.loss!r})")
            parts = relative_l2_loss(
                raw,
                data.value[rows],
                query[:, 5],
                data.scale[rows],
                stderr=data.stderr[rows] if weighted and data.stderr is not None else None,
                group=index if config.loss in MEAN_TERM_LOSSES else None,
            )
        else:
            parts = fabric_loss(raw, data.target[rows])
        opt.zero_grad(set_to_none=True)
        parts.total.backward()
        grad_norm = float(torch.nn.utils.clip_grad_norm_(params, config.clip, foreach=False))
        loss = float(parts.total.detach())
        if not (math.isfinite(loss) and math.isfinite(grad_norm)):
            raise _diverged(step, steps, f"loss {loss}, gradient norm {grad_norm}", lr)
        if step == 1:
            limit = max(DIVERGENCE_FACTOR * loss, DIVERGENCE_FLOOR)
        elif loss > limit:
            raise _diverged(step, steps, f"loss {loss:.4g} > {limit:.4g}", lr)
        opt.step()
        sched.step()
        loss_sum += loss
        comp_sum += parts.per_component.double().cpu()
        n_sum += 1
        if data.value is not None:
            with torch.no_grad():
                pred_sum += components(raw.detach(), query[:, 5]).double().sum(dim=0).cpu()
                value_sum += data.value[rows].double().sum(dim=0).cpu()
        if step % every == 0 or step == steps:
            curves.step.append(step)
            curves.loss.append(loss_sum / n_sum)
            for c, v in zip(COMPONENTS, (comp_sum / n_sum).tolist(), strict=True):
                curves.components[c].append(v)
            curves.lr.append(lr)
            if curves.mean_ratio is not None:
                ratio = torch.where(value_sum.abs() > 1e-30, pred_sum / value_sum, 1.0)
                for c, v in zip(COMPONENTS, ratio.tolist(), strict=True):
                    curves.mean_ratio[c].append(v)
                pred_sum.zero_()
                value_sum.zero_()
            loss_sum, comp_sum, n_sum = 0.0, torch.zeros(4, dtype=torch.float64), 0
            if on_curves is not None:
                on_curves(curves)
        if on_progress is not None and (step % report_every == 0 or step == steps):
            on_progress(step, steps, loss)
    net.eval()
    bad = [n for n, p in net.named_parameters() if not bool(torch.isfinite(p).all())]
    if bad:
        raise _diverged(steps, steps, f"non-finite weights {', '.join(bad[:3])}", config.lr)
    curves.seconds = time.perf_counter() - started
    return curves
