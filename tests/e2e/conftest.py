"""End-to-end fixtures: a ``matforge serve`` per test module (see :mod:`.harness`), with
every process it started stopped at the end, workers included."""

from __future__ import annotations

import warnings
from collections.abc import Iterator

import pytest

from .browser import page  # noqa: F401 (the browser tests' fixture)
from .harness import Server, start_server, stop_server


def _stop(srv: Server) -> None:
    leftovers = stop_server(srv)
    if leftovers:
        warnings.warn(
            f"processes outlived matforge serve and were killed: {leftovers}", stacklevel=2
        )


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """One server (1 worker, no token) shared by a test module."""
    srv = start_server(tmp_path_factory.mktemp("server"))
    try:
        yield srv
    finally:
        _stop(srv)


@pytest.fixture(scope="module")
def token_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """A server that requires ``MATFORGE_TOKEN`` (no workers: only auth is tested)."""
    srv = start_server(tmp_path_factory.mktemp("token-server"), token="s3cret-token", workers=0)
    try:
        yield srv
    finally:
        _stop(srv)
