"""BRDF models of the hybrid-BRDF paper (De Oliveira et al.): the ``train.brdf`` job kind.

Submodules (imported explicitly by their users, not here, so that registering the kind does
not import torch):

- :mod:`models.brdf.networks`: torch modules (hybrid, neural, analytic) and constraints;
- :mod:`models.brdf.losses`: Eq. 4-5;
- :mod:`models.brdf.data`: tables, cosine-weighted pair batches, family splits;
- :mod:`models.brdf.train`: AdamW + cosine decay + clipping, divergence guard, determinism;
- :mod:`models.brdf.portable`: the ``model.json`` format and its numpy evaluator;
- :mod:`models.brdf.report`: ``metrics.json`` and ``curves.png``;
- :mod:`models.brdf.kind`: the params model and registration; :mod:`models.brdf.runner`:
  the runner's body;
- :mod:`models.brdf.report_kind`: the ``report.brdf`` kind over finished runs, with
  :mod:`models.brdf.study` (its numbers) and :mod:`models.brdf.report_plots` (its pictures).
"""

SUBMODULES: tuple[str, ...] = (
    "networks",
    "losses",
    "data",
    "train",
    "portable",
    "report",
    "kind",
    "runner",
    "study",
    "report_plots",
    "report_kind",
)
