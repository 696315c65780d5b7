"""What every dataset reader shares: its source job."""

from __future__ import annotations

from matforge.datasets.source import Source


class DatasetReader:
    """A reader of one finished dataset job.

    Attributes
    ----------
    source
        Where the artifacts come from (:class:`~matforge.datasets.source.Source`).
    job_id, kind, spec
        The job's id, kind and validated spec.
    """

    #: The job kinds this reader opens.
    KINDS: tuple[str, ...] = ()

    def __init__(self, source: Source) -> None:
        if source.kind not in self.KINDS:
            raise ValueError(
                f"job {source.job_id} is a {source.kind} job; {type(self).__name__} reads "
                f"{', '.join(self.KINDS)}"
            )
        self.source = source
        self.job_id = source.job_id
        self.kind = source.kind
        self.spec = source.spec

    @property
    def ref(self) -> str:
        """``job:<id>``."""
        return self.source.ref

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.ref} ({self.kind})>"
