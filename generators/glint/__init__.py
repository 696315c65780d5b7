"""Tiny-example glint data (Xing et al. 2024): the ``generate.glint`` kind.

Submodules: :mod:`~generators.glint.params` (params, presets, the surface spec),
:mod:`~generators.glint.preview` (the labelled preview) and :mod:`~generators.glint.kind`
(runner and registration).
"""

SUBMODULES: tuple[str, ...] = ("params", "preview", "rows", "kind")
