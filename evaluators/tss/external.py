"""A user's BTF in ``evaluate.tss``: ``{"model": {"external": {"model": REF, "kind": "btf"}}}``.

An MLP BTF (``matforge.mlp-btf/1``, or an ONNX BTF whose graph is an MLP:
:mod:`models.external.onnx_mlp`) is traced into the same Dr.Jit passes as a
``train.btf`` model: :class:`ExternalPlaneModel` gives :class:`evaluators.tss.passes.Plane`
what it asks of a model (``eval(uv, wi, wo)``, ``h``, ``w``, ``mi``, ``dr``) through
:func:`models.external.fused.fused_of`, the kernel the renderer uses. It has no amortised
2 x 2 pass (that is the coarse-to-fine student's), so every radiance texture is shaded per
texel. Its resolution (for the texel-matched default) is its first latent texture's, or
:data:`DEFAULT_RESOLUTION` without one.

Any other ONNX BTF (:class:`OnnxPlaneModel`) runs in the same passes with onnxruntime: texture-space
shading evaluates the model over a batch of texels (the radiance texture's, or a frame's
pixels for the screen-space reference), so each pass reads its ``(uv, wi, wo)`` lanes back
once per light, runs the session on them (:meth:`OnnxMaterial.eval`) and hands the values
back to Dr.Jit. The passes have no loops, so no symbolic scope is involved. Its cost per
pass is the Dr.Jit kernels' execution time plus the seconds spent inside onnxruntime
(:attr:`OnnxPlaneModel.outside_seconds`), so the screen-space pass it is compared with is
timed the same way; the rows name the runtime (``onnxruntime``). An ONNX file has no latent
texture to take a resolution from: the texel-matched default is :data:`DEFAULT_RESOLUTION`.
"""

from __future__ import annotations

import types
from typing import TYPE_CHECKING, Any

from jobapi.errors import JobFailed
from storage.errors import FormatError

if TYPE_CHECKING:
    from jobapi.context import JobContext

#: The side of a texture-less model's texel-matched radiance texture.
DEFAULT_RESOLUTION = 32
#: The runtime of an MLP BTF (traced into the passes).
RUNTIME = "drjit-fused"
#: The runtime of an ONNX BTF (called from the passes).
ONNX_RUNTIME = "onnxruntime"


class ExternalPlaneModel:
    """An MLP BTF as the plane's model (see the module docstring)."""

    kind = "external"
    model = "external"
    #: No 2 x 2 amortised pass: :meth:`Plane.texel_matched` is false for it.
    amortisable = False

    def __init__(self, material: Any, mi: types.ModuleType) -> None:
        import drjit as dr

        from models.external.fused import fused_of

        self.material = material
        self.fused = fused_of(material, mi)
        self.mi, self.dr = mi, dr
        doc = getattr(material, "doc", None)  # an ONNX graph has no latent textures
        tex = doc.textures if doc is not None else ()
        self.h, self.w = (int(tex[0].shape[1]), int(tex[0].shape[2])) if tex else (
            DEFAULT_RESOLUTION, DEFAULT_RESOLUTION)  # fmt: skip

    runtime = RUNTIME

    @property
    def resolution(self) -> tuple[int, int]:
        return self.h, self.w

    def eval(self, uv: Any, wi: Any, wo: Any) -> Any:
        """The BTF (``mi.Color3f``) at patch coordinates ``uv``, light ``wi``, view ``wo``."""
        return self.fused.eval(wi, wo, uv)


class OnnxPlaneModel:
    """An ONNX BTF (:class:`models.external.onnx_model.OnnxMaterial`) as the plane's model:
    every :meth:`eval` evaluates its inputs, runs onnxruntime on the batch and returns the
    values as Dr.Jit arrays (see the module docstring)."""

    kind = "external"
    model = "external"
    amortisable = False

    def __init__(self, material: Any, mi: types.ModuleType) -> None:
        import drjit as dr

        self.material = material
        self.runtime = str(material.runtime)
        self.mi, self.dr = mi, dr
        self.h = self.w = DEFAULT_RESOLUTION

    @property
    def resolution(self) -> tuple[int, int]:
        return self.h, self.w

    def outside_seconds(self) -> float:
        """Seconds spent inside onnxruntime so far (cumulative)."""
        return float(self.material.stats.seconds)

    def eval(self, uv: Any, wi: Any, wo: Any) -> Any:
        """The BTF (``mi.Color3f``) at ``uv``, light ``wi``, view ``wo``: the lanes read
        back (float32, ``(N, k)``), onnxruntime once over them (in chunks), the values
        returned as they are (the plane masks lights and eyes below the horizon)."""
        import numpy as np

        dr, mi = self.dr, self.mi
        arrays = (uv, wi, wo)
        dr.eval(*arrays)
        n = max(dr.width(a) for a in arrays)
        host = [np.broadcast_to(np.asarray(a.numpy(), np.float32).T, (n, len(a)))
                for a in arrays]  # fmt: skip
        from models.external.onnx_model import OnnxEvalError

        try:
            out = self.material.eval(host[1], host[2], uv=host[0])
        except OnnxEvalError as exc:
            raise JobFailed(str(exc)) from None
        return mi.Color3f(mi.Float(out[:, 0]), mi.Float(out[:, 1]), mi.Float(out[:, 2]))


def load_external_btf(value: dict[str, Any], ctx: JobContext, mi: types.ModuleType) -> Any:
    """The :class:`ExternalPlaneModel` (an MLP BTF) or :class:`OnnxPlaneModel` (an ONNX
    BTF) of ``{"model": REF, "kind": "btf"}``; ``JobFailed`` naming ``model.external`` for
    a malformed file or an unknown runtime."""
    from models.external import load_external

    where = "model.external.model"
    ref = value["model"]
    try:
        model = load_external(ctx.resolve(ref), "btf", label=ref, runtime=value.get("runtime"))
    except (ValueError, FormatError) as exc:
        problem = exc.problem if isinstance(exc, FormatError) else str(exc)
        raise JobFailed(f"{where}: {ref}: {problem}") from None
    if model.runtime == RUNTIME:
        return ExternalPlaneModel(model, mi)
    if model.runtime == ONNX_RUNTIME:
        return OnnxPlaneModel(model, mi)
    raise JobFailed(f"{where}: {ref} runs in {model.runtime}, which evaluate.tss cannot run")
