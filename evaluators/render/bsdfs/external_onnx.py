"""Mitsuba BSDF ``external_onnx``: a user's ONNX BRDF or BTF evaluated inside the render.

A graph that is an MLP (:func:`models.external.onnx_mlp.compile_onnx` recognises it) is
traced into the render kernel like ``external_mlp``: the same fused Dr.Jit dense layers as
the built-in models, inside Mitsuba's symbolic path loop (:class:`OnnxFusedBrdf`,
:class:`OnnxFusedBtf`; runtime ``drjit-fused``). Any other graph
(:class:`models.external.onnx_model.OnnxMaterial`, signature in ``docs/onnx-models.md``)
runs in onnxruntime, outside Dr.Jit, so it cannot be traced into a kernel: Dr.Jit's
symbolic loops and calls cannot call out to Python. Renders with such a BSDF therefore run
in Dr.Jit's **evaluated (wavefront) mode** (:func:`wavefront_scope`:
``JitFlag.SymbolicLoops``, ``SymbolicCalls`` and ``SymbolicConditionals`` off for the
render, restored afterwards). Mitsuba's path loop then runs one iteration (one bounce) at a
time over all live paths, and each BSDF call receives concrete arrays of the lanes that hit
this material: ``eval`` reads them back (``.numpy()``), runs onnxruntime once on the active
lanes, and hands the result back as a Dr.Jit array. That is "once per bounce over all live
paths" (two calls per bounce: the emitter sample's ``eval`` and the BSDF sample's).

:func:`wavefront_scope` turns the flags off while any ``external_onnx`` BSDF is alive,
because Mitsuba traces **every** live BSDF instance into a render's call table, whether the
scene uses it or not. Traced symbolically anyway (a caller rendering without the scope), the
BSDF cannot call out and returns 0, and counts that in ``symbolic_calls``.

Evaluation
    ``brdf``: ``f(wi = si.wi, wo)`` (``si.wi`` toward the previous vertex, the camera side;
    ``wo`` toward the next: Mitsuba's order), times ``cos theta_wo``. ``btf``: the BTF at
    ``(uv * uv_scale, wi = light = wo, wo = view = si.wi)`` as it is (foreshortening
    included; frame and mirroring as :mod:`.btf_common`).
Sampling
    Cosine-weighted hemisphere sampling (``pdf = cos / pi``) by default for both kinds: the
    signature gives no lobe to sample, and cosine needs no model evaluation. A glossy model
    converges more slowly than with the GGX mixture of the built-in models, but without
    bias. A BRDF may name a GGX lobe to sample (``alpha``, ``specular_weight``: the material's
    ``sampling``): the mixture of :class:`.common.MixtureSampling`, the built-in models' MIS.
Frame and sides
    Local shading frame, z up, one-sided: 0 (value and pdf) below either horizon.

====================  ======  =======  ===============================================
parameter             type    default  meaning
====================  ======  =======  ===============================================
``filename``          string  --       the ``.onnx`` file
``kind``              string  --       ``brdf`` or ``btf`` (the signature it must follow)
``label``             string  file     the model's name in messages (the user's ref)
``threads``           int     2        onnxruntime intra-op threads
``runtime``           string  auto     ``auto`` (fused when recognised), ``onnxruntime``
``alpha``             float   1        (BRDF) GGX roughness of the sampled lobe
``specular_weight``   float   0        (BRDF) probability of sampling the GGX lobe
``uv_scale_u``        float   1        (BTF) patch repeats per unit of u
``uv_scale_v``        float   1        (BTF) patch repeats per unit of v
====================  ======  =======  ===============================================
"""

from __future__ import annotations

import contextlib
import logging
import types
import weakref
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from evaluators.render.bsdfs.btf_common import BtfReflector, uv_scale_of
from evaluators.render.bsdfs.common import GlossyDiffuseReflector, MixtureReflector, MixtureSampling
from evaluators.render.plugins import VariantPlugin, class_for_variant, register_vectorised_bsdf
from jobapi.errors import JobFailed
from models.external.onnx_mlp import OnnxMlpMaterial, open_onnx
from models.external.onnx_model import DEFAULT_THREADS, OnnxEvalError, OnnxMaterial
from storage.errors import FormatError, TooLargeError
from storage.formats.onnx import check_onnx_file

if TYPE_CHECKING:
    from jobapi.context import JobContext

log = logging.getLogger("matforge.render.onnx")

#: The plugin name.
EXTERNAL_ONNX_NAME = "external_onnx"
#: The live ``external_onnx`` BSDFs (see :func:`wavefront_scope`).
_LIVE: weakref.WeakSet[Any] = weakref.WeakSet()


def register_external_onnx_bsdf(mi: types.ModuleType) -> type:
    """Register ``external_onnx`` for Mitsuba's (vectorised RGB) variant; returns the class."""
    return register_vectorised_bsdf(mi, EXTERNAL_ONNX_NAME, ExternalOnnx, "ONNX model BSDF")


def external_onnx_plugin(
    path: Path, value: dict[str, Any], ctx: JobContext | None, mi: types.ModuleType
) -> dict[str, Any]:
    """The Mitsuba BSDF dict of an ONNX model at ``path`` (``value``: the material's keys,
    ``kind`` required, ``uv_scale`` (a float or ``[u, v]``) and ``threads`` optional).

    The file is checked here against ``kind``'s signature (and all the upload checks): a
    wrong one raises ``ValueError`` naming the model (``value["model"]``, else the file)
    and the problem, which the material source turns into a ``JobFailed`` at job start.
    """
    register_external_onnx_bsdf(mi)
    kind = str(value.get("kind", ""))
    if kind not in ("brdf", "btf"):
        raise ValueError(f"kind must be 'brdf' or 'btf', not {kind!r}")
    label = str(value.get("model") or Path(path).name)
    try:
        check_onnx_file(Path(path), label, kind)
    except (FormatError, TooLargeError) as exc:
        raise ValueError(str(exc)) from None
    out: dict[str, Any] = {
        "type": EXTERNAL_ONNX_NAME,
        "filename": str(path),
        "kind": kind,
        "label": label,
    }
    if "threads" in value:
        out["threads"] = int(value["threads"])
    if value.get("runtime") is not None:  # "auto" (default) or "onnxruntime"
        out["runtime"] = str(value["runtime"])
    sampling = value.get("sampling")
    if sampling is not None:
        if kind != "brdf":
            raise ValueError("sampling applies to a BRDF model only")
        out["alpha"] = float(sampling["alpha"])
        out["specular_weight"] = float(sampling["specular_weight"])
    scale = value.get("uv_scale")
    if scale is not None:
        if kind != "btf":
            raise ValueError("uv_scale applies to a BTF model only")
        su, sv = (scale, scale) if isinstance(scale, int | float) else scale
        out["uv_scale_u"], out["uv_scale_v"] = float(su), float(sv)
    return out


def onnx_bsdfs_alive() -> bool:
    """Whether any ``external_onnx`` BSDF exists (then renders must be evaluated)."""
    return len(_LIVE) > 0


@contextlib.contextmanager
def wavefront_scope(force: bool = False) -> Iterator[bool]:
    """Dr.Jit's evaluated mode (symbolic loops, calls and conditionals off) while an
    ``external_onnx`` BSDF is alive (or ``force``); yields whether it is on. The flags are
    restored on exit, so renders without ONNX materials keep their fused kernels. A model
    that fails inside the render (:class:`OnnxEvalError`, which Dr.Jit wraps in its own
    ``RuntimeError``) leaves the scope as a :class:`JobFailed` with the model's message."""
    import drjit as dr

    if not (force or onnx_bsdfs_alive()):
        yield False
        return
    with contextlib.ExitStack() as stack:
        for flag in (
            dr.JitFlag.SymbolicLoops,
            dr.JitFlag.SymbolicCalls,
            dr.JitFlag.SymbolicConditionals,
        ):
            stack.enter_context(dr.scoped_set_flag(flag, False))
        try:
            yield True
        except Exception as exc:
            failure = model_failure(exc)
            if failure is None:
                raise
            raise JobFailed(str(failure)) from None


def model_failure(exc: BaseException) -> OnnxEvalError | None:
    """The :class:`OnnxEvalError` that ``exc`` is or was raised from (its causes and
    contexts), else ``None``."""
    seen: list[BaseException] = []
    cur: BaseException | None = exc
    while cur is not None and all(cur is not e for e in seen):
        if isinstance(cur, OnnxEvalError):
            return cur
        seen.append(cur)
        cur = cur.__cause__ or cur.__context__
    return None


def _call_model(
    mi: types.ModuleType, owner: Any, model: OnnxMaterial, active: Any, *arrays: Any
) -> Any:
    """``model.eval`` on the active lanes of Dr.Jit arrays ``(uv,) wi, wo``; a
    ``mi.Color3f``, 0 on inactive lanes. Returns 0 in a symbolic scope (module docstring)."""
    import drjit as dr

    if dr.flag(dr.JitFlag.SymbolicScope):
        owner.symbolic_calls += 1
        if owner.symbolic_calls == 1:
            log.warning(
                "%s traced symbolically: it returns 0 there; render inside wavefront_scope()",
                model.name,
            )
        return mi.Color3f(0.0)
    n = max(dr.width(a) for a in (active, *arrays))
    mask = np.broadcast_to(np.asarray(mi.Bool(active).numpy(), bool), (n,))
    host = [np.broadcast_to(np.asarray(a.numpy(), np.float32).T, (n, len(a))) for a in arrays]
    out = np.zeros((n, 3), np.float32)
    if mask.any():
        picked = [h[mask] for h in host]
        if model.kind == "btf":
            out[mask] = model.eval(picked[1], picked[2], uv=picked[0])
        else:
            out[mask] = model.eval(picked[0], picked[1])
    return mi.Color3f(mi.Float(out[:, 0]), mi.Float(out[:, 1]), mi.Float(out[:, 2]))


def _load(props: Any) -> OnnxMaterial | OnnxMlpMaterial:
    if "filename" not in props or "kind" not in props:
        raise ValueError("external_onnx: 'filename' and 'kind' are required")
    threads = int(props.get("threads", DEFAULT_THREADS))
    label = str(props["label"]) if "label" in props else None
    runtime = str(props.get("runtime", "auto"))
    try:
        return open_onnx(
            Path(str(props["filename"])),
            str(props["kind"]),
            threads=threads,
            runtime=runtime,
            label=label,
        )
    except Exception as exc:  # FormatError, TooLargeError: a one-line message naming the file
        raise ValueError(f"external_onnx: {exc}") from None


def _check_sampling(props: Any) -> MixtureSampling:
    alpha = float(props.get("alpha", 1.0))
    weight = float(props.get("specular_weight", 0.0))
    if not (0.0 < alpha <= 1.0 and 0.0 <= weight < 1.0):
        raise ValueError(
            f"external_onnx: alpha must lie in (0, 1] and specular_weight in [0, 1), "
            f"got {alpha} and {weight}"
        )
    return MixtureSampling(alpha, weight)  # weight 0: cosine only


class OnnxBrdf(GlossyDiffuseReflector):
    """An ONNX BRDF (``kind = brdf``), cosine-sampled or with a GGX lobe (MIS)."""

    def __init__(self, props: Any, model: OnnxMaterial) -> None:
        MixtureReflector.__init__(self, props)
        mi = self.mi
        flags = (
            mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
        )
        self.model = model
        self.symbolic_calls = 0
        self.sampling = _check_sampling(props)
        self.m_flags = flags
        self.m_components = [flags]
        _LIVE.add(self)

    def brdf(self, ctx: Any, wi: Any, wo: Any, active: Any) -> Any:
        mi, dr = self.mi, self.dr
        active = active & (wi.z > 0.0) & (wo.z > 0.0)
        return dr.select(active, _call_model(mi, self, self.model, active, wi, wo), 0.0)

    def to_string(self) -> str:
        return f"OnnxBrdf[{self.model.name}, {self.model.param_bytes} parameter bytes]"


class OnnxBtf(BtfReflector):
    """An ONNX BTF (``kind = btf``), cosine-sampled."""

    def __init__(self, props: Any, model: OnnxMaterial) -> None:
        BtfReflector.__init__(self, props)
        self.model = model
        self.symbolic_calls = 0
        self.uv_scale = uv_scale_of(props)
        _LIVE.add(self)

    def btf(self, uv: Any, light: Any, view: Any, active: Any) -> Any:
        return _call_model(self.mi, self, self.model, active, uv, light, view)

    def to_string(self) -> str:
        return f"OnnxBtf[{self.model.name}, uv_scale={self.uv_scale}]"


class OnnxFusedBrdf(GlossyDiffuseReflector):
    """A recognised ONNX BRDF traced into the render kernel (sampling as :class:`OnnxBrdf`)."""

    def __init__(self, props: Any, model: OnnxMlpMaterial) -> None:
        MixtureReflector.__init__(self, props)
        mi = self.mi
        flags = (
            mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
        )
        self.model = model
        self.fused = model.fused(mi)
        self.sampling = _check_sampling(props)
        self.m_flags = flags
        self.m_components = [flags]

    def brdf(self, ctx: Any, wi: Any, wo: Any, active: Any) -> Any:
        active = active & (wi.z > 0.0) & (wo.z > 0.0)
        return self.dr.select(active, self.fused.eval(wi, wo), 0.0)

    def to_string(self) -> str:
        return f"OnnxFusedBrdf[{self.model.name}, {self.model.param_bytes} parameter bytes]"


class OnnxFusedBtf(BtfReflector):
    """A recognised ONNX BTF traced into the render kernel (cosine-sampled)."""

    def __init__(self, props: Any, model: OnnxMlpMaterial) -> None:
        BtfReflector.__init__(self, props)
        self.model = model
        self.fused = model.fused(self.mi)
        self.uv_scale = uv_scale_of(props)

    def btf(self, uv: Any, light: Any, view: Any, active: Any) -> Any:
        return self.fused.eval(light, view, uv)

    def to_string(self) -> str:
        return f"OnnxFusedBtf[{self.model.name}, uv_scale={self.uv_scale}]"


class _VariantClasses:
    """A class attribute: the classes of the owner's variant (:func:`class_for_variant`)
    for the given bodies."""

    def __init__(self, *bodies: type[VariantPlugin]) -> None:
        self.bodies = bodies

    def __get__(self, obj: Any, owner: type[VariantPlugin]) -> tuple[type, ...]:
        return tuple(class_for_variant(owner.mi, body) for body in self.bodies)


class ExternalOnnx(VariantPlugin):
    """Factory: by the ``kind`` property, an :class:`OnnxFusedBrdf` or :class:`OnnxFusedBtf`
    for a recognised MLP graph (unless ``runtime`` is ``onnxruntime``), else an
    :class:`OnnxBrdf` or :class:`OnnxBtf` (of the variant's classes). Its own per-variant
    class is never instantiated."""

    #: The BSDF classes it makes, the variant's (all ``mi.BSDF`` subclasses).
    variants = _VariantClasses(OnnxBrdf, OnnxBtf, OnnxFusedBrdf, OnnxFusedBtf)

    def __new__(cls, props: Any) -> Any:
        model = _load(props)
        body: type[VariantPlugin]
        if isinstance(model, OnnxMlpMaterial):
            body = OnnxFusedBtf if model.kind == "btf" else OnnxFusedBrdf
        else:
            body = OnnxBtf if model.kind == "btf" else OnnxBrdf
        return class_for_variant(cls.mi, body)(props, model)
