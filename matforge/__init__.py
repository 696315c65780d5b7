"""matforge: the public Python API.

This package is small and stable; everything else (``service``, ``generators``,
``models``, ...) is internal and may change. What a user's code needs:

- :data:`__version__`: the one version (also ``matforge --version``, the API's OpenAPI
  document and every job manifest);
- :class:`Client`: the REST API of a server, typed, with the CLI's errors as exceptions
  (:class:`SpecError`, :class:`JobFailed`, :class:`ServerUnreachable`, ...);
- :func:`run`: one job in this process, no server;
- :mod:`matforge.datasets`: dataset jobs as typed readers with ``.numpy()`` and
  ``.torch_dataset(...)``.

``import matforge`` imports neither torch nor Mitsuba.
"""

from __future__ import annotations

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
from matforge.run import run

__all__ = [
    "BadInput",
    "Client",
    "ClientError",
    "JobFailed",
    "ServerRefused",
    "ServerUnreachable",
    "SpecError",
    "__version__",
    "datasets",
    "run",
]
