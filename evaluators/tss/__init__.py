"""The ``evaluate.tss`` kind: texture-space shading with temporal reuse (Xu et al. 2025,
Sec. 4.2), scored against screen-space shading and timed.

Submodules: :mod:`~evaluators.tss.params` (its params), :mod:`~evaluators.tss.path` (the
seeded head motion), :mod:`~evaluators.tss.passes` (the Dr.Jit shading, lookup and
screen-space passes), :mod:`~evaluators.tss.simulate` (frames, scores, timings),
:mod:`~evaluators.tss.figures` (``table.png``, ``frames.png``) and
:mod:`~evaluators.tss.kind` (the kind).
"""

SUBMODULES: tuple[str, ...] = ("params", "path", "passes", "simulate", "figures", "kind")
