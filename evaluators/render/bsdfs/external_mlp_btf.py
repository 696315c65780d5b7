"""Mitsuba BSDF ``external_mlp_btf``: a user's neural BTF (``matforge.mlp-btf/1``) fused into
the render kernel.

``eval`` is :meth:`models.external.fused.FusedMlp.eval` at the shading point's patch
coordinates with the light ``wo`` and the view ``si.wi`` (frame, ``uv_scale`` and cosine
sampling from :mod:`.btf_common`, as the built-in ``btf_model``): the BTF's value already
includes foreshortening (UBO2014, as ``generate.btf``), so it is ``eval`` as it stands. The
latent textures are sampled bilinearly and periodically; the reference is
:meth:`models.external.mlp.MlpMaterial.eval` (numpy).
"""

from __future__ import annotations

import types
from typing import Any

from evaluators.render.bsdfs.btf_common import BtfReflector, uv_scale_of
from evaluators.render.bsdfs.external_mlp import fused_mlp
from evaluators.render.plugins import register_vectorised_bsdf

#: The plugin name.
EXTERNAL_MLP_BTF_NAME = "external_mlp_btf"


def register_external_mlp_btf_bsdf(mi: types.ModuleType) -> type:
    """Register ``external_mlp_btf`` for Mitsuba's (vectorised RGB) variant; returns the
    class."""
    return register_vectorised_bsdf(
        mi, EXTERNAL_MLP_BTF_NAME, ExternalMlpBtfBSDF, "external MLP BTF BSDF"
    )


class ExternalMlpBtfBSDF(BtfReflector):
    """A user's neural BTF (plugin ``"external_mlp_btf"``).

    ==============  ======  =======  ============================================
    parameter       type    default  meaning
    ==============  ======  =======  ============================================
    ``filename``    string  --       a ``matforge.mlp-btf/1`` JSON file
    ``uv_scale_u``  float   1        patch repeats per unit of u
    ``uv_scale_v``  float   1        patch repeats per unit of v
    ==============  ======  =======  ============================================

    Example (XML)::

        <bsdf type="external_mlp_btf"><string name="filename" value="my-btf.json"/></bsdf>
    """

    def __init__(self, props: Any) -> None:
        BtfReflector.__init__(self, props)
        self.fused = fused_mlp(self.mi, props, "external_mlp_btf", "btf")
        self.uv_scale = uv_scale_of(props)

    def btf(self, uv: Any, light: Any, view: Any, active: Any) -> Any:
        return self.fused.eval(light, view, uv)

    def to_string(self) -> str:
        m = self.fused.material
        return f"ExternalMlpBtf[{m.doc.name or m.source}, uv_scale={self.uv_scale}]"
