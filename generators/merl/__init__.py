"""MERL-format BRDF tables: the ``generate.merl`` kind.

Submodules: :mod:`~generators.merl.kind` (params, runner, registration) and
:mod:`~generators.merl.collections` (material families and the named collections).
"""

SUBMODULES: tuple[str, ...] = ("collections", "kind")
