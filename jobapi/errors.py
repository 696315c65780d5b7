"""Error types of the service layer.

The edges map them: ``SpecError`` is a 422 in REST and exit 2 in the CLI; ``JobFailed`` is
a failed job with its message as the one-line ``error``; ``JobCancelled`` stops a runner.
"""

from __future__ import annotations

from storage.errors import FormatError, IntegrityError, NotFoundError, StorageError, TooLargeError

__all__ = [
    "FormatError",
    "IntegrityError",
    "JobCancelled",
    "JobFailed",
    "LeaseLost",
    "NotFoundError",
    "SpecError",
    "StorageError",
    "TooLargeError",
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
