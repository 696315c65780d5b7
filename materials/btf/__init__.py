"""Bidirectional texture functions (Xu et al., "Real-Time Neural Materials on Mobile VR"):
pure numpy pieces.

Submodules (imported explicitly by their users):

- :mod:`~materials.btf.directions`: the BTF convention, direction sets (``small``, the
  UBO2014 count) and conversions between angles and unit vectors;
- :mod:`~materials.btf.surfaces`: seeded procedural surfaces (height, albedo and roughness
  maps) in the spirit of UBO2014's classes: leather, fabric, wood, stone;
- :mod:`~materials.btf.lafortune`: the 4-lobe Lafortune baseline (Eq. 6-7): the model,
  its 55-float layout and the fit's starting point (the fit is
  :mod:`models.btf.lafortune`);
- :mod:`~materials.btf.angular`: interpolation between a BTF's measured directions
  (barycentric over a triangulation of the hemisphere; numpy set-up, Dr.Jit evaluation).
"""

SUBMODULES: tuple[str, ...] = ("directions", "surfaces", "lafortune", "angular")
