"""Error types raised by the storage layer. The edges (REST, CLI, job records) map them."""

from __future__ import annotations


class StorageError(Exception):
    """Base class for storage errors; ``str(err)`` is one line a user can act on."""


class FormatError(StorageError):
    """A file is malformed. The message names the file and what is wrong with it."""

    def __init__(self, filename: str, problem: str) -> None:
        self.filename = filename
        self.problem = problem
        super().__init__(f"{filename}: {problem}")

    def __reduce__(self) -> tuple[type[FormatError], tuple[str, str]]:
        # Crosses process boundaries (uploads are validated in a child process).
        return (type(self), (self.filename, self.problem))


class IntegrityError(StorageError):
    """An object's bytes do not hash to its digest (corruption on disk)."""


class NotFoundError(StorageError):
    """A job, artifact or object does not exist."""


class TooLargeError(StorageError):
    """An upload exceeds the configured size cap."""


class AmbiguousIdError(StorageError):
    """A short job id (a prefix) matches more than one job; ``matches`` lists some."""

    def __init__(self, prefix: str, matches: list[str]) -> None:
        self.prefix = prefix
        self.matches = matches
        shown = ", ".join(m[:12] for m in matches[:5])
        more = " ..." if len(matches) > 5 else ""
        super().__init__(
            f"job id prefix {prefix!r} is ambiguous: it matches {shown}{more}; give more digits"
        )
