"""What the CLI says when the server returns an existing job for a resubmitted spec.

A spec's identity is its canonical kind, seed and params: the ``name`` is a label and not
part of it. So a resubmitted spec, even with a new name, gets the job that already ran
(or is queued or running), and the user is told so on stderr, with how to run it again.
"""

from __future__ import annotations

from typing import Any


def reuse_notices(raw: Any, doc: dict[str, Any], created: bool) -> list[str]:
    """The lines to print on stderr for a submission (none for a new job).

    ``raw`` is the spec as the user wrote it, ``doc`` the job document the server returned
    and ``created`` whether it queued a new job.
    """
    if created:
        return []
    job_id = str(doc.get("id"))
    state = doc.get("state")
    same = "same spec" if state == "succeeded" else f"same spec, {state}"
    lines = [f"reusing job {job_id} ({same}); add `force: true` to run again"]
    wanted = raw.get("name") if isinstance(raw, dict) else None
    if wanted is not None and wanted != doc.get("name"):
        kept = doc.get("name")
        kept_text = f"keeps its name {kept!r}" if kept is not None else "keeps having no name"
        lines.append(
            f"the name {wanted!r} is ignored: the name is not part of a spec's identity, and "
            f"job {job_id} {kept_text}"
        )
    return lines
