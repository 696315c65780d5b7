"""A job monitor that kills the job's thread mid-job, for the tests of resumed jobs."""

from __future__ import annotations

from jobapi.context import NullMonitor


class CrashAfter(NullMonitor):
    """A monitor whose ``n``-th progress report raises ``error`` (the first report of a map
    is its start, then one after each recorded shard): the job's thread dies there, as a
    killed worker's would, from the store's view."""

    def __init__(self, n: int, error: type[BaseException]) -> None:
        super().__init__()
        self.n = n
        self.error = error

    def report(self, progress: float, message: str | None) -> None:
        self.n -= 1
        if self.n == 0:
            raise self.error
