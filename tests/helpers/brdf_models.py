"""``model.json`` documents of random-but-plausible trained BRDF models, for tests.

Models are written by :func:`models.brdf.portable.to_portable` from freshly initialised torch
models whose weights are perturbed (corrections of a few 0.01-0.1 /sr, gates between 0.3
and 0.95) and whose materials get the chosen ``kd``, ``eta``, ``alpha`` of :data:`MATERIALS`.
"""

from __future__ import annotations

from typing import Any

#: name -> (kd, eta, alpha): a rough gold-like metal, a glossy blue plastic, a sharp one.
MATERIALS = {
    "gold": ((0.02, 0.015, 0.01), (4.0, 2.2, 1.4), 0.25),
    "plastic": ((0.2, 0.45, 0.7), (1.5, 1.5, 1.5), 0.12),
    "sharp": ((0.05, 0.05, 0.05), (2.5, 2.5, 2.5), 0.1),
}


def make_model(kind: str, width: int, depth: int, latent: int, seed: int = 0) -> dict[str, Any]:
    """A ``model.json`` document with random-but-plausible weights (see the module doc)."""
    import torch

    from models.brdf.networks import Architecture, build_model
    from models.brdf.portable import to_portable

    gen = torch.Generator().manual_seed(seed)
    sizes = (width, depth, latent) if kind != "analytic" else (0, 0, 0)
    arch = Architecture(kind, *sizes)  # type: ignore[arg-type]
    model = build_model(arch, len(MATERIALS), gen)
    with torch.no_grad():
        for p in model.network_parameters():
            p.add_(0.3 * torch.randn(p.shape, generator=gen))
        if kind != "analytic":
            model.z.normal_(0.0, 1.0, generator=gen)
    doc = to_portable(model, list(MATERIALS), ["test"] * len(MATERIALS))
    for mat in doc["materials"]:
        if kind != "neural":
            kd, eta, alpha = MATERIALS[mat["name"]]
            mat.update(kd=list(kd), eta=list(eta), alpha=alpha)
    return doc
