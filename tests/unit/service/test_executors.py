"""Choosing the shard backend from the environment (no Ray is started here)."""

from __future__ import annotations

import pytest

from jobapi.executor import InlineExecutor
from service.settings import Settings
from service.workers.executors import LocalPoolExecutor, executor_for, make_executor


def test01_default_is_the_local_process_pool() -> None:
    settings = Settings.from_env({})
    assert settings.executor == "process" and settings.ray_address is None
    executor = executor_for(settings)
    assert isinstance(executor, LocalPoolExecutor)
    assert executor.describe() == {"executor": "process", "executor_nodes": 1}


def test02_ray_with_an_address_and_retries() -> None:
    from service.workers.ray_executor import RayExecutor

    env = {
        "MATFORGE_EXECUTOR": "Ray",
        "RAY_ADDRESS": "10.0.0.5:6379",
        "MATFORGE_RAY_MAX_RETRIES": "5",
        "RAY_AUTH_MODE": "token",
    }
    settings = Settings.from_env(env)
    executor = executor_for(settings)
    assert isinstance(executor, RayExecutor)
    assert (executor.address, executor.max_retries, executor.auth_mode) == (
        "10.0.0.5:6379",
        5,
        "token",
    )
    # A worker started by the supervisor gets the same choice.
    assert Settings.from_env(settings.to_env()).executor == "ray"
    assert Settings.from_env(settings.to_env()).ray_address == "10.0.0.5:6379"


def test03_unknown_backend_is_refused_with_its_name() -> None:
    with pytest.raises(ValueError, match="MATFORGE_EXECUTOR='dask'"):
        Settings.from_env({"MATFORGE_EXECUTOR": "dask"})
    with pytest.raises(ValueError, match="unknown executor backend 'dask'"):
        make_executor("dask")


def test04_inline_describes_itself() -> None:
    assert InlineExecutor().describe() == {"executor": "inline", "executor_nodes": 1}


def test05_the_watch_and_archive_settings_reach_the_workers() -> None:
    """Issue 21: the stall limit and the archive pixel cap travel to worker processes."""
    default = Settings.from_env({})
    assert default.stall_seconds is None and default.archive_max_pixels == 64_000_000
    assert "MATFORGE_STALL_SECONDS" not in default.to_env()
    s = Settings.from_env({"MATFORGE_STALL_SECONDS": "2.5", "MATFORGE_ARCHIVE_MPIX": "0.05"})
    assert s.stall_seconds == 2.5 and s.archive_max_pixels == 50_000
    again = Settings.from_env(s.to_env())
    assert again.stall_seconds == 2.5 and again.archive_max_pixels == 50_000


def test06_abort_frees_a_map_blocked_on_the_pool() -> None:
    """Issue 21 item 6: ``abort`` from another thread ends a map whose shards would take
    a minute; the executor then runs the next map in a fresh pool."""
    import threading
    import time
    from concurrent.futures.process import BrokenProcessPool

    ex = LocalPoolExecutor(2)
    try:
        threading.Timer(3.0, ex.abort).start()
        t0 = time.monotonic()
        with pytest.raises(BrokenProcessPool):
            list(ex.map(time.sleep, [60.0, 60.0, 60.0]))
        assert time.monotonic() - t0 < 30
        assert sorted(r for _, r in ex.map(abs, [-1, -2])) == [1, 2]
    finally:
        ex.close()


def test06_shared_store_is_an_explicit_flag_that_reaches_the_executors() -> None:
    """``MATFORGE_SHARED_STORE``: off unless said; then the pool and Ray backends both
    let their shards store their own results, and a worker process gets the same."""
    from jobapi.executor import uses_shared_store
    from service.workers.ray_executor import RayExecutor

    default = Settings.from_env({})
    assert default.shared_store is False
    assert not uses_shared_store(executor_for(default))
    for raw in ("1", "true", "YES"):
        s = Settings.from_env({"MATFORGE_SHARED_STORE": raw, "MATFORGE_EXECUTOR": "ray"})
        ex = executor_for(s)
        assert isinstance(ex, RayExecutor) and uses_shared_store(ex)
        assert Settings.from_env(s.to_env()).shared_store is True
        assert uses_shared_store(executor_for(s.with_(executor="process")))
    assert Settings.from_env({"MATFORGE_SHARED_STORE": "0"}).shared_store is False
    assert Settings.from_env(default.to_env()).shared_store is False
    with pytest.raises(ValueError, match="MATFORGE_SHARED_STORE='maybe' is not a flag"):
        Settings.from_env({"MATFORGE_SHARED_STORE": "maybe"})
