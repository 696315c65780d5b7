"""A GGX + Lambert BRDF in plain PyTorch, written for tests from the formulas (Walter et al.
2007: the GGX ``D`` and the separable Smith ``G1``), not with matforge's code."""

from __future__ import annotations

import math

import torch


class GgxLambert(torch.nn.Module):
    """``f(wi, wo) = kd / pi + ks D(h) G1(wi) G1(wo) / (4 cos_i cos_o)``: a Lambertian base
    plus a GGX microfacet lobe of roughness ``alpha`` with Fresnel 1 (a perfect mirror's
    microfacets). ``forward(wi, wo)``: ``(N, 3)`` local unit vectors, z up, to ``(N, 3)``
    RGB in 1/sr, no cosine."""

    def __init__(self, kd: list[float], ks: list[float], alpha: float) -> None:
        super().__init__()
        self.register_buffer("kd", torch.tensor(kd, dtype=torch.float32))
        self.register_buffer("ks", torch.tensor(ks, dtype=torch.float32))
        self.alpha = float(alpha)

    def forward(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        a2 = self.alpha**2
        h = wi + wo
        h = h / torch.sqrt((h * h).sum(dim=1, keepdim=True))
        cos_h = h[:, 2:3]
        d = a2 / (math.pi * (cos_h * cos_h * (a2 - 1.0) + 1.0) ** 2)

        def g1(w: torch.Tensor) -> torch.Tensor:
            c2 = torch.clamp(w[:, 2:3] * w[:, 2:3], min=1e-12)
            return 2.0 / (1.0 + torch.sqrt(1.0 + a2 * (1.0 - c2) / c2))

        cos_i = torch.clamp(wi[:, 2:3], min=1e-6)
        cos_o = torch.clamp(wo[:, 2:3], min=1e-6)
        spec = d * g1(wi) * g1(wo) / (4.0 * cos_i * cos_o)
        return self.kd / math.pi + self.ks * spec


def mitsuba_twin(kd: list[float], ks: list[float], alpha: float) -> dict[str, object]:
    """Mitsuba's own BSDF of the same BRDF: ``blendbsdf`` (weight 0.5) of ``diffuse``
    (reflectance ``2 kd``) and ``roughconductor`` (GGX, ``alpha``, material ``none``: Fresnel
    1, specular reflectance ``2 ks``)."""
    return {
        "type": "blendbsdf",
        "weight": 0.5,
        "diffuse": {
            "type": "diffuse",
            "reflectance": {"type": "rgb", "value": [2 * x for x in kd]},
        },
        "conductor": {
            "type": "roughconductor",
            "distribution": "ggx",
            "alpha": alpha,
            "material": "none",
            "specular_reflectance": {"type": "rgb", "value": [2 * x for x in ks]},
        },
    }
