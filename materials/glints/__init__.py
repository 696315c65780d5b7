"""Glinty microstructure (Xing et al. 2024, after Yan et al. 2016): pure numpy physics.

Submodules (imported explicitly by their users):

- :mod:`~materials.glints.examples`: the conventions, the six seeded procedural tiny
  examples (user normal maps are read by :mod:`storage.formats.normal_map`);
- :mod:`~materials.glints.lobes`: the 4D Gaussian lobes of a normal map and the closed forms
  (the lobes' normal marginals, Eq. 1 against a Gaussian footprint);
- :mod:`~materials.glints.ndf_maps`: the multi-scale NDF maps of Eq. 2;
- :mod:`~materials.glints.surface`: transforms and distributions of examples, and the export
  of the procedural microstructure as an explicit normal map;
- :mod:`~materials.glints.footprint`: Heckbert footprints, the tiny-example LOD descent and
  the Yan et al. reference.
"""

SUBMODULES: tuple[str, ...] = ("examples", "lobes", "ndf_maps", "surface", "footprint")
