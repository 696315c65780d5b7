"""Error types of the service layer.

The edges map them: ``SpecError`` is a 422 in REST and exit 2 in the CLI; ``JobFailed`` is
a failed job with its message as the one-line ``error``; ``JobCancelled`` stops a runner.
"""

from __future__ import annotations

from storage.errors import FormatError, IntegrityError, NotFoundError, StorageError, TooLargeError

__all__ = [
    "BackendUnavailable",
    "ExecutorUnavailable",
    "FormatError",
    "IntegrityError",
    "JobCancelled",
    "JobFailed",
    "LeaseLost",
    "NotFoundError",
    "ShardLost",
    "SpecError",
    "StorageError",
    "TooLargeError",
    "TRANSIENT_ERRORS",
    "TransientError",
]


class SpecError(ValueError):
    """A job spec is invalid. ``errors`` lists ``(field path, message)`` pairs."""

    def __init__(self, errors: list[tuple[str, str]]) -> None:
        self.errors = errors
        super().__init__("; ".join(f"{loc}: {msg}" if loc else msg for loc, msg in errors))


class JobFailed(Exception):
    """Raised by a runner: the job fails with ``str(exc)`` as its one-line error."""


class JobCancelled(Exception):
    """Raised inside a runner when its job was cancelled (or its lease was taken)."""


class LeaseLost(JobCancelled):
    """The worker no longer holds the job's lease; its results must not be written."""


class TransientError(Exception):
    """Raised by a shard function for a failure worth retrying as it is (a flaky mount, a
    dropped connection). Executors that retry (Ray) run such a shard again; a deterministic
    error (``ValueError``, ``FormatError``...) fails the job at once instead."""


#: The application errors of a shard that a retrying executor retries: nothing about the
#: shard's inputs is wrong, so the same call may succeed on a second try or another node.
TRANSIENT_ERRORS: tuple[type[BaseException], ...] = (
    TransientError,
    ConnectionError,
    TimeoutError,
    MemoryError,
)


class ShardLost(JobFailed):
    """The executor could not finish a shard after its retries (its node kept dying)."""


class ExecutorUnavailable(RuntimeError):
    """An executor's backend cannot be started or reached (no Ray cluster at the address).
    Raised before a job is claimed, so the job stays queued."""


class BackendUnavailable(RuntimeError):
    """The Mitsuba variant the settings ask for (``MATFORGE_VARIANT``) cannot run on this
    machine (``cuda_ad_rgb`` without a CUDA driver and device, ``llvm_ad_rgb`` without a
    working libLLVM). Raised at start-up, before a job is claimed; the message names the
    setting."""
