"""Rendering BTF slices with Mitsuba 3 (Xu et al., Sec. 3.1; UBO2014's convention).

Submodules (imported explicitly by their users):

- :mod:`~evaluators.render.btf.patch`: the surface a slice sees: a flat plane carrying any
  Mitsuba BSDF, or a procedural patch as a displaced, 3 x 3 tiled triangle mesh with
  principled-BSDF albedo and roughness textures;
- :mod:`~evaluators.render.btf.slices`: one slice per (light, view) pair, path-traced with
  Mitsuba's own ``path`` integrator under a ``directional`` emitter, with its Monte Carlo
  standard error.
"""

SUBMODULES: tuple[str, ...] = ("patch", "slices")
