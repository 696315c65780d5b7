"""Decoding users' files in a small pool of bounded child processes, not in the web process.

Decoding a user's file can take far more memory than the file's size (a deflated ``.npz`` of
zeros, a huge EXR). The format readers refuse what their headers already show to be too big
(:mod:`storage.formats`); what remains is decoded here, by :class:`UploadChecker`:

- **A pool of children** (``MATFORGE_UPLOAD_CHECKERS``, default 2), each decoding one file at
  a time, so one slow upload (an archive of 10,000 files) does not hold up the others. A
  call waits at most ``queue_wait`` seconds for a free child, then raises
  :class:`CheckerBusy` (503 with ``Retry-After``).
- **Bounded**: each child's data segment is capped (``RLIMIT_DATA``,
  ``MATFORGE_UPLOAD_CHECK_MB``) and each call is timed (``MATFORGE_UPLOAD_CHECK_SECONDS``).
  Running out of memory there is a :class:`TooLargeError` (413), a crash or a time-out a
  :class:`FormatError` (422); the child is then replaced, and the web process is untouched.
- **Plain child processes** (``python -m service.upload_check``, started with
  :mod:`subprocess`), not ``multiprocessing``: a daemonic process (the extra web processes
  of ``serve --http-workers N``) may not start ``multiprocessing`` children, and the spawn
  context starts a resource tracker that outlived a killed server (issue 21, items 2 and 9).
- **They die with their parent**: each child asks the kernel for SIGKILL when its parent
  dies (``prctl(PR_SET_PDEATHSIG)``). That signal follows the *thread* that forked the child,
  so children are started from one long-lived thread (:class:`_Spawner`), never from a
  request thread that may end. A child also exits when its request pipe closes.

- **A budget per upload** (:meth:`UploadChecker.budget_for`): checking a file may take
  ``MATFORGE_UPLOAD_BUDGET_SECONDS`` (10) plus one second per MiB of it, at most
  ``MATFORGE_UPLOAD_CHECK_SECONDS``, and an archive's members may inflate to
  ``MATFORGE_UPLOAD_INFLATE_RATIO`` (20) times its size plus 16 MiB, summed from its zip
  directory before anything is inflated (:mod:`storage.formats.zip_budget`). A file over
  either is an :class:`OverBudget` (413) naming what was over: a small file cannot hold a
  checker for long, nor fill the temporary disk. A new child imports its readers and says
  it is ready before it takes a call, so its start-up is never counted in a budget.

Any module-level function runs in a child with :meth:`UploadChecker.run`
(``checker.run(fn, *args, label=name)``); :meth:`UploadChecker.validate` is
``run(storage.formats.validate_file, path, name)``.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import functools
import logging
import math
import os
import pickle
import queue
import select
import signal
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from storage.errors import FormatError, TooLargeError

log = logging.getLogger("matforge.uploads")

T = TypeVar("T")

#: Seconds one check may take (default of ``MATFORGE_UPLOAD_CHECK_SECONDS``).
TIMEOUT_SECONDS = 120.0
#: Seconds a new child may take to import its readers and say it is ready (not counted in
#: any call's time budget).
STARTUP_SECONDS = 120.0
#: The first frame a child sends: it has imported its readers.
READY = "ready"
#: Seconds a call waits for a free child before :class:`CheckerBusy`.
QUEUE_WAIT_SECONDS = 10.0
#: Children in the pool (default of ``MATFORGE_UPLOAD_CHECKERS``).
PROCESSES = 2
#: Seconds a check of an upload may take before one second per MiB is added (default of
#: ``MATFORGE_UPLOAD_BUDGET_SECONDS``).
BUDGET_SECONDS = 10.0
#: Times its own size an upload's archive members may inflate to (default of
#: ``MATFORGE_UPLOAD_INFLATE_RATIO``), beside :data:`INFLATE_ALLOWANCE`.
INFLATE_RATIO = 20.0
#: Bytes any archive's members may inflate to beyond the ratio (a small archive of
#: well-compressed members: an angle list, a few images).
INFLATE_ALLOWANCE = 16 << 20
_FRAME = struct.Struct("<Q")
#: Environment variables a child does not get: it decodes hostile files and needs no secrets.
_SECRETS = ("MATFORGE_TOKEN", "RAY_AUTH_TOKEN")
_PR_SET_PDEATHSIG = 1


class CheckerBusy(Exception):
    """Every checker stayed busy for the whole queue wait: answered 503 with
    ``Retry-After: retry_after`` (seconds)."""

    def __init__(self, label: str, retry_after: int) -> None:
        self.label = label
        self.retry_after = retry_after
        super().__init__(
            f"{label}: every file checker is busy with other uploads; try again in {retry_after} s"
        )


class OverBudget(TooLargeError):
    """An upload over its budget (:meth:`UploadChecker.budget_for`): answered 413;
    ``what`` is ``"seconds"`` or ``"inflated bytes"``."""

    def __init__(self, message: str, what: str) -> None:
        self.what = what
        super().__init__(message)

    def __reduce__(self) -> tuple[type[OverBudget], tuple[str, str]]:
        return (type(self), (str(self), self.what))


class CheckFailed(FormatError):
    """The check of a file crashed its child or ran out of time (the file is refused, 422;
    another try may end differently)."""


class _ChildDied(Exception):
    pass


# -- framing: an 8-byte length, then a pickle ---------------------------------------------
def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


def _read_exact(fd: int, n: int, deadline: float | None) -> bytearray | None:
    """``n`` bytes from ``fd``, read in place; ``None`` at end of file; ``TimeoutError``
    past ``deadline`` (``time.monotonic()``; ``None``: wait forever). ``poll``, not
    ``select``: a busy web process has descriptors above ``FD_SETSIZE``."""
    buf = bytearray(n)
    view = memoryview(buf)
    got = 0
    poller = select.poll() if deadline is not None else None
    if poller is not None:
        poller.register(fd, select.POLLIN)
    while got < n:
        if poller is not None and deadline is not None:
            left = deadline - time.monotonic()
            if left <= 0 or not poller.poll(max(1, math.ceil(left * 1000))):
                raise TimeoutError
        k = os.readv(fd, [view[got : got + (1 << 20)]])
        if k == 0:
            return None
        got += k
    return buf


def _send(fd: int, obj: object) -> None:
    body = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    _write_all(fd, _FRAME.pack(len(body)) + body)


def _recv(fd: int, deadline: float | None = None) -> Any:
    head = _read_exact(fd, _FRAME.size, deadline)
    if head is None:
        raise EOFError
    body = _read_exact(fd, _FRAME.unpack(head)[0], deadline)
    if body is None:
        raise EOFError
    return pickle.loads(body)


# -- the child ------------------------------------------------------------------------------
def _die_with_parent(parent: int) -> None:
    """SIGKILL this process when its parent (thread) dies; exit now if it already has."""
    if sys.platform.startswith("linux"):
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) != 0:
            log.warning("prctl(PR_SET_PDEATHSIG) failed: errno %d", ctypes.get_errno())
    if os.getppid() != parent:  # the parent died before prctl took effect
        os._exit(0)


def _limit_memory(max_bytes: int) -> None:
    """Cap this process's data segment (heap and anonymous mappings) before the decoders
    are imported."""
    import resource

    resource.setrlimit(resource.RLIMIT_DATA, (max_bytes, max_bytes))


def _answer(fn: Callable[..., Any], args: tuple[Any, ...], label: str) -> tuple[str, Any, bool]:
    """Run one call: ``(status, value, retire)``; ``retire`` asks for a fresh child next."""
    try:
        return ("ok", fn(*args), False)
    except MemoryError:
        return (
            "err",
            TooLargeError(
                f"{label}: decoding it needs more memory than file checks may use; "
                "send a smaller file"
            ),
            True,
        )
    except Exception as exc:  # sent back and raised in the caller, as if run there
        try:
            pickle.dumps(exc)
        except Exception:
            exc = RuntimeError(f"{type(exc).__name__}: {exc}")
        return ("err", exc, False)


def _preload() -> None:
    """Import what the format readers use (numpy, the readers, onnx) before the first call:
    a call's time budget then measures the check, not the child's start-up, which takes
    seconds on a loaded machine."""
    from storage.formats import onnx as onnx_format  # the readers, numpy with them

    onnx_format.preload()


def child_main(argv: list[str]) -> None:
    """``python -m service.upload_check PARENT_PID MAX_BYTES``: answer calls from stdin on
    the original stdout until stdin closes (stray prints go to stderr)."""
    parent, max_bytes = int(argv[0]), int(argv[1])
    _die_with_parent(parent)
    _limit_memory(max_bytes)
    reply_fd = os.dup(1)
    os.dup2(2, 1)  # a decoder's print must not corrupt the replies
    _preload()
    _send(reply_fd, (READY, None, False))
    while True:
        try:
            fn, args, label = _recv(0)
        except EOFError:
            return
        status, value, retire = _answer(fn, args, label)
        _send(reply_fd, (status, value, retire))
        if retire:
            return


# -- the parent -----------------------------------------------------------------------------
class _Spawner:
    """One long-lived thread that starts the children: their parent-death signal follows the
    thread that forked them, and request threads come and go. :meth:`stop` ends the thread
    (and with it, by that signal, any child it started); the next :meth:`start` starts
    another."""

    _Item = tuple[list[str], dict[str, str], "cf.Future[subprocess.Popen[bytes]]"]

    def __init__(self) -> None:
        self._queue: queue.Queue[_Spawner._Item | None] | None = None
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()

    def start(self, cmd: list[str], env: dict[str, str]) -> subprocess.Popen[bytes]:
        future: cf.Future[subprocess.Popen[bytes]] = cf.Future()
        with self._lock:
            if self._queue is None:
                self._queue = queue.Queue()
                self._thread = threading.Thread(
                    target=self._loop,
                    args=(self._queue,),
                    name="upload-checker-spawner",
                    daemon=True,
                )
                self._thread.start()
            self._queue.put((cmd, env, future))
        return future.result()

    @staticmethod
    def _loop(items: queue.Queue[_Spawner._Item | None]) -> None:
        while (item := items.get()) is not None:
            cmd, env, future = item
            try:
                proc = subprocess.Popen(
                    cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env, bufsize=0
                )
            except BaseException as exc:
                future.set_exception(exc)
            else:
                future.set_result(proc)

    def stop(self) -> None:
        with self._lock:
            items, thread = self._queue, self._thread
            self._queue = self._thread = None
            if items is not None:
                items.put(None)
        if thread is not None:
            thread.join(timeout=5)


class _Child:
    """One checker process and its two pipes."""

    def __init__(self, proc: subprocess.Popen[bytes], generation: int) -> None:
        self.proc = proc
        self.generation = generation
        assert proc.stdin is not None and proc.stdout is not None
        self._in = proc.stdin.fileno()
        self._out = proc.stdout.fileno()

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def wait_ready(self, timeout: float) -> None:
        """Wait for the child's :data:`READY` frame (its readers imported)."""
        try:
            status, _, _ = _recv(self._out, time.monotonic() + timeout)
        except TimeoutError:
            raise
        except (EOFError, OSError) as exc:
            raise _ChildDied from exc
        if status != READY:
            raise _ChildDied

    def call(self, request: bytes, timeout: float) -> tuple[str, Any, bool]:
        deadline = time.monotonic() + timeout
        try:
            _write_all(self._in, request)
            status, value, retire = _recv(self._out, deadline)
            return status, value, retire
        except TimeoutError:  # an OSError too, but the child is alive
            raise
        except (EOFError, OSError) as exc:  # BrokenPipeError: it died before reading
            raise _ChildDied from exc

    def kill(self) -> None:
        with contextlib.suppress(OSError):
            self.proc.kill()
        for pipe in (self.proc.stdin, self.proc.stdout):
            with contextlib.suppress(OSError):
                if pipe is not None:
                    pipe.close()
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.proc.wait(timeout=5)


class UploadChecker:
    """Runs checks in a pool of ``processes`` bounded children (see the module docstring);
    thread-safe. Children start on first use and are replaced after a crash, a time-out or
    running out of memory; :meth:`close` ends them all.

    ``max_bytes``: each child's data segment; ``timeout``: seconds one call may take;
    ``queue_wait``: seconds a call waits for a free child before :class:`CheckerBusy`;
    ``max_archive_pixels``: the most pixels all the images of a BTF archive may decode to,
    summed from their headers (:class:`~storage.formats.TooLargeError` above);
    ``budget_seconds`` and ``inflate_ratio``: an upload's budget (:meth:`budget_for`).
    """

    def __init__(
        self,
        max_bytes: int,
        timeout: float = TIMEOUT_SECONDS,
        *,
        processes: int = PROCESSES,
        queue_wait: float = QUEUE_WAIT_SECONDS,
        max_archive_pixels: int | None = None,
        budget_seconds: float = BUDGET_SECONDS,
        inflate_ratio: float = INFLATE_RATIO,
    ) -> None:
        if processes < 1:
            raise ValueError(f"an upload checker needs at least 1 process, not {processes}")
        self.max_bytes = max_bytes
        self.timeout = timeout
        self.processes = processes
        self.queue_wait = queue_wait
        self.max_archive_pixels = max_archive_pixels
        self.budget_seconds = budget_seconds
        self.inflate_ratio = inflate_ratio
        #: Calls answered by a child (for statistics and tests).
        self.calls = 0
        self._free = threading.BoundedSemaphore(processes)
        self._idle: list[_Child] = []
        self._busy: set[_Child] = set()
        self._lock = threading.Lock()
        self._spawner = _Spawner()
        self._generation = 0  # children of an older one (before a close) are not reused

    # -- the pool ---------------------------------------------------------------------------
    def child_pids(self) -> list[int]:
        """Pids of the live children, idle or busy."""
        with self._lock:
            return sorted(c.pid for c in (*self._idle, *self._busy) if c.alive())

    @property
    def in_flight(self) -> int:
        """Calls running in a child now."""
        with self._lock:
            return len(self._busy)

    def _start_child(self) -> _Child:
        cmd = [sys.executable, "-m", "service.upload_check", str(os.getpid()), str(self.max_bytes)]
        env = {k: v for k, v in os.environ.items() if k not in _SECRETS}
        for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            env[var] = "1"
        with self._lock:
            generation = self._generation
        child = _Child(self._spawner.start(cmd, env), generation)
        try:
            child.wait_ready(STARTUP_SECONDS)
        except (TimeoutError, _ChildDied):
            child.kill()
            raise CheckFailed(
                "upload checker", f"a checker process did not start within {STARTUP_SECONDS:g} s"
            ) from None
        log.info("started upload checker pid %d", child.pid)
        return child

    def _take(self, label: str) -> _Child:
        if not self._free.acquire(timeout=self.queue_wait):
            raise CheckerBusy(label, max(1, math.ceil(self.queue_wait)))
        try:
            with self._lock:
                child = self._idle.pop() if self._idle else None
            if child is not None and not child.alive():
                child.kill()
                child = None
            if child is None:
                child = self._start_child()
            with self._lock:
                self._busy.add(child)
            return child
        except BaseException:
            self._free.release()
            raise

    def _give_back(self, child: _Child, keep: bool) -> None:
        with self._lock:
            self._busy.discard(child)
            keep = keep and child.generation == self._generation
            if keep:
                self._idle.append(child)
        if not keep:
            child.kill()
        self._free.release()

    # -- calls ------------------------------------------------------------------------------
    def budget_for(self, size: int) -> tuple[float, int]:
        """The budget of checking an upload of ``size`` bytes: ``(seconds, inflated
        bytes)``. Seconds: ``budget_seconds`` plus one per MiB, at most the checker's
        ``timeout``; inflated bytes: ``inflate_ratio`` times ``size`` plus
        :data:`INFLATE_ALLOWANCE`."""
        seconds = min(self.timeout, self.budget_seconds + size / (1 << 20))
        return seconds, int(self.inflate_ratio * size) + INFLATE_ALLOWANCE

    def run(
        self,
        fn: Callable[..., T],
        *args: Any,
        label: str,
        timeout: float | None = None,
        over_time: str | None = None,
    ) -> T:
        """``fn(*args)`` in a child; its exceptions are raised here. ``fn`` must be a
        module-level function, and ``args`` and the result picklable. ``label`` (the user's
        file name) starts the messages of the errors raised here: :class:`CheckerBusy`,
        :class:`TooLargeError` (out of memory) and :class:`CheckFailed` (crash, time-out).
        ``timeout``: seconds this call may take (default: the checker's); with
        ``over_time`` (what the time limit is made of), running past it is an
        :class:`OverBudget` instead of a :class:`CheckFailed`."""
        limit = self.timeout if timeout is None else timeout
        request = pickle.dumps((fn, args, label), protocol=pickle.HIGHEST_PROTOCOL)
        request = _FRAME.pack(len(request)) + request
        child = self._take(label)
        keep = False
        try:
            status, value, retire = child.call(request, limit)
            keep = not retire
        except _ChildDied:
            log.warning("checking %s killed its checker process (pid %d)", label, child.pid)
            raise CheckFailed(
                label, "checking it crashed the checker (out of memory, or a corrupt file)"
            ) from None
        except TimeoutError:
            log.warning("checking %s took longer than %g s; killed pid %d", label, limit, child.pid)
            if over_time is not None:
                raise OverBudget(
                    f"{label}: over its time budget: checking it took longer than {limit:.3g} s "
                    f"({over_time}); send a smaller or simpler file",
                    "seconds",
                ) from None
            raise CheckFailed(label, f"checking it took longer than {limit:g} s") from None
        finally:
            self._give_back(child, keep)
        with self._lock:
            self.calls += 1
        if status == "ok":
            return value
        raise value

    def validate(self, path: Path, name: str) -> str:
        """The media type of the file at ``path`` (``storage.formats.validate_file``, in a
        child, within the file's budget: :meth:`budget_for`); ``name`` is the user's file
        name."""
        from storage.formats import validate_file

        size = Path(path).stat().st_size
        seconds, inflated = self.budget_for(size)
        check = functools.partial(
            validate_file,
            max_archive_pixels=self.max_archive_pixels,
            max_inflated_bytes=inflated,
            inflate_budget=(
                f"{self.inflate_ratio:g} times the upload's size plus {INFLATE_ALLOWANCE >> 20} "
                "MiB, MATFORGE_UPLOAD_INFLATE_RATIO"
            ),
        )
        over_time = (
            f"{self.budget_seconds:g} s plus 1 s per MiB uploaded, at most {self.timeout:g} s; "
            "MATFORGE_UPLOAD_BUDGET_SECONDS, MATFORGE_UPLOAD_CHECK_SECONDS"
        )
        return self.run(check, Path(path), name, label=name, timeout=seconds, over_time=over_time)

    def close(self) -> None:
        """End every child (a call in flight gets a :class:`CheckFailed`); a later call
        starts new ones."""
        with self._lock:
            self._generation += 1
            children = [*self._idle, *self._busy]
            self._idle.clear()
        for child in children:
            child.kill()
        self._spawner.stop()


if __name__ == "__main__":
    child_main(sys.argv[1:])
