"""Mitsuba BSDF ``btf_model``: a trained BTF model of ``train.btf`` (Xu et al. 2025: the
modified NeuMIP, its teacher, the coarse-to-fine student, or the 4-lobe Lafortune fit)
fused into the render kernel.

``eval`` is :meth:`models.btf.fused.FusedBtf.eval` at the shading point's patch
coordinates, with the local light and view directions (frame, ``uv_scale`` and cosine
sampling from :mod:`.btf_common`): the networks run per lane in Dr.Jit, the neural textures
bilinear and periodic (the student's coarse texture per 2 x 2 block, Lafortune's
parameters from the nearest texel), exactly as in the texture-space pass of Sec. 4.2 at
texel centres. ``FusedBtf`` matches :class:`models.btf.portable.PortableBtf` (numpy) to
float32 precision, so at a texel centre ``eval`` is the model's slice there.
"""

from __future__ import annotations

import json
import types
from pathlib import Path
from typing import Any

from evaluators.render.bsdfs.btf_common import BtfReflector, uv_scale_of
from evaluators.render.plugins import register_vectorised_bsdf

#: The plugin name.
BTF_MODEL_NAME = "btf_model"


def register_btf_model_bsdf(mi: types.ModuleType) -> type:
    """Register ``btf_model`` for Mitsuba's (vectorised RGB) variant; returns the class."""
    return register_vectorised_bsdf(mi, BTF_MODEL_NAME, BtfModelBSDF, "BTF model BSDF")


def load_fused(mi: types.ModuleType, model_path: str, textures_path: str) -> Any:
    """The :class:`~models.btf.fused.FusedBtf` of a ``model.json`` and ``textures.npz``;
    ``ValueError`` naming the file when either is malformed."""
    from models.btf.fused import FusedBtf
    from models.btf.portable import read_model, read_textures

    try:
        doc = json.loads(Path(model_path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"model.json: not readable JSON: {exc}") from None
    try:
        textures = read_textures(Path(textures_path).read_bytes())
    except Exception as exc:  # numpy raises several types for a corrupt archive
        raise ValueError(f"textures.npz: not a readable .npz: {exc}") from None
    return FusedBtf(read_model(doc, textures), mi)


class BtfModelBSDF(BtfReflector):
    """A trained BTF model (plugin ``"btf_model"``).

    ==============  ======  =======  ================================================
    parameter       type    default  meaning
    ==============  ======  =======  ================================================
    ``model``       string  --       a ``model.json`` (``matforge.btf-model/1``)
    ``textures``    string  --       its ``textures.npz``
    ``uv_scale_u``  float   1        patch repeats per unit of u
    ``uv_scale_v``  float   1        patch repeats per unit of v
    ==============  ======  =======  ================================================

    Example (XML)::

        <bsdf type="btf_model"><string name="model" value="model.json"/>
            <string name="textures" value="textures.npz"/></bsdf>
    """

    def __init__(self, props: Any) -> None:
        BtfReflector.__init__(self, props)
        mi = self.mi
        if "model" not in props or "textures" not in props:
            raise ValueError("btf_model: 'model' and 'textures' are required")
        self.fused = load_fused(mi, str(props["model"]), str(props["textures"]))
        self.uv_scale = uv_scale_of(props)

    def btf(self, uv: Any, light: Any, view: Any, active: Any) -> Any:
        return self.fused.eval(uv, light, view)

    def to_string(self) -> str:
        h, w = self.fused.h, self.fused.w
        return f"BtfModel[{self.fused.model.model}, {h}x{w}, uv_scale={self.uv_scale}]"
