"""A user's BTF in ``evaluate.tss``: ``{"model": {"external": {"model": REF, "kind": "btf"}}}``.

An MLP BTF (``matforge.mlp-btf/1``) is traced into the same Dr.Jit passes as a
``train.btf`` model: :class:`ExternalPlaneModel` gives :class:`evaluators.tss.passes.Plane`
what it asks of a model (``eval(uv, wi, wo)``, ``h``, ``w``, ``mi``, ``dr``) through
:class:`models.external.fused.FusedMlp`, the kernel the renderer uses. It has no amortised
2 x 2 pass (that is the coarse-to-fine student's), so every radiance texture is shaded per
texel. Its resolution (for the texel-matched default) is its first latent texture's, or
:data:`DEFAULT_RESOLUTION` without one.

An ONNX BTF is refused: the passes are timed as Dr.Jit kernels (``seconds_per_frame`` from
the kernel history), and onnxruntime cannot be traced into them, so its cost per frame
would be missing from the figures.
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
#: The runtime of every model evaluate.tss times.
RUNTIME = "drjit-fused"


class ExternalPlaneModel:
    """An MLP BTF as the plane's model (see the module docstring)."""

    kind = "external"
    model = "external"
    #: No 2 x 2 amortised pass: :meth:`Plane.texel_matched` is false for it.
    amortisable = False

    def __init__(self, material: Any, mi: types.ModuleType) -> None:
        import drjit as dr

        from models.external.fused import FusedMlp

        self.material = material
        self.fused = FusedMlp(material, mi)
        self.mi, self.dr = mi, dr
        tex = material.doc.textures
        self.h, self.w = (int(tex[0].shape[1]), int(tex[0].shape[2])) if tex else (
            DEFAULT_RESOLUTION, DEFAULT_RESOLUTION)  # fmt: skip

    @property
    def resolution(self) -> tuple[int, int]:
        return self.h, self.w

    def eval(self, uv: Any, wi: Any, wo: Any) -> Any:
        """The BTF (``mi.Color3f``) at patch coordinates ``uv``, light ``wi``, view ``wo``."""
        return self.fused.eval(wi, wo, uv)


def load_external_btf(value: dict[str, Any], ctx: JobContext, mi: types.ModuleType) -> Any:
    """The :class:`ExternalPlaneModel` of ``{"model": REF, "kind": "btf"}``; ``JobFailed``
    naming ``model.external`` for an ONNX or malformed file."""
    from models.external import load_external

    where = "model.external.model"
    ref = value["model"]
    try:
        model = load_external(ctx.resolve(ref), "btf")
    except (ValueError, FormatError) as exc:
        problem = exc.problem if isinstance(exc, FormatError) else str(exc)
        raise JobFailed(f"{where}: {ref}: {problem}") from None
    if model.runtime != RUNTIME:
        raise JobFailed(
            f"{where}: {ref} runs in {model.runtime}; evaluate.tss times Dr.Jit kernels, "
            f"which cannot call out to it: export the network as matforge.mlp-btf/1 "
            f"(matforge.export.btf_mlp) to run it here"
        )
    return ExternalPlaneModel(model, mi)
