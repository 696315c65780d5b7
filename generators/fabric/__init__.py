"""Woven-fabric training data (Chen et al. 2024, Sec. 5.1): the ``generate.fabric`` kind.

Submodules: :mod:`~generators.fabric.kind` (runner and registration),
:mod:`~generators.fabric.params` (params, presets, the plan), :mod:`~generators.fabric.queries`
(the stratified query design) and :mod:`~generators.fabric.preview` (maps and pictures).
"""

SUBMODULES: tuple[str, ...] = ("queries", "params", "preview", "rows", "kind")
