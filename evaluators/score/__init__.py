"""The ``score`` kind: candidates against a reference, per artifact kind.

Submodules: :mod:`~evaluators.score.kind` (the kind), :mod:`~evaluators.score.params` (its
params), :mod:`~evaluators.score.artifacts` (the artifact-kind registry and loading),
:mod:`~evaluators.score.images` (EXR and PNG), :mod:`~evaluators.score.brdf` (MERL tables
and trained BRDF models) and :mod:`~evaluators.score.sets` (whole models against sets of
tables).
"""

SUBMODULES: tuple[str, ...] = ("params", "artifacts", "images", "brdf", "sets", "kind")
