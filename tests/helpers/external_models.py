"""Independent torch references for the external-model tests: written here from the papers'
formulas with trig and rotation matrices, not with matforge's code.

- ``ggx_lambert``: ``kd / pi + D G F / (4 cos_i cos_o)``; GGX ``D`` (Walter et al. 2007,
  Eq. 33), Smith ``G1`` of GGX (Eq. 34) applied separably, exact unpolarised Fresnel of a
  dielectric of real IOR ``eta`` at ``dot(wi, h)`` (Born and Wolf).
- ``difference``: Rusinkiewicz 1998: ``wi`` rotated by ``-phi_h`` about z and ``-theta_h``
  about y, with the angles from ``atan2`` and ``acos``.
"""

from __future__ import annotations

import math

import torch


def ggx_lambert(
    wi: torch.Tensor, wo: torch.Tensor, kd: torch.Tensor, alpha: float, eta: torch.Tensor
) -> torch.Tensor:
    h = torch.nn.functional.normalize(wi + wo, dim=1)
    a2 = alpha * alpha
    cos_h = h[:, 2]
    d = a2 / (math.pi * ((a2 - 1.0) * cos_h**2 + 1.0) ** 2)

    def g1(v: torch.Tensor) -> torch.Tensor:
        cos = v[:, 2]
        tan2 = (1.0 - cos**2) / cos**2
        return 2.0 / (1.0 + torch.sqrt(1.0 + a2 * tan2))

    c = torch.clamp((wi * h).sum(dim=1, keepdim=True), 0.0, 1.0)
    sin_t2 = (1.0 - c**2) / eta**2
    cos_t = torch.sqrt(1.0 - sin_t2)
    r_s = (c - eta * cos_t) / (c + eta * cos_t)
    r_p = (eta * c - cos_t) / (eta * c + cos_t)
    fresnel = 0.5 * (r_s**2 + r_p**2)
    spec = (d * g1(wi) * g1(wo) / (4.0 * wi[:, 2] * wo[:, 2]))[:, None]
    return kd / math.pi + spec * fresnel


def difference(wi: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
    theta = torch.acos(torch.clamp(h[:, 2], -1.0, 1.0))
    phi = torch.atan2(h[:, 1], h[:, 0])
    zero, one = torch.zeros_like(phi), torch.ones_like(phi)
    rz = torch.stack(
        [
            torch.stack([torch.cos(-phi), -torch.sin(-phi), zero], 1),
            torch.stack([torch.sin(-phi), torch.cos(-phi), zero], 1),
            torch.stack([zero, zero, one], 1),
        ],
        1,
    )
    ry = torch.stack(
        [
            torch.stack([torch.cos(-theta), zero, torch.sin(-theta)], 1),
            torch.stack([zero, one, zero], 1),
            torch.stack([-torch.sin(-theta), zero, torch.cos(-theta)], 1),
        ],
        1,
    )
    return torch.einsum("nij,njk,nk->ni", ry, rz, wi)


def hemisphere(gen: torch.Generator, n: int, min_z: float = 0.05) -> torch.Tensor:
    """``(n, 3)`` float64 unit directions with ``z >= min_z``."""
    z = min_z + (1.0 - min_z) * torch.rand(n, generator=gen, dtype=torch.float64)
    phi = 2.0 * math.pi * torch.rand(n, generator=gen, dtype=torch.float64)
    r = torch.sqrt(1.0 - z * z)
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], 1)
