"""Woven-fabric model of Chen, Wang & Wang 2024 (after Jin et al. 2022 and Zhu et al. 2023).

Submodules, imported explicitly (DESIGN.md):

- ``patterns``: weave patterns as data, the built-in registry and user-pattern validation;
- ``params``: :class:`FabricParams`, one material, and the documented sampling ranges;
- ``array_ops``: the numpy / Dr.Jit operations the shared physics is written over;
- ``yarn``: the yarn geometry (n_p, t_p, height, yarn id) and tile rasterisation;
- ``shading``: the point BSDF of Eq. 1-2 (SpongeCake fibre microflakes, blended Lambertian,
  slab transmission);
- ``integrand``: the per-sample terms of the aggregate of Eq. 3-5 with yarn visibility;
- ``samplers``: independent and scrambled Sobol sample points;
- ``aggregate``: the estimator of the four components of Eq. 7-8 with standard errors.

``aggregate_drjit`` (the Dr.Jit LLVM twin of the estimator) is imported on demand only,
because it starts Dr.Jit. The Mitsuba plugins that render this model live in
:mod:`evaluators.render.bsdfs` (``fabric_footprint``, ``fabric_aggregate``,
``fabric_model``).
"""

from materials.fabric import (
    aggregate,
    array_ops,
    integrand,
    params,
    patterns,
    samplers,
    shading,
    yarn,
)

__all__ = [
    "aggregate",
    "array_ops",
    "integrand",
    "params",
    "patterns",
    "samplers",
    "shading",
    "yarn",
]
