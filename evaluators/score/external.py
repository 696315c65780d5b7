"""``score`` of a user's model: ``{"external": {"model": REF, "kind": "brdf" | "btf"}}``.

- **BRDF** (``kind: brdf``) against a MERL table (reference ``job:<id>/<name>.binary`` or a
  ``sha256:`` table): the artifact kind ``external-brdf``, a candidate of ``merl``
  references. The model is evaluated (:meth:`ExternalModel.eval`, float32 in, compared in
  float64) at exactly the pairs and with exactly the rules of a ``brdf-model`` candidate
  (:mod:`evaluators.score.brdf`: 10^6 fixed-seed cosine-weighted pairs, pairs without table
  data excluded, ``smape`` Eq. 6 with eps 0, ``mae``), beside built-in models and tables in
  the same job.
- **BTF** (``kind: btf``), and built-in ``train.btf`` models beside it
  (``{"model": "job:<train.btf id>/model.json"}``, evaluated by their portable evaluator),
  against the slices of a BTF job (reference ``job:<generate.btf
  id>``): every slice evaluated at the texel centres ``uv = ((i + 1/2) / W, (j + 1/2) / H)``
  (times ``uv_scale``) with the slice's light ``wi`` and view ``wo``, and the L1 that
  ``train.btf`` reports (:func:`models.btf.cases.predicted_slice_l1`, one implementation):
  ``l1`` over every slice, texel and channel, ``relative_l1`` over the mean ``|BTF|``, and
  both per failure case (:func:`models.btf.cases.case_errors`) under ``cases``.

Cost: every external candidate is timed by :func:`models.external.cost.measure_cost` (the
fixed batch of ``train.brdf``'s ``speed.json``, in the model's own runtime), a built-in
BTF by :func:`models.external.cost.measure_builtin_btf` (its fused kernel on the same
batch), and recorded in the job's manifest as the measurement ``cost`` (``timings.measured.cost``:
``{"format", "candidates": {label: {ns_per_eval, runtime, bytes_per_network, method,
batch, repeats}}}``): timings vary between runs, so they are no artifact (the artifacts
stay byte-identical for the same spec); the result rows read them from there.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from evaluators.render.sources.btf import uv_scale_pair
from evaluators.score.artifacts import ArtifactKind, Loaded, register_artifact_kind
from evaluators.score.brdf import score_brdfs
from evaluators.score.params import ExternalCandidate, ModelCandidate, ScoreParams
from jobapi.errors import JobFailed
from storage.errors import FormatError

if TYPE_CHECKING:
    from evaluators.render.sources.external import ExternalSpec
    from jobapi.context import JobContext
    from models.external import ExternalModel

#: Metrics of a BTF score, in the order listed.
BTF_METRICS: tuple[str, ...] = ("l1", "relative_l1")
#: The artifact kind of an external BRDF candidate.
EXTERNAL_BRDF = "external-brdf"


def open_external(path: Path, name: str, kind: str, runtime: str | None = None) -> ExternalModel:
    """The model in ``path`` (:func:`models.external.load_external`: an MLP weight file or
    an ONNX file, by content); ``FormatError`` naming ``name`` and what is wrong."""
    from models.external import load_external

    try:
        model = load_external(path, kind, label=name, runtime=runtime)
    except FormatError as exc:  # named after the store's object file: name the ref
        raise FormatError(name, exc.problem) from None
    except ValueError as exc:
        raise FormatError(name, str(exc).removeprefix(f"{path.name}: ")) from None
    if model.kind != kind:
        raise FormatError(name, f"the file holds a {model.kind} model, not a {kind}")
    return model


def load_candidate(label: str, value: ExternalSpec, ctx: JobContext) -> ExternalModel:
    """Open candidate ``label``'s model; ``JobFailed`` naming the candidate."""
    try:
        return open_external(ctx.resolve(value.model), value.model, value.kind, value.runtime)
    except FormatError as exc:
        raise JobFailed(f"candidate {label!r}: {exc}") from None


@dataclass(frozen=True, eq=False)
class ExternalSampler:
    """An external BRDF as a :class:`evaluators.metrics.brdf.BrdfSampler`."""

    ref: str
    model: Any

    def eval(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """``(N, 3)`` float64 BRDF values at ``(N, 3)`` pairs (evaluated in float32)."""
        out = self.model.eval(np.asarray(wi, np.float32), np.asarray(wo, np.float32))
        out = np.asarray(out, np.float64)
        if out.shape != (len(wi), 3):
            raise ValueError(f"{self.ref}: the model returned {out.shape} for {len(wi)} pairs")
        if not np.all(np.isfinite(out)):
            raise ValueError(f"{self.ref}: the model returned non-finite values")
        return out


def external_brdf_input(label: str, spec: ExternalCandidate, ctx: JobContext) -> Loaded:
    """The :class:`Loaded` of an external BRDF candidate."""
    if spec.external.kind != "brdf":
        raise JobFailed(f"candidate {label!r}: a {spec.external.kind} model is not a BRDF")
    model = load_candidate(label, spec.external, ctx)
    return Loaded(
        ref=spec.external.model,
        kind=EXTERNAL_BRDF,
        data=ExternalSampler(spec.external.model, model),
    )


def external_costs(
    models: dict[str, Any], ctx: JobContext, builtins: dict[str, Any] | None = None
) -> dict[str, Any]:
    """The ``cost`` document of the external candidates ``{label: model}`` and of the
    built-in ``train.btf`` ones (``builtins``, each a
    :class:`models.btf.portable.PortableBtf`, timed the same way; see the module)."""
    from jobapi.documents import check_typed
    from models.external.cost import COST_FORMAT, CostDocument, measure_builtin_btf, measure_cost

    timers: list[tuple[str, Callable[[Any], dict[str, Any]], Any]] = [
        *((label, measure_cost, m) for label, m in sorted(models.items())),
        *((label, measure_builtin_btf, m) for label, m in sorted((builtins or {}).items())),
    ]
    out: dict[str, Any] = {}
    for label, measure, model in timers:
        ctx.check_cancelled()
        try:
            out[label] = measure(model)
        except ValueError as exc:
            raise JobFailed(f"candidate {label!r}: cost: {exc}") from None
    doc = {"format": COST_FORMAT, "candidates": out}
    check_typed("cost", doc, CostDocument)  # a malformed record is a bug: it fails the job
    return doc


def external_settings(params: ScoreParams) -> dict[str, Any]:
    """``settings.candidate_external``: each external candidate's value."""
    return {
        label: c.external.model_dump(mode="json", exclude_none=True)
        for label, c in sorted(params.candidates.items())
        if isinstance(c, ExternalCandidate)
    }


# -- BTF slices --------------------------------------------------------------------------


def texel_uv(h: int, w: int, scale: tuple[float, float]) -> np.ndarray:
    """``(H W, 2)`` float32 texel centres ``((i + 1/2) / W s_u, (j + 1/2) / H s_v)``, row
    ``j`` major (the slices' ``[row, column]`` layout)."""
    jj, ii = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    uv = np.stack([(ii.ravel() + 0.5) / w * scale[0], (jj.ravel() + 0.5) / h * scale[1]], axis=1)
    return uv.astype(np.float32)


def score_btf_slices(params: ScoreParams, ctx: JobContext) -> None:
    """Score every external BTF candidate on every slice of the reference BTF job; store
    ``metrics.json`` (and the measurement ``cost`` in the manifest)."""
    from models.btf.cases import case_errors, predicted_slice_l1, slice_mean_abs
    from models.btf.data import BtfDataset

    wanted = list(params.metrics or BTF_METRICS)
    bad = [m for m in wanted if m not in BTF_METRICS]
    if bad:
        raise JobFailed(
            f"metrics: {', '.join(map(repr, bad))} do not apply to BTF slices; use "
            f"{', '.join(BTF_METRICS)}"
        )
    if params.exposure is not None:
        raise JobFailed("exposure: applies to HDR-FLIP only, not to BTF slices")
    assert isinstance(params.reference, str)
    data = BtfDataset.open(params.reference, ctx, "reference")
    h, w = data.resolution
    scale = slice_mean_abs(data)
    mean_abs = float(np.mean(scale))
    models: dict[str, Any] = {}
    metrics: dict[str, dict[str, float | None]] = {}
    cases: dict[str, list[dict[str, Any]]] = {}
    candidates = sorted(params.candidates.items())
    builtins: dict[str, Any] = {}
    for k, (label, cand) in enumerate(candidates):
        if isinstance(cand, ModelCandidate):
            builtin = load_builtin_btf(label, cand.model, ctx)
            builtins[label] = builtin
            predict: Any = builtin.slice
        else:
            assert isinstance(cand, ExternalCandidate)
            model = load_candidate(label, cand.external, ctx)
            models[label] = model
            uv = texel_uv(h, w, uv_scale_pair(cand.external.model_dump()))

            def predict(
                wi: np.ndarray, wo: np.ndarray, model: Any = model, uv: np.ndarray = uv
            ) -> np.ndarray:
                n = len(uv)
                out = model.eval(np.tile(wi, (n, 1)), np.tile(wo, (n, 1)), uv)
                return np.asarray(out).reshape(h, w, 3)

        try:
            per_slice = predicted_slice_l1(predict, data, np.arange(len(data)))
        except ValueError as exc:
            raise JobFailed(f"candidate {label!r}: {exc}") from None
        l1 = float(np.mean(per_slice))
        row = {"l1": l1, "relative_l1": l1 / max(mean_abs, 1e-12)}
        metrics[label] = {m: row[m] for m in wanted}
        cases[label] = case_errors(data.wi, data.wo, per_slice, scale)
        ctx.progress(0.1 + 0.7 * (k + 1) / len(candidates), f"scored {label}")
    settings = {
        "artifact_kind": "btf-slices",
        "slices": len(data),
        "resolution": [h, w],
        "mean_abs_btf": mean_abs,
        "uv": "texel centres ((i + 0.5) / W, (j + 0.5) / H) x uv_scale",
        "l1": "mean absolute error over every slice, texel and channel, in BTF units (1/sr), "
        "as train.btf's l1 (models.btf.cases.predicted_slice_l1)",
        "relative_l1": "l1 / the BTF's mean |value|",
        "cases": "the same per failure case (models.btf.cases)",
        "candidate_external": external_settings(params),
    }
    ctx.put_json(
        "metrics.json",
        {"reference": params.reference, "metrics": metrics, "cases": cases, "settings": settings},
    )
    ctx.progress(0.85, "timing the models")
    ctx.measure("cost", external_costs(models, ctx, builtins))
    ctx.progress(1.0, f"scored {len(models)} BTF model(s) on {len(data)} slices")


def load_builtin_btf(label: str, ref: str, ctx: JobContext) -> Any:
    """The :class:`models.btf.portable.PortableBtf` of a ``train.btf`` job's
    ``job:<id>/model.json`` (its ``textures.npz`` beside it)."""
    from jobapi.params import JOB_REF
    from models.btf.portable import read_model, read_textures

    m = JOB_REF.match(ref)
    if m is None or not ref.endswith("/model.json"):
        raise JobFailed(f"candidate {label!r}: a train.btf model is 'job:<id>/model.json'")
    job = ctx.input_job(m["job"], f"candidates.{label}.model", "train.btf")
    try:
        doc = json.loads(ctx.read_ref(f"job:{job.id}/model.json"))
        return read_model(doc, read_textures(ctx.read_ref(f"job:{job.id}/textures.npz")))
    except (ValueError, OSError) as exc:
        raise JobFailed(f"candidate {label!r}: {ref}: {exc}") from None


def _never_loaded(path: Path, name: str) -> Any:
    # A candidate only (no media type, extension, magic or detect: never identified).
    raise FormatError(name, "an external model is given as {'external': {...}}, not as a ref")


register_artifact_kind(
    ArtifactKind(
        name=EXTERNAL_BRDF,
        description="a user's BRDF model ({'external': {'model': REF, 'kind': 'brdf'}})",
        media_types=(),
        extensions=(),
        magic=b"",
        load=_never_loaded,
        scorer=score_brdfs,
        metrics=("smape", "mae"),
        space="brdf",
    )
)
