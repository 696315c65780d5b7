"""The training loss of the hybrid-BRDF paper: Eq. 4 (joint objective) and Eq. 5 (metric).

De Oliveira et al., "A Hybrid Neural-Microfacet BRDF Model for Real-Time Rendering", Sec. 3.3.

Eq. 5: ``L(f1, f2) = || log(1 + cos(theta_i) f1) - log(1 + cos(theta_i) f2) ||^2``, the
squared Euclidean norm over the RGB channels of one direction pair. The log compresses the
dynamic range and the cosine down-weights grazing incidence.

Eq. 4: ``sum_i sum_(w in B) L_a(f^i, f_a) + L_t(f^i, f_t)`` over materials ``i`` and pairs.
We take the *mean* over materials and valid pairs instead of the sum: a constant factor
``1 / (M |B|)``, which leaves AdamW's steps unchanged but sets the scale at which the
gradient-norm clip of Sec. 3.3 (0.01) applies. Pairs where the reference table has no data
(negative values) get weight zero.

Which terms each model fits: ``hybrid`` ``L_a + L_t`` (Eq. 4); ``analytic`` ``L_a`` alone
(its ``f_t`` is ``f_a``, so Eq. 4 would just double it); ``neural`` ``L_t`` alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from models.brdf.networks import BrdfOutput, ModelType


def log_cos_error(reference: Tensor, model: Tensor, cos_i: Tensor) -> Tensor:
    """Eq. 5 per pair: ``sum_rgb (log1p(cos_i f_ref) - log1p(cos_i f_model))^2``.

    ``reference``, ``model``: ``(..., 3)`` BRDF values (1/sr, non-negative);
    ``cos_i``: ``(..., 1)``. Returns ``(...)``.
    """
    diff = torch.log1p(cos_i * reference) - torch.log1p(cos_i * model)
    return (diff * diff).sum(dim=-1)


@dataclass
class LossParts:
    """The scalar objective and its two means (``None`` where a term is not fitted)."""

    total: Tensor
    analytic: Tensor | None
    hybrid: Tensor | None


def joint_loss(
    model_type: ModelType, out: BrdfOutput, reference: Tensor, cos_i: Tensor, valid: Tensor
) -> LossParts:
    """Eq. 4 as a mean over valid pairs (see the module docstring for the terms per model).

    ``reference``: ``(M, B, 3)`` table values with clamped missing entries; ``valid``:
    ``(M, B)`` bool, pairs with data; ``cos_i``: ``(M, B, 1)``.
    """
    weight = valid.to(reference.dtype)
    count = weight.sum().clamp_min(1.0)
    ref = reference.clamp_min(0.0)

    def mean_error(f: Tensor) -> Tensor:
        return (log_cos_error(ref, f, cos_i) * weight).sum() / count

    l_a = mean_error(out.f_a) if model_type != "neural" and out.f_a is not None else None
    l_t = mean_error(out.f) if model_type != "analytic" else None
    terms = [t for t in (l_a, l_t) if t is not None]
    return LossParts(total=torch.stack(terms).sum(), analytic=l_a, hybrid=l_t)
