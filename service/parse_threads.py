"""Spec parsing off the web app's event loop, a few at a time (issue 21, item 5).

Parsing and checking a hostile spec (deep YAML, a 1 MB flat array) costs up to a few hundred
milliseconds of CPU. Run on the event loop, four of them at once held ``/api/health`` for
seconds. :func:`off_loop` runs such work in worker threads, at most :data:`PARSE_THREADS` at
once: pure-Python parsing holds the GIL however many threads share it, so more threads would
not parse faster, only make the event loop wait longer for the GIL between them. Requests
beyond that wait on the loop, costing nothing.
"""

from __future__ import annotations

import asyncio
import weakref
from collections.abc import Callable
from typing import TypeVar

import anyio.to_thread
from anyio import CapacityLimiter

T = TypeVar("T")

#: Large specs parsed and validated at once per web process.
PARSE_THREADS = 1
#: Text up to this size is cheap to parse and validate whatever it holds (a few ms; YAML is
#: checked on libyaml's events first), and is not limited.
SMALL_BYTES = 16 * 1024
# One limiter per event loop: a limiter waits with its loop's primitives (tests run several
# loops, one per TestClient, over one app).
_LIMITERS: weakref.WeakKeyDictionary[asyncio.AbstractEventLoop, CapacityLimiter] = (
    weakref.WeakKeyDictionary()
)


def _limiter() -> CapacityLimiter:
    loop = asyncio.get_running_loop()
    limiter = _LIMITERS.get(loop)
    if limiter is None:
        limiter = _LIMITERS[loop] = CapacityLimiter(PARSE_THREADS)
    return limiter


async def off_loop(func: Callable[..., T], *args: object, size: int) -> T:
    """``func(*args)`` in a worker thread; its result or its exception, as if called here.

    ``size``: the bytes of the text ``func`` works on. Above :data:`SMALL_BYTES`, at most
    :data:`PARSE_THREADS` run at once; smaller work (every real spec) takes the thread pool
    the sync routes share, so that ordinary submissions do not queue behind each other
    (one parse thread for all of them cost a third of the submissions per second in
    ``benchmarks/bench_submit.py``)."""
    limiter = _limiter() if size > SMALL_BYTES else None
    return await anyio.to_thread.run_sync(func, *args, limiter=limiter)
