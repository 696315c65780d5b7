"""Mitsuba BSDF ``fabric_model``: a trained ``train.fabric`` network shades a pixel footprint.

Chen, Wang & Wang 2024, Sec. 4.3: the decoder replaces the Monte Carlo aggregate per
shading query. The plugin derives from the same footprint base as the Monte Carlo
``fabric_aggregate`` (:mod:`evaluators.render.bsdfs.fabric_footprint`: uv partials, sides,
cosine sampling, Eq. 8), and its ``estimate`` is the fused decoder of
:mod:`models.fabric.fused` (``decoder_drjit``) traced into the render kernel: deterministic
per footprint, so one sample per pixel is already noise-free in the footprint (the light
integral still needs samples). The material source that builds it (encoding the material's
latent, interpolating two) is :mod:`evaluators.render.sources.fabric_model`.

Footprint: the network takes an isotropic square ``(cx, cy, size)``; the pixel's uv
parallelogram (tile units) becomes the square of the same area around the hit point's uv,
``size = sqrt(|det|)``; the decoder clamps sizes beyond 5 tiles.
"""

from __future__ import annotations

import types
from pathlib import Path
from typing import Any

import numpy as np

from evaluators.render.bsdfs.fabric_footprint import FabricFootprintBSDF
from evaluators.render.plugins import register_vectorised_bsdf

#: The plugin name.
FABRIC_MODEL_BSDF_NAME = "fabric_model"


def register_fabric_model_bsdf(mi: types.ModuleType) -> type:
    """Register ``fabric_model`` for Mitsuba's (vectorised RGB) variant; returns the class."""
    return register_vectorised_bsdf(
        mi, FABRIC_MODEL_BSDF_NAME, FabricModelBSDF, "fabric model BSDF"
    )


class FabricModelBSDF(FabricFootprintBSDF):
    """A ``train.fabric`` network as a footprint BSDF (plugin ``"fabric_model"``).

    ================  ==========  ========  ==============================================
    parameter         type        default   meaning
    ================  ==========  ========  ==============================================
    ``filename``      string      --        ``model.json`` or ``model.pt`` of the model
    ``latent``        TensorXf    --        the material's ``(latent_dim,)`` latent
    ``params``        string      --        the material (JSON of the ``FabricParams``
                                            fields; its albedos give Eq. 8)
    ``tiles_per_uv``  float       16        pattern tiles across the uv range [0, 1]
    ================  ==========  ========  ==============================================
    """

    def __init__(self, props: Any) -> None:
        FabricFootprintBSDF.__init__(self, props)
        from models.fabric.fused import decoder_drjit, load_fabric_model

        mi = self.mi
        model = load_fabric_model(Path(str(props.get("filename"))).read_bytes())
        latent = np.asarray(props.get("latent").numpy(), np.float32).reshape(-1)
        self.decoder = decoder_drjit(model, latent, mi.Float)

    def estimate(self, si: Any, light: Any, active: Any = True) -> Any:
        """The network's ``f_P`` (Eq. 8) at the footprint, ``mi.Color3f``."""
        dr = self.dr
        view, lit, active = self.directions(si, light, active)
        cs, ct, ax, ay, bx, by = self.footprint(si)
        size = dr.sqrt(dr.abs(ax * by - ay * bx))
        comps = self.decoder(cs, ct, size, lit[0], lit[1], lit[2], view[0], view[1])
        return dr.select(active, self.recombine(comps), 0.0)

    def to_string(self) -> str:
        return (
            f"FabricModelBSDF[pattern={self.params.pattern.name}, "
            f"tiles_per_uv={self.tiles_per_uv:g}]"
        )
