"""storage.write_lock: writers of several processes are serialised by the lock itself, not
by SQLite's sleeping busy handler. Reference: the kernel's ``flock`` semantics, observed from
another process (a child holding the lock keeps this process out until it lets go)."""

from __future__ import annotations

import multiprocessing as mp
import threading
import time
from pathlib import Path

from storage.jobs import JobStore
from storage.write_lock import write_lock


def _hold(db: str, held: mp.synchronize.Event, release: mp.synchronize.Event) -> None:
    with write_lock(Path(db)).hold():
        held.set()
        release.wait(30)


def test01_another_process_holding_the_lock_blocks_a_writer(tmp_path: Path) -> None:
    store = JobStore(tmp_path / "jobs.sqlite3")
    ctx = mp.get_context("spawn")
    held, release = ctx.Event(), ctx.Event()
    child = ctx.Process(target=_hold, args=(str(tmp_path / "jobs.sqlite3"), held, release))
    child.start()
    try:
        assert held.wait(60), "the child never took the lock"
        done = threading.Event()

        def submit() -> None:
            spec = {"kind": "render", "params": {"n": 1}}
            store.submit(kind="render", name=None, seed=0, spec_hash="h" * 64, spec=spec)
            done.set()

        t = threading.Thread(target=submit)
        t.start()
        # While the child holds the lock the write cannot finish (0.5 s is far more than a
        # write takes; the assertion is about order, not speed).
        assert not done.wait(0.5)
        release.set()
        assert done.wait(30), "the write never went through after the child let go"
        t.join()
    finally:
        release.set()
        child.join(30)
    assert child.exitcode == 0
    assert len(store.list_jobs()) == 1


def test02_reentrant_in_one_thread_and_exclusive_between_threads(tmp_path: Path) -> None:
    lock = write_lock(tmp_path / "db")
    order: list[str] = []
    with lock.hold():
        with lock.hold():  # re-entrant: no deadlock

            def other() -> None:
                with lock.hold():
                    order.append("t")

            t = threading.Thread(target=other)
            t.start()
            time.sleep(0.2)
            order.append("main")
    t.join(10)
    assert order == ["main", "t"]
