"""Material sources: from a ``material`` param to a Mitsuba BSDF.

The registry and the ``material`` params type are in :mod:`.common`; each other module
registers one source when it is imported. The list below is the one place that decides
which sources exist:

================  =============================================================  ============
key               value                                                           module
================  =============================================================  ============
``mitsuba``       a Mitsuba 3 BSDF plugin dict                                    ``mitsuba``
``merl``          a MERL ``.binary`` table ref                                    ``merl``
``model``         a trained ``train.brdf`` model's material (or, with ``fabric``,  ``model``
                  a ``train.fabric`` network)
``fabric``        the woven-fabric aggregate (Monte Carlo over the footprint)     ``fabric``
``glint``         glinty microstructure of a ``generate.glint`` job               ``glint``
``btf``           a BTF job's slices as a table (6D interpolation); also the      ``btf``
                  ``uv_scale`` sibling and the BTF branch of ``model``
                  (``{"model": "job:<train.btf id>"}``)
``btf_surface``   the surface a ``generate.btf`` job path-traced (relief mesh     ``btf_surface``
                  on the floor scenes, or its flat BSDF)
``external``      a user's own BRDF or BTF model file: the MLP formats            ``external``
                  (fused Dr.Jit) or ONNX (onnxruntime)
================  =============================================================  ============
"""

from __future__ import annotations

from evaluators.render.sources import (
    btf,
    btf_surface,
    external,
    fabric,
    fabric_model,
    glint,
    merl,
    mitsuba,
    model,
)
from evaluators.render.sources.common import (
    MaterialParam,
    load_bsdf,
    material_sources,
    register_material_source,
    resolve_material,
)

#: The modules that register the built-in sources, in table order.
BUILTIN = (mitsuba, merl, model, fabric, fabric_model, glint, btf, btf_surface, external)

__all__ = [
    "BUILTIN",
    "MaterialParam",
    "load_bsdf",
    "material_sources",
    "register_material_source",
    "resolve_material",
]
