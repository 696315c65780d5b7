"""The fitting loop of the hybrid-BRDF paper (Sec. 3.3): AdamW, cosine decay, clipping.

De Oliveira et al., "A Hybrid Neural-Microfacet BRDF Model for Real-Time Rendering": the
shared weights ``w`` and the per-material ``(z, p)`` are optimised jointly by mini-batch
AdamW on Eq. 4 (:mod:`models.brdf.losses`), learning rate ``lr`` with a cosine decay to 0
over ``steps``, gradient norms clipped at ``clip`` (the paper: lr 0.005, 200k steps, clip
0.01). Each step draws ``batch_pairs`` cosine-weighted pairs per material
(:func:`models.brdf.data.draw_batch`).

Weight decay (AdamW's decoupled decay, ``weight_decay``) applies to the network weights
only: decaying the unconstrained per-material values would pull every material toward
``kd = 0.5``, ``eta = 5.5`` and ``z = 0``, a prior the paper does not state.

Freezing (Sec. 4.2, "Sparse Training"): with ``train_network=False`` only ``(z, p)`` move;
the network's tensors are left bit-for-bit unchanged.

Stability: the loss and the gradient norm are checked at every step. A non-finite value,
or a loss above ``max(DIVERGENCE_FACTOR * first loss, DIVERGENCE_FLOOR)``, raises
:class:`~jobapi.errors.JobFailed` naming the step and suggesting a lower ``lr``; so does a
non-finite parameter at the end. A silent bad model is never returned.

Determinism: :func:`deterministic_torch` fixes the thread count (:data:`TORCH_THREADS`) and
enables ``torch.use_deterministic_algorithms``; all randomness comes from the caller's
``torch.Generator``. On one machine and torch build the same inputs give the same bytes.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor

from jobapi.errors import JobFailed
from models.brdf.data import draw_batch
from models.brdf.losses import joint_loss
from models.brdf.networks import BrdfModel

#: Threads of every training run: fixed so that results do not depend on the machine's size.
#: One, measured: on the shared 2-core machines a second OpenMP thread spin-waits against the
#: other tenants' processes and made a 12-material 32x3 hybrid step 8x slower (414 vs 50 ms at
#: load average 6), while an idle machine gains under 2x from it.
TORCH_THREADS = 1
#: Divergence: a loss above max(factor * the first step's loss, floor) fails the job.
DIVERGENCE_FACTOR = 100.0
DIVERGENCE_FLOOR = 10.0
#: Points of the loss curve (``curves.json``); each is the mean over its interval of steps.
CURVE_POINTS = 200

#: ``on_progress(step, steps, loss)``; may raise (e.g. to cancel).
ProgressFn = Callable[[int, int, float], None]


@contextmanager
def deterministic_torch(threads: int = TORCH_THREADS) -> Iterator[None]:
    """Fix torch's CPU thread count and use deterministic algorithms; restore on exit."""
    old_threads = torch.get_num_threads()
    old_det = torch.are_deterministic_algorithms_enabled()
    if threads != old_threads:  # set_num_threads restarts the pool even when unchanged
        torch.set_num_threads(threads)
    # warn_only: CUDA matmuls need an environment variable for determinism; CPU has none.
    torch.use_deterministic_algorithms(True, warn_only=True)
    try:
        yield
    finally:
        torch.use_deterministic_algorithms(old_det)
        if threads != old_threads:
            torch.set_num_threads(old_threads)


@dataclass(frozen=True)
class FitConfig:
    """Optimiser settings of one fitting phase (Sec. 3.3)."""

    steps: int
    batch_pairs: int
    lr: float
    weight_decay: float
    clip: float
    train_network: bool = True


@dataclass
class Curves:
    """Loss against step: each point is the mean over the steps since the previous one."""

    step: list[int] = field(default_factory=list)
    loss: list[float] = field(default_factory=list)
    loss_analytic: list[float | None] = field(default_factory=list)
    loss_hybrid: list[float | None] = field(default_factory=list)
    lr: list[float] = field(default_factory=list)
    seconds: float = 0.0

    def as_dict(self) -> dict[str, list[int] | list[float] | list[float | None]]:
        """JSON-ready lists (no timing, so that the same spec gives the same bytes)."""
        return {
            "step": self.step,
            "loss": self.loss,
            "loss_analytic": self.loss_analytic,
            "loss_hybrid": self.loss_hybrid,
            "lr": self.lr,
        }


def curves_document(phases: dict[str, Curves | None]) -> dict[str, Any]:
    """The ``curves.json`` document of a run's phases (``train``, then ``heldout`` when it
    has held-out materials), in the one schema of :mod:`jobapi.documents`: ``step`` counts
    on across phases (as the progress messages do), ``phases`` says where each one starts and
    ends, and a series that no point measures (``loss_hybrid`` of an analytic model) is left
    out."""
    step: list[int] = []
    series: dict[str, list[float | None]] = {k: [] for k in SERIES}
    spans = []
    offset = 0
    for name, c in phases.items():
        if c is None or not c.step:
            continue
        step += [offset + s for s in c.step]
        for key in SERIES:
            series[key] += getattr(c, key)
        spans.append({"name": name, "first_step": offset + 1, "last_step": offset + c.step[-1]})
        offset += c.step[-1]
    doc: dict[str, Any] = {"step": step, "phases": spans}
    doc.update({k: v for k, v in series.items() if any(x is not None for x in v)})
    return doc


#: The series of ``curves.json`` (:func:`curves_document`).
SERIES = ("loss", "loss_analytic", "loss_hybrid", "lr")


def _diverged(phase: str, step: int, steps: int, what: str, lr: float) -> JobFailed:
    return JobFailed(
        f"{phase}: training diverged at step {step}/{steps} ({what}); the model is "
        f"discarded. Lower lr (now {lr:g}) or clip, or check the dataset"
    )


def fit(
    model: BrdfModel,
    tables: Tensor,
    config: FitConfig,
    generator: torch.Generator,
    *,
    on_progress: ProgressFn | None = None,
    on_curves: Callable[[Curves], object] | None = None,
    phase: str = "train",
) -> Curves:
    """Fit ``model`` (its ``M`` materials) to ``tables`` ``(M, 90, 90, P, 3)`` in place.

    Returns the loss curve; ``on_curves(curves)`` is called each time a point is added
    (the live chart). Raises :class:`JobFailed` on divergence (see module docstring).
    """
    if tables.shape[0] != model.n_materials:
        raise ValueError(f"{tables.shape[0]} tables for {model.n_materials} materials")
    net = model.network_parameters()
    mats = model.material_parameters()
    for p in net:
        p.requires_grad_(config.train_network)
    trainable = mats + (net if config.train_network else [])
    groups: list[dict[str, Any]] = [{"params": mats, "weight_decay": 0.0}]
    if config.train_network and net:
        groups.append({"params": net, "weight_decay": config.weight_decay})
    opt = torch.optim.AdamW(groups, lr=config.lr, foreach=False)
    steps = config.steps
    sched = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda t: 0.5 * (1.0 + math.cos(math.pi * min(t, steps) / steps))
    )
    every = max(1, math.ceil(steps / CURVE_POINTS))
    report_every = max(1, steps // 100)
    curves = Curves()
    sums = [0.0, 0.0, 0.0]
    n_sum = 0
    limit = math.inf
    started = time.perf_counter()
    model.train()
    for step in range(1, steps + 1):
        lr = opt.param_groups[0]["lr"]
        batch = draw_batch(tables, config.batch_pairs, generator)
        out = model(batch.wi, batch.wo)
        parts = joint_loss(model.arch.model, out, batch.reference, batch.cos_i, batch.valid)
        opt.zero_grad(set_to_none=True)
        parts.total.backward()
        grad_norm = float(torch.nn.utils.clip_grad_norm_(trainable, config.clip, foreach=False))
        loss = float(parts.total.detach())
        if not (math.isfinite(loss) and math.isfinite(grad_norm)):
            raise _diverged(phase, step, steps, f"loss {loss}, gradient norm {grad_norm}", lr)
        if step == 1:
            limit = max(DIVERGENCE_FACTOR * loss, DIVERGENCE_FLOOR)
        elif loss > limit:
            raise _diverged(phase, step, steps, f"loss {loss:.4g} > {limit:.4g}", lr)
        opt.step()
        sched.step()
        sums[0] += loss
        sums[1] += float(parts.analytic.detach()) if parts.analytic is not None else 0.0
        sums[2] += float(parts.hybrid.detach()) if parts.hybrid is not None else 0.0
        n_sum += 1
        if step % every == 0 or step == steps:
            curves.step.append(step)
            curves.loss.append(sums[0] / n_sum)
            curves.loss_analytic.append(sums[1] / n_sum if parts.analytic is not None else None)
            curves.loss_hybrid.append(sums[2] / n_sum if parts.hybrid is not None else None)
            curves.lr.append(lr)
            sums, n_sum = [0.0, 0.0, 0.0], 0
            if on_curves is not None:
                on_curves(curves)
        if on_progress is not None and (step % report_every == 0 or step == steps):
            on_progress(step, steps, loss)
    model.eval()
    for p in net:
        p.requires_grad_(True)
    bad = [n for n, p in model.named_parameters() if not bool(torch.isfinite(p).all())]
    if bad:
        raise _diverged(phase, steps, steps, f"non-finite parameters {', '.join(bad)}", config.lr)
    curves.seconds = time.perf_counter() - started
    return curves
