"""Export a PyTorch material model to an ONNX file with matforge's documented signature.

``docs/onnx-models.md`` documents the signature; these helpers call ``torch.onnx.export``
with the right input and output names, a dynamic batch dimension ``N``, and check the file
with the same validator the server runs on an upload (``storage.formats.onnx``), so a file
that exports here uploads there.

- :func:`brdf_onnx`: ``module(wi, wo) -> rgb``, ``(N, 3)`` float32 each; the plain BRDF in
  1/sr (no cosine), directions in the local frame, z up.
- :func:`btf_onnx`: ``module(uv, wi, wo) -> rgb``, ``uv`` ``(N, 2)``; the BTF in
  ``generate.btf``'s convention (``cos(theta_i)`` of the light ``wi`` included).

The TorchScript exporter is used (``dynamo=False``): it needs only the ``onnx`` package,
whereas torch's dynamo exporter also needs ``onnxscript``. Importing this module imports
neither torch nor onnx; the helpers do.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

#: The opset the helpers export with (inside the accepted range of the validator).
OPSET = 17


def _export(module: Any, path: Path | str, names: tuple[str, ...], kind: str, opset: int) -> Path:
    import torch

    from storage.formats.onnx import check_onnx_file

    dims = {"uv": 2, "wi": 3, "wo": 3}
    gen = torch.Generator().manual_seed(0)
    args = []
    for name in names:
        x = torch.rand(8, dims[name], generator=gen)
        if name != "uv":
            x = torch.nn.functional.normalize(x + torch.tensor([0.0, 0.0, 0.5]), dim=1)
        args.append(x)
    path = Path(path)
    was_training = getattr(module, "training", False)
    if hasattr(module, "eval"):
        module.eval()
    try:
        with torch.no_grad():
            torch.onnx.export(
                module,
                tuple(args),
                str(path),
                input_names=list(names),
                output_names=["rgb"],
                dynamic_axes={n: {0: "N"} for n in (*names, "rgb")},
                opset_version=opset,
                dynamo=False,
            )
    finally:
        if was_training:
            module.train()
    _fix_output_shape(path)
    check_onnx_file(path, path.name, kind)
    return path


def _fix_output_shape(path: Path) -> None:
    """Write the output's shape as ``[N, 3]``: torch leaves a broadcast dimension symbolic."""
    import onnx

    model = onnx.load(str(path))
    dims = model.graph.output[0].type.tensor_type.shape.dim
    if len(dims) == 2 and not dims[1].HasField("dim_value"):
        dims[1].ClearField("dim_param")
        dims[1].dim_value = 3
        onnx.save(model, str(path))


def brdf_onnx(module: Any, path: Path | str, *, opset: int = OPSET) -> Path:
    """Export a BRDF ``module(wi, wo) -> rgb`` (``torch.nn.Module``, ``(N, 3)`` float32 in
    and out) to ``path``; returns the path. Raises ``storage.errors.FormatError`` naming
    the file if the export strays from the signature or uses an operator the server refuses.
    """
    return _export(module, path, ("wi", "wo"), "brdf", opset)


def btf_onnx(module: Any, path: Path | str, *, opset: int = OPSET) -> Path:
    """Export a BTF ``module(uv, wi, wo) -> rgb`` (``uv`` ``(N, 2)``, directions ``(N, 3)``)
    to ``path``; returns the path. Raises as :func:`brdf_onnx`."""
    return _export(module, path, ("uv", "wi", "wo"), "btf", opset)


__all__ = ["brdf_onnx", "btf_onnx"]
