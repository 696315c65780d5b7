"""The ``render`` kind and everything it renders with (Mitsuba 3, LLVM variant).

Submodules:

- :mod:`~evaluators.render.kind`: the ``render`` job kind;
- :mod:`~evaluators.render.scenes`: the built-in scenes and the generated studio envmap;
- :mod:`~evaluators.render.meshes`: triangle meshes from numpy arrays;
- :mod:`~evaluators.render.btf`: BTF patches and slices (``generate.btf``), relief floors;
- :mod:`~evaluators.render.sources`: material sources, from a ``material`` param to a BSDF;
- :mod:`~evaluators.render.bsdfs`: our BSDF plugins, one per module;
- :mod:`~evaluators.render.integrators`: our path integrators, one shared loop;
- :mod:`~evaluators.render.plugins`: per-variant plugin registration.

Mitsuba itself is loaded by :func:`materials.backend.load_mitsuba`.
"""

SUBMODULES: tuple[str, ...] = (
    "plugins", "scenes", "meshes", "btf", "bsdfs", "integrators", "sources", "kind",
)  # fmt: skip
