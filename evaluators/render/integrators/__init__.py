"""Our Python path integrators: one shared loop (:mod:`.common`) and small hooks on it.

=================  =========================================================================
plugin             what it changes in Mitsuba's ``path``
=================  =========================================================================
``neural_depth``   evaluates a ``brdf_model`` BSDF's network only up to a path depth
                   (:mod:`.neural_depth`; De Oliveira et al., Sec. 5.3)
``fabric_path``    hands each pixel's footprint to the fabric BSDFs (:mod:`.fabric_path`;
                   Chen et al. 2024, Sec. 6)
=================  =========================================================================

:func:`integrator_for` picks the one a material needs.
"""

from __future__ import annotations

import types
from typing import Any

from evaluators.render.integrators import fabric_path, neural_depth

#: The specialised integrators, each with ``wants(bsdf)`` and ``integrator_dict(...)``.
SPECIALISED = (neural_depth, fabric_path)


def integrator_for(mi: types.ModuleType, bsdf: Any, integrator: dict[str, Any]) -> dict[str, Any]:
    """The integrator dict to render ``bsdf`` with, given the scene's default ``integrator``
    (a ``{"type": "path", "max_depth": n}`` dict, returned unchanged when ``bsdf`` needs
    nothing special).

    A material that needs two specialised integrators at once is refused with a
    ``ValueError`` naming both, rather than silently losing one's feature.
    """
    wanted = [m for m in SPECIALISED if m.wants(bsdf)]
    if len(wanted) > 1:
        names = " and ".join(m.__name__.rsplit(".", 1)[-1] for m in wanted)
        raise ValueError(f"the material needs both the {names} integrators; none does both")
    return wanted[0].integrator_dict(mi, bsdf, integrator) if wanted else integrator
