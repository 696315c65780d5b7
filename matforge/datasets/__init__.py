"""Datasets of matforge jobs as typed readers, with numpy access and PyTorch datasets.

:func:`open` takes a finished dataset job (``job:<id>``, an id, or a unique prefix of one)
from a local data directory (``data_dir=``) or a server (``client=``, a
:class:`matforge.Client`) and returns the reader of its kind:

====================================  ==============================================
kind                                  reader
====================================  ==============================================
``generate.fabric``                   :class:`FabricQueries`
``generate.btf``, ``import.btf``      :class:`BtfSlices`
``generate.merl``                     :class:`MerlCollection`
``generate.glint``                    :class:`GlintExample`
====================================  ==============================================

Every reader has ``.numpy()`` and ``.torch_dataset(...)`` (torch is imported only then).
Artifacts are verified against their digests before use; from a server, each object is
downloaded once into a local cache (``cache_dir``, default ``~/.cache/matforge``). The
artifact layouts are documented in ``docs/artifacts.md``.
"""

from __future__ import annotations

import os
from typing import Any

from matforge.datasets.base import DatasetReader
from matforge.datasets.btf import BtfSlices
from matforge.datasets.fabric import FabricQueries
from matforge.datasets.glint import GlintExample
from matforge.datasets.merl import MerlCollection, MerlMaterial
from matforge.datasets.source import LocalSource, RemoteSource, Source

__all__ = [
    "BtfSlices",
    "DatasetReader",
    "FabricQueries",
    "GlintExample",
    "MerlCollection",
    "MerlMaterial",
    "READERS",
    "open",
]

#: The reader of each dataset kind.
READERS: dict[str, type[DatasetReader]] = {
    kind: reader
    for reader in (FabricQueries, BtfSlices, MerlCollection, GlintExample)
    for kind in reader.KINDS
}


def open(  # noqa: A001 (the issue's name: matforge.datasets.open)
    ref_or_job: str,
    data_dir: str | os.PathLike[str] | None = None,
    *,
    client: Any = None,
    cache_dir: str | os.PathLike[str] | None = None,
) -> Any:
    """The reader of a finished dataset job.

    Parameters
    ----------
    ref_or_job
        ``job:<id>`` (``job:<id>/<artifact>`` names the same job), a job id, or a unique
        prefix of one.
    data_dir
        Read the job from this local data directory (its job database and store).
    client
        Else read it from this server (a :class:`matforge.Client`); with neither, a
        ``matforge.Client()`` of ``MATFORGE_SERVER`` / ``MATFORGE_TOKEN``.
    cache_dir
        Where objects downloaded from a server are kept (default ``~/.cache/matforge``).

    Returns
    -------
    :class:`FabricQueries`, :class:`BtfSlices`, :class:`MerlCollection` or
    :class:`GlintExample`, by the job's kind. ``ValueError`` for a job of another kind or
    one that has not succeeded.
    """
    source: Source
    if data_dir is not None and client is not None:
        raise ValueError("give data_dir or client, not both")
    if data_dir is not None:
        source = LocalSource(ref_or_job, data_dir)
    else:
        if client is None:
            from matforge.client import Client

            client = Client()
        source = RemoteSource(ref_or_job, client, cache_dir)
    reader = READERS.get(source.kind)
    if reader is None:
        raise ValueError(
            f"job {source.job_id} is a {source.kind} job, not a dataset; datasets are "
            f"{', '.join(sorted(READERS))}"
        )
    return reader(source)
