"""Validating uploads in a bounded child process, not in the web process.

Decoding a user's file can take far more memory than the file's size (a deflated ``.npz`` of
zeros, a huge EXR). The format readers refuse what their headers already show to be too big
(:mod:`storage.formats`); what remains is decoded here, in one child process whose data
segment is capped (``RLIMIT_DATA``, ``MATFORGE_UPLOAD_CHECK_MB``) and whose run is timed.
Running out of memory there is a :class:`TooLargeError` (413), a crash or a time-out a
:class:`FormatError` (422); either way the web process is untouched, and the next upload gets
a fresh child.
"""

from __future__ import annotations

import concurrent.futures as cf
import logging
import multiprocessing
import os
import threading
from pathlib import Path

from storage.errors import FormatError, TooLargeError

log = logging.getLogger("matforge.uploads")

#: Seconds a validation may take.
TIMEOUT_SECONDS = 120.0


def _limit_memory(max_bytes: int) -> None:
    """Pool initializer: cap this process's data segment (heap and anonymous mappings) and
    keep numeric libraries to one thread, before they are imported."""
    import resource

    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"
    resource.setrlimit(resource.RLIMIT_DATA, (max_bytes, max_bytes))


def _validate(path: str, name: str, max_archive_pixels: int | None = None) -> str:
    """Runs in the child: the media type, or the exception the format raised (an archive
    whose images' headers add up to more than ``max_archive_pixels``: TooLargeError)."""
    from storage.formats import validate_file

    try:
        return validate_file(Path(path), name, max_archive_pixels=max_archive_pixels)
    except MemoryError:
        raise TooLargeError(
            f"{name}: decoding it needs more memory than uploads may use; send a smaller file"
        ) from None


class UploadChecker:
    """``validate(path, name) -> media type`` in a bounded child process (see the module
    docstring); thread-safe; :meth:`close` ends the child."""

    def __init__(
        self,
        max_bytes: int,
        timeout: float = TIMEOUT_SECONDS,
        max_archive_pixels: int | None = None,
    ) -> None:
        self.max_bytes = max_bytes
        self.timeout = timeout
        self.max_archive_pixels = max_archive_pixels
        self._pool: cf.ProcessPoolExecutor | None = None
        self._lock = threading.Lock()

    def _get_pool(self) -> cf.ProcessPoolExecutor:
        with self._lock:
            if self._pool is None:
                self._pool = cf.ProcessPoolExecutor(
                    max_workers=1,
                    mp_context=multiprocessing.get_context("spawn"),
                    initializer=_limit_memory,
                    initargs=(self.max_bytes,),
                )
            return self._pool

    def _reset(self, pool: cf.ProcessPoolExecutor) -> None:
        with self._lock:
            if self._pool is pool:
                self._pool = None
        for proc in list(getattr(pool, "_processes", {}).values()):
            proc.kill()
        pool.shutdown(wait=False, cancel_futures=True)

    def validate(self, path: Path, name: str) -> str:
        pool = self._get_pool()
        future = pool.submit(_validate, str(path), name, self.max_archive_pixels)
        try:
            return future.result(timeout=self.timeout)
        except cf.process.BrokenProcessPool:
            self._reset(pool)
            log.warning("validating upload %s killed its checker process", name)
            raise FormatError(
                name, "validating it crashed the checker (out of memory, or a corrupt file)"
            ) from None
        except cf.TimeoutError:
            self._reset(pool)
            raise FormatError(name, f"validating it took longer than {self.timeout:g} s") from None

    def close(self) -> None:
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
