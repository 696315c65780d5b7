"""``generate.btf`` and ``import.btf``: BTF slices (Xu et al., Sec. 3.1) in one shard layout
(:mod:`storage.formats.btf`).

Submodules:

- :mod:`~generators.btf.params`: both kinds' parameters and presets;
- :mod:`~generators.btf.preview`: ``preview.png`` (a grid of slices and a texel's apparent
  BRDF, unfolded as in the paper's Fig. 9);
- :mod:`~generators.btf.kind`: ``generate.btf``, slices path-traced with Mitsuba 3;
- :mod:`~generators.btf.importer`: ``import.btf``, a folder of measured slice images.
"""

SUBMODULES: tuple[str, ...] = ("params", "preview", "kind", "importer")
