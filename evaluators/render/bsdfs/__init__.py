"""Our Mitsuba 3 BSDF plugins, one per module; shared machinery in :mod:`.common`,
:mod:`.fabric_footprint` and :mod:`.btf_common`.

=====================  ======================  =============================================
plugin                 module                  what it renders
=====================  ======================  =============================================
``merl_table``         ``merl_table``          a MERL table, interpolated, GGX/cosine MIS
``brdf_model``         ``brdf_model``          one material of a trained BRDF model (fused)
``fabric_aggregate``   ``fabric_aggregate``    the woven-fabric aggregate over the pixel
                                               footprint, one Monte Carlo sample per call
``fabric_model``       ``fabric_model``        a trained fabric network over the footprint
``glint``              ``glint``               glinty microstructure over the footprint
                                               (tiny examples or the Yan et al. reference)
``btf_table``          ``btf_table``           a BTF job's slices, bilinear in space and
                                               barycentric between measured directions
``btf_model``          ``btf_model``           a trained BTF model (train.btf), fused
``btf_surface``        ``btf_surface``         a generate.btf surface's principled BSDF,
                                               carrying its relief for the floor scenes
``external_mlp``       ``external_mlp``        a user's BRDF network (matforge.mlp-brdf/1)
``external_mlp_btf``   ``external_mlp_btf``    a user's neural BTF (matforge.mlp-btf/1)
``external_onnx``      ``external_onnx``       a user's ONNX BRDF or BTF (onnxruntime, in
                                               Dr.Jit's evaluated mode)
=====================  ======================  =============================================

Each registers itself per Mitsuba variant through :mod:`evaluators.render.plugins` when its
``register_*`` function is first called (the material sources do), not on import.
"""

from __future__ import annotations

from evaluators.render.bsdfs import (
    brdf_model,
    btf_model,
    btf_surface,
    btf_table,
    external_mlp,
    external_mlp_btf,
    external_onnx,
    fabric_aggregate,
    fabric_model,
    glint,
    merl_table,
)

#: The plugin modules, in table order.
PLUGINS = (
    merl_table,
    brdf_model,
    fabric_aggregate,
    fabric_model,
    glint,
    btf_table,
    btf_model,
    btf_surface,
    external_mlp,
    external_mlp_btf,
    external_onnx,
)
