"""matforge: the public Python API.

This package is small and stable; everything else (``service``, ``generators``,
``models``, ...) is internal and may change. What a user's code needs:

- :data:`__version__`: the one version (also ``matforge --version``, the API's OpenAPI
  document and every job manifest);
- :class:`Client`: the REST API of a server, answering with typed objects (:class:`Job`,
  :class:`Artifact`, :class:`ResultRow`, :class:`Kind`, :class:`Upload`, each with
  ``.raw``, the whole document), with the CLI's errors as exceptions (:class:`SpecError`,
  :class:`JobFailed`, :class:`ServerUnreachable`, ...);
- :func:`run`: one job in this process, no server;
- :mod:`matforge.datasets`: dataset jobs as typed readers with ``.numpy()`` and
  ``.torch_dataset(...)``;
- :mod:`matforge.export`: your own PyTorch BRDF or BTF network as a matforge MLP file
  (``matforge.mlp-brdf/1``, ``matforge.mlp-btf/1``), rendered by the fused kernel;
- :mod:`matforge.export_onnx`: any PyTorch material model as an ONNX file with the
  documented signature, evaluated with onnxruntime.

``import matforge`` imports neither torch nor Mitsuba; ``matforge.export`` and
``matforge.export_onnx`` are imported on first use (``matforge.export.brdf_mlp``), and
import torch (and onnx) only when a helper converts a module.
"""

from __future__ import annotations

from typing import Any

from jobapi.version import __version__
from matforge import datasets
from matforge.client import (
    BadInput,
    Client,
    ClientError,
    JobFailed,
    ServerRefused,
    ServerUnreachable,
    SpecError,
)
from matforge.objects import Artifact, Job, Kind, ResultRow, Upload
from matforge.run import run

#: Submodules imported on first attribute access (PEP 562), so that ``import matforge``
#: stays light.
_LAZY = ("export", "export_onnx")


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return importlib.import_module(f"matforge.{name}")
    raise AttributeError(f"module 'matforge' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


__all__ = [
    "Artifact",
    "BadInput",
    "Client",
    "ClientError",
    "Job",
    "JobFailed",
    "Kind",
    "ResultRow",
    "ServerRefused",
    "ServerUnreachable",
    "SpecError",
    "Upload",
    "__version__",
    "datasets",
    "export",
    "export_onnx",
    "run",
]
