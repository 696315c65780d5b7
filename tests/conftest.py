"""Shared fixtures: a temporary data directory and a toy job kind for platform tests."""

from __future__ import annotations

import time
import types
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from pydantic import Field

from jobapi import kinds as jobapi_kinds
from jobapi.context import JobContext
from jobapi.errors import JobFailed
from jobapi.kinds import Kind
from jobapi.params import StrictModel
from service import kinds
from service.settings import Settings
from storage.artifacts import ArtifactStore
from storage.jobs import JobStore


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    """Settings over a fresh data directory, short leases, inline-sized pools."""
    return Settings.from_env({}).with_(
        data_dir=tmp_path / "data", lease_seconds=2.0, pool_processes=2
    )


@pytest.fixture
def jobs(settings: Settings) -> Iterator[JobStore]:
    store = JobStore(settings.db_path)
    yield store
    store.close()


@pytest.fixture
def store(settings: Settings) -> ArtifactStore:
    return ArtifactStore(settings.store_dir)


class ToyParams(StrictModel):
    """Params of the test-only ``toy`` kind."""

    n: int = Field(default=4, ge=1, le=1000, description="number of shards")
    sleep: float = Field(default=0.0, ge=0.0, le=30.0, description="seconds per shard")
    fail: bool = Field(default=False, description="fail with a JobFailed")


def toy_shard(item: tuple[int, float]) -> int:
    """A shard: sleeps, then returns i squared (module level, so it pickles)."""
    i, sleep = item
    time.sleep(sleep)
    return i * i


def run_toy(params: ToyParams, ctx: JobContext) -> None:
    if params.fail:
        raise JobFailed("toy failure requested by params.fail")
    out = ctx.map_shards(toy_shard, [(i, params.sleep) for i in range(params.n)], label="toy")
    ctx.put_json("result.json", {"squares": out, "seed_draw": int(ctx.rng().integers(1 << 30))})


@pytest.fixture
def toy_kind(monkeypatch: pytest.MonkeyPatch) -> Kind:
    """Register the toy kind for the duration of one test."""
    kinds.load_builtin()
    kind = Kind(name="toy", params=ToyParams, runner=run_toy, description="test-only kind")
    monkeypatch.setitem(jobapi_kinds._KINDS, "toy", kind)
    return kind


@pytest.fixture(scope="session")
def mi() -> types.ModuleType:
    """Mitsuba in its LLVM variant. ``make setup`` installs libLLVM 19 for it, so a scalar
    fallback means a broken set-up: the tests that need LLVM fail loudly rather than skip."""
    from materials.backend import load_mitsuba

    mod = load_mitsuba()
    if not mod.variant().startswith("llvm_"):
        pytest.fail(
            f"Mitsuba runs {mod.variant()!r}, not an LLVM variant: libLLVM 19 is missing "
            "(run `make setup`, which installs Debian's libllvm19)"
        )
    return mod


@pytest.fixture(scope="session")
def mitsuba_llvm(mi: types.ModuleType) -> None:
    """For tests that only need the LLVM variant to be active."""


@pytest.fixture(scope="session")
def ray_session() -> Iterator[Any]:
    """The test session's Ray (:class:`tests.helpers.ray_session.RaySession`), shut down,
    every process of it, when the session ends. Imported here only when a test asks."""
    from tests.helpers.ray_session import RaySession

    session = RaySession()
    try:
        yield session
    finally:
        session.shutdown()


@pytest.fixture
def ray_local(ray_session: Any) -> Any:
    """A local Ray of 2 CPUs, shared by the tests that use it (started once)."""
    ray_session.local(num_cpus=2)
    return ray_session


#: The per-test limit of a test marked ``slow`` that sets none itself (the default of
#: pyproject.toml, 300 s, is for the rest).
SLOW_TIMEOUT_S = 600


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if item.get_closest_marker("slow") and not item.get_closest_marker("timeout"):
            item.add_marker(pytest.mark.timeout(SLOW_TIMEOUT_S))
