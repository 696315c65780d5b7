"""What a job kind is written against: the small API between the kinds and the service.

Submodules (imported explicitly by their users):

- :mod:`jobapi.kinds`: :class:`~jobapi.kinds.Kind` and :func:`~jobapi.kinds.register`;
- :mod:`jobapi.context`: :class:`~jobapi.context.JobContext`, what a runner receives (seed,
  progress, cancellation, inputs, shards, artifacts);
- :mod:`jobapi.params`: :class:`~jobapi.params.StrictModel`, the base of every params model,
  and the reference types ``Ref`` (an artifact) and ``JobRef`` (a whole job);
- :mod:`jobapi.presets`: named presets with per-field overrides;
- :mod:`jobapi.results`: :class:`~jobapi.results.ResultTable`, what a summary hook returns;
- :mod:`jobapi.reports`: :class:`~jobapi.reports.ReportFacts`, what a training kind tells the
  report kinds (headline metric, loss key, failure cases, model checks, claims);
- :mod:`jobapi.errors`: ``SpecError``, ``JobFailed``, ``JobCancelled`` and the storage errors;
- :mod:`jobapi.executor`: the executor interface behind ``ctx.map_shards``;
- :mod:`jobapi.version`: ``__version__``, the one version of matforge.

``jobapi`` imports nothing of ours but :mod:`storage`; the kinds import ``jobapi`` and never
``service`` (import contracts in ``pyproject.toml`` keep both true).
"""

SUBMODULES: tuple[str, ...] = (
    "errors",
    "params",
    "presets",
    "results",
    "reports",
    "executor",
    "kinds",
    "context",
    "version",
)
