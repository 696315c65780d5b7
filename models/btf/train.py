"""Training of the neural BTF models (Xu et al., Sec. 4.3-4.4).

"We apply the Adam optimizer with beta_1 = 0.9, beta_2 = 0.999, and epsilon = 1e-8. We decay
the learning rate from 5e-4 to 1e-7 using the ReduceLROnPlateau scheduler. It will halve
the learning rate when the decreased testing L1 error is smaller than a threshold (1e-4) in
each epoch. For each training step, we take a 2D slice from the BTF dataset under the same
viewing and lighting angles as one batch. We apply stratified sampling to the neural
textures." Here exactly that: one slice per step (its texels in one batch), every training
slice once per epoch in a seeded random order, the textures sampled at a uniform point of
each texel (:func:`models.btf.networks.texel_grid`), ``ReduceLROnPlateau(factor 0.5,
patience 0, threshold 1e-4 absolute, min_lr 1e-7)`` stepped on the held-out L1 after each
epoch (on the training L1 when nothing is held out) -- or every ``plateau_steps`` steps
(see :class:`FitConfig`).

**Distillation** (Eq. 5): ``L = L1(y_s, y_gt) + sigma L1(y_s, y_t) + lambda_1 L2(z_s1,
T_1 z_t1) + lambda_2 L2(z_s2, T_2 z_t2)``, the teacher (a trained NeuMIP Max) frozen and
evaluated at the same texture points; ``T_1``, ``T_2`` learned linear maps (no bias,
teacher width -> student width) trained with the student. Taps: the student's ``z_c`` and
fine hidden layer, the teacher's second and third hidden layers.

**The hint terms** (``L2`` above, :func:`hint_loss`), two forms (``Distillation.hint``):

- ``"mse"`` (the default, the form of every earlier spec, whose bytes it keeps): the mean
  squared error. Its size is that of the features: the student's are about 0.1, so at
  ``lambda = 0.1`` the two hints carried 0.5 % and 0.3 % of the ground-truth L1 term's
  gradient on the student's weights, and ``z_s = T z_t`` is degenerate in scale: with ReLU
  networks the student can shrink ``z_c`` (and grow the next layer's weights) while ``T``
  shrinks with it, which lowers the hint to zero without matching anything (``z_c``'s RMS
  halved under distillation).
- ``"standardised"``: each feature (column) of both sides standardised over the slice's
  texels (zero mean, unit variance, :data:`HINT_EPS` added to the variance) before the mean
  squared error; per feature that is ``2 (1 - r)``, ``r`` the correlation of the student's
  feature with its mapped teacher feature. It is invariant to the scale (and offset) of
  either side, so shrinking cannot lower it, and it is of order 1 whatever the features'
  size, so ``lambda`` weighs it against L1 directly. Chosen over dividing by the teacher
  features' variance because that variance is fixed while ``T`` is learned: ``T`` and the
  student could still shrink together.

Stability: a non-finite loss fails the job naming the epoch and step. Determinism: run in
:func:`models.brdf.train.deterministic_torch`; the slice order comes from a numpy
Generator, the texture jitter from a torch Generator, both seeded by the job.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import nn

from jobapi.errors import JobFailed
from models.btf.data import BtfDataset
from models.btf.networks import slice_forward

#: Adam and the scheduler (Sec. 4.4).
BETAS, EPS = (0.9, 0.999), 1e-8
LR, MIN_LR, PLATEAU_FACTOR, PLATEAU_THRESHOLD = 5e-4, 1e-7, 0.5, 1e-4

#: The forms of Eq. 5's hint terms (see the module docstring); the first is the default.
HINTS = ("mse", "standardised")
#: Added to each feature's variance in the standardised hint (features are about 0.1, so
#: variances about 1e-2): bounds the gain on a nearly constant (dead ReLU) feature at 1e3.
HINT_EPS = 1e-6

#: ``on_progress(step, steps, train_l1, test_l1)`` at each check; may raise (e.g. to cancel).
ProgressFn = Callable[[int, int, float, float], None]


@dataclass(frozen=True)
class Distillation:
    """A frozen ``teacher``, the weights of Eq. 5 (0.1 each in the paper) and the form of
    its hint terms (:data:`HINTS`)."""

    teacher: nn.Module
    sigma: float = 0.1
    lambda1: float = 0.1
    lambda2: float = 0.1
    taps: tuple[int, int] = (1, 2)
    hint: str = "mse"

    def __post_init__(self) -> None:
        if self.hint not in HINTS:
            raise ValueError(f"hint {self.hint!r}: use one of {', '.join(HINTS)}")


def _standardise(z: torch.Tensor) -> torch.Tensor:
    mean = z.mean(dim=0, keepdim=True)
    var = z.var(dim=0, unbiased=False, keepdim=True)
    return (z - mean) / torch.sqrt(var + HINT_EPS)


def hint_loss(student: torch.Tensor, target: torch.Tensor, form: str = "mse") -> torch.Tensor:
    """One hint term of Eq. 5 between the student's features ``(N, C)`` and the mapped
    teacher features ``(N, C)`` (``T z_t``), rows the slice's texels: the mean squared
    error (``"mse"``), or that of both sides standardised per feature (``"standardised"``;
    see the module docstring)."""
    if form == "mse":
        return torch.mean((student - target) ** 2)
    if form == "standardised":
        return torch.mean((_standardise(student) - _standardise(target)) ** 2)
    raise ValueError(f"hint {form!r}: use one of {', '.join(HINTS)}")


class _Maps(nn.Module):
    def __init__(self, teacher_width: int, student_width: int, gen: torch.Generator) -> None:
        super().__init__()
        self.t1 = nn.Linear(teacher_width, student_width, bias=False)
        self.t2 = nn.Linear(teacher_width, student_width, bias=False)
        bound = 1.0 / math.sqrt(teacher_width)
        with torch.no_grad():
            self.t1.weight.uniform_(-bound, bound, generator=gen)
            self.t2.weight.uniform_(-bound, bound, generator=gen)


def eq5_terms(
    pred: torch.Tensor,
    target: torch.Tensor,
    taps: list[torch.Tensor],
    y_t: torch.Tensor,
    t_hidden: list[torch.Tensor],
    maps: _Maps,
    distill: Distillation,
) -> dict[str, torch.Tensor]:
    """Eq. 5's four terms, each with its weight: ``l1`` (to the ground truth),
    ``teacher_l1`` (``sigma L1(y_s, y_t)``), ``hint1`` and ``hint2`` (``lambda_i`` times
    :func:`hint_loss`); the loss is their sum."""
    a, b = distill.taps
    return {
        "l1": torch.mean(torch.abs(pred - target)),
        "teacher_l1": distill.sigma * torch.mean(torch.abs(pred - y_t)),
        "hint1": distill.lambda1 * hint_loss(taps[0], maps.t1(t_hidden[a]), distill.hint),
        "hint2": distill.lambda2 * hint_loss(taps[1], maps.t2(t_hidden[b]), distill.hint),
    }


@dataclass(frozen=True)
class FitConfig:
    """Epochs, the scheduler's and the curves' periods, and the Adam settings (defaults: the
    paper's).

    ``plateau_steps``: steps between scheduler steps (each on the held-out L1 then);
    ``None`` is once per epoch, the paper's. At the paper's scale an epoch is 20 000 steps;
    a small BTF's 32-step epoch would halve the rate after any epoch that gained less than
    1e-4, long before the model has learned anything, so the small preset steps it every
    1024 steps instead. The threshold is per scheduler step, so a shorter period halves the
    rate sooner: keep it near the paper's 20 000 steps wherever the BTF allows.
    ``check_steps``: steps between points of the curves (a held-out evaluation each);
    ``None``: at the scheduler's steps."""

    epochs: int
    check_steps: int | None = None
    plateau_steps: int | None = None
    lr: float = LR
    min_lr: float = MIN_LR


@dataclass
class Curves:
    """Per check: the step, epoch, mean training loss and L1 since the previous check,
    held-out L1 and the learning rate after the scheduler's step."""

    step: list[int] = field(default_factory=list)
    epoch: list[float] = field(default_factory=list)
    train_loss: list[float] = field(default_factory=list)
    train_l1: list[float] = field(default_factory=list)
    test_l1: list[float] = field(default_factory=list)
    lr: list[float] = field(default_factory=list)
    seconds: float = 0.0

    def as_dict(self) -> dict[str, object]:
        """JSON-ready lists; no timing (same spec, same bytes)."""
        return {
            "step": self.step,
            "epoch": self.epoch,
            "train_loss": self.train_loss,
            "train_l1": self.train_l1,
            "test_l1": self.test_l1,
            "lr": self.lr,
            "definition": "train_loss: Eq. 5 (L1 alone without distillation), mean over the "
            "steps since the previous check; train_l1: mean L1 to the ground truth over "
            "those steps (jittered texture samples); test_l1: mean absolute error over the "
            "held-out slices at texel centres (the training slices when none are held out)",
        }


def _device(net: nn.Module) -> torch.device:
    """Where ``net``'s parameters live: every tensor it meets goes there."""
    return next(net.parameters()).device


def _dirs(data: BtfDataset, i: int, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    return torch.from_numpy(data.wi[i]).to(device), torch.from_numpy(data.wo[i]).to(device)


@torch.no_grad()
def mean_l1(net: nn.Module, data: BtfDataset, indices: np.ndarray) -> float:
    """Mean absolute error of ``net`` over the slices ``indices`` (texel centres, all three
    channels): the mean of :func:`slice_l1` (slices are of equal size)."""
    if len(indices) == 0:
        return float("nan")
    return float(np.mean(slice_l1(net, data, indices)))


@torch.no_grad()
def slice_l1(net: nn.Module, data: BtfDataset, indices: np.ndarray) -> np.ndarray:
    """Mean absolute error of ``net`` on each slice of ``indices`` (``(len(indices),)``
    float64, in the order of ``indices``)."""
    out = np.full(len(indices), np.nan)
    where = {int(i): k for k, i in enumerate(indices)}
    dev = _device(net)
    for i, rgb in data.iter_slices(indices):
        wi, wo = _dirs(data, i, dev)
        pred, _ = slice_forward(net, wi, wo)
        err = float(torch.abs(pred - torch.from_numpy(rgb).to(dev).reshape(-1, 3)).sum())
        out[where[i]] = err / rgb.size
    return out


def fit(
    net: nn.Module,
    data: BtfDataset,
    train: np.ndarray,
    test: np.ndarray,
    cfg: FitConfig,
    gen: torch.Generator,
    order_rng: np.random.Generator,
    *,
    distill: Distillation | None = None,
    on_progress: ProgressFn | None = None,
    on_curves: Callable[[Curves], object] | None = None,
    on_terms: Callable[[dict[str, float]], object] | None = None,
) -> Curves:
    """Train ``net`` on the slices ``train`` for ``cfg.epochs`` epochs (see the module
    docstring); returns the curves. ``on_curves(curves)`` is called at each check (the
    live chart). ``on_terms`` (distillation only; an instrument, it costs four extra
    backward passes a step and changes nothing else): called each step with the norm of
    each Eq. 5 term's gradient on the student's network weights (textures excluded), by
    the names of :func:`eq5_terms`."""
    started = time.perf_counter()
    dev = _device(net)  # the data follow the network (models.device.pick_device)
    params = list(net.parameters())
    maps: _Maps | None = None
    if distill is not None:
        t_width = _width(distill.teacher)
        maps = _Maps(t_width, _width(net), gen).to(_device(net))
        params += list(maps.parameters())
        distill.teacher.eval()
    opt = torch.optim.Adam(params, lr=cfg.lr, betas=BETAS, eps=EPS)
    sched = torch.optim.lr_scheduler.ReduceLROnPlateau(
        opt, mode="min", factor=PLATEAU_FACTOR, patience=0, threshold=PLATEAU_THRESHOLD,
        threshold_mode="abs", min_lr=cfg.min_lr,
    )  # fmt: skip
    curves = Curves()
    scored = test if len(test) else train
    plateau = cfg.plateau_steps or len(train)
    period = cfg.check_steps or plateau
    total = cfg.epochs * len(train)
    loss_sum = l1_sum = 0.0
    since = step = 0
    for epoch in range(1, cfg.epochs + 1):
        net.train()
        for i, rgb in data.iter_slices(train, order_rng):
            wi, wo = _dirs(data, i, dev)
            target = torch.from_numpy(rgb).to(dev).reshape(-1, 3)
            # one jitter draw shared by student and teacher: same texture points
            state = gen.get_state()
            pred, taps = slice_forward(net, wi, wo, gen)
            l1 = torch.mean(torch.abs(pred - target))
            loss = l1
            if distill is not None and maps is not None:
                after = gen.get_state()
                gen.set_state(state)
                with torch.no_grad():
                    y_t, t_hidden = slice_forward(distill.teacher, wi, wo, _student_grid(net, gen))
                gen.set_state(after)
                terms = eq5_terms(pred, target, taps, y_t, t_hidden, maps, distill)
                loss = l1 + terms["teacher_l1"] + terms["hint1"] + terms["hint2"]
                if on_terms is not None:
                    on_terms(term_gradients(net, terms))
            if not torch.isfinite(loss):
                raise JobFailed(f"training diverged: non-finite loss at epoch {epoch}, slice {i}")
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            loss_sum += float(loss.detach())
            l1_sum += float(l1.detach())
            since += 1
            step += 1
            at_plateau = step % plateau == 0
            if since == period or step == total or at_plateau:
                net.eval()
                test_l1 = mean_l1(net, data, scored)
                net.train()
                if at_plateau:
                    sched.step(test_l1)
            if since == period or step == total:
                curves.step.append(step)
                curves.epoch.append(step / len(train))
                curves.train_loss.append(loss_sum / since)
                curves.train_l1.append(l1_sum / since)
                curves.test_l1.append(test_l1)
                curves.lr.append(float(opt.param_groups[0]["lr"]))
                loss_sum = l1_sum = 0.0
                since = 0
                if on_curves is not None:
                    on_curves(curves)
                if on_progress is not None:
                    on_progress(step, total, curves.train_l1[-1], test_l1)
    net.eval()
    curves.seconds = time.perf_counter() - started
    return curves


def term_gradients(net: nn.Module, terms: dict[str, torch.Tensor]) -> dict[str, float]:
    """The L2 norm of each term's gradient on ``net``'s network weights (every parameter
    but the neural textures); a term that does not reach a weight contributes zero there."""
    weights = [p for n, p in net.named_parameters() if "texture" not in n]
    out = {}
    for name, term in terms.items():
        grads = torch.autograd.grad(term, weights, retain_graph=True, allow_unused=True)
        out[name] = math.sqrt(sum(float((g.detach() ** 2).sum()) for g in grads if g is not None))
    return out


def _width(net: nn.Module) -> int:
    arch = getattr(net, "arch", None)
    if arch is None:
        raise TypeError("not a BTF network (no .arch)")
    return int(arch.width)


def _student_grid(net: nn.Module, gen: torch.Generator) -> torch.Generator:
    """The generator positioned so the teacher draws the student's *fine* texel points.

    The student draws its coarse block points first, then its texel points; the teacher
    draws only texel points. Skip the coarse draws so both see the same texel points."""
    from models.btf.networks import CoarseToFine

    if isinstance(net, CoarseToFine):
        h, w = net.arch.resolution
        torch.rand((h // 2) * (w // 2), generator=gen)
        torch.rand((h // 2) * (w // 2), generator=gen)
    return gen
