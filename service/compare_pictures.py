"""The pictures of a job by *role*, for the compare view (issue 26, section 2).

The compare view used to pair pictures by file name, so two score jobs with different
candidate labels had nothing in common (``no flip_gold16.png``) and a batch of different
kinds was mostly placeholders. Each picture now carries a role, derived here once from the
job's spec and artifacts rather than guessed in the page from names:

============  ================================================================  =========
role          what                                                              label
============  ================================================================  =========
reference     the picture ``params.reference`` refers to (a score's reference)  reference
candidate     each picture ``params.candidates`` refers to                      its label
error         each ``flip_<label>.png`` artifact (a FLIP map, magma)            <label>
lead          the kind's lead picture (:attr:`jobapi.kinds.Figure.lead`)        its name
image         any other picture artifact                                        its name
============  ================================================================  =========

A job's *main* pictures are its reference and candidates when it has candidates (a score
job's candidates become panels side by side), else its lead picture, else its first
picture: every job with a picture shows something in the main view.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

from jobapi.params import JOB_REF, SHA_REF
from service.routes.dashboard import EXR_TYPE, IMAGE_TYPES, picture_views
from storage.errors import NotFoundError
from storage.jobs import ArtifactRecord, Job, JobStore

#: The view of every job's main pictures; ``errors`` and ``diff`` are the other role views.
MAIN, ERRORS, DIFF = "main", "errors", "diff"
#: Artifact names shown first among the by-name views when several are common.
PREFERRED = ("image.exr", "preview.png")


def _is_exr(record: ArtifactRecord) -> bool:
    return record.media_type == EXR_TYPE or record.name.endswith(".exr")


def _picture(record: ArtifactRecord, role: str, label: str, src: str) -> dict[str, Any]:
    hdr = _is_exr(record)
    values = "linear" if hdr else "magma" if role == "error" else "srgb"
    return {
        "key": f"{role}:{label}",
        "role": role,
        "label": label,
        "name": record.name,
        "src": src,
        "hdr": hdr,
        "digest": record.digest,
        "pixels": f"/api/artifacts/{record.digest}/pixels?values={values}",
        "values": values,
    }


def _input(value: Any, jobs: JobStore) -> ArtifactRecord | None:
    """The picture record a ``job:<id>/<name>`` or ``sha256:`` ref names, or None."""
    if isinstance(value, dict):  # {"model": REF, "material": NAME}: not a picture
        return None
    if not isinstance(value, str):
        return None
    record: ArtifactRecord | None
    try:
        if (m := JOB_REF.match(value)) is not None:
            record = jobs.artifact(m["job"], m["name"])
        elif (s := SHA_REF.match(value)) is not None:
            record = jobs.find_digest(s["digest"])
        else:
            return None
    except NotFoundError:
        return None
    if record is None or not (record.media_type in IMAGE_TYPES or _is_exr(record)):
        return None
    return record


def _src(record: ArtifactRecord) -> str:
    if _is_exr(record):
        return f"/api/artifacts/{record.digest}/preview.png"
    return f"/api/artifacts/{record.digest}"


def job_pictures(job: Job, jobs: JobStore) -> dict[str, Any]:
    """``{"pictures": [...], "main": [keys]}``: the job's pictures with their roles (see
    the module docstring) and the keys of its main pictures."""
    params = job.spec.get("params") or {}
    pictures: list[dict[str, Any]] = []
    reference = _input(params.get("reference"), jobs)
    if reference is not None:
        pictures.append(_picture(reference, "reference", "reference", _src(reference)))
    candidates = params.get("candidates")
    labels: list[str] = []
    if isinstance(candidates, dict):
        for label, value in candidates.items():
            record = _input(value, jobs)
            if record is not None:
                pictures.append(_picture(record, "candidate", str(label), _src(record)))
                labels.append(str(label))
    by_name = {a.name: a for a in job.artifacts}
    for view in picture_views(job.artifacts, job.kind):
        record = by_name[view["name"]]
        stem = Path(record.name).name
        if view["group"] == "flip" and stem.endswith(".png"):
            label = stem.removeprefix("flip_").removesuffix(".png")
            pictures.append(_picture(record, "error", label, view["src"]))
        else:
            role = "lead" if view["group"] == "lead" else "image"
            pictures.append(_picture(record, role, record.name, view["src"]))
    if labels:
        main = [p["key"] for p in pictures if p["role"] in ("reference", "candidate")]
    else:
        lead = [p for p in pictures if p["role"] == "lead"] or [
            p for p in pictures if p["role"] == "image"
        ]
        main = [(lead or pictures)[0]["key"]] if pictures else []
    return {"pictures": pictures, "main": main}


def compare_views(panels: list[dict[str, Any]]) -> list[dict[str, str]]:
    """The page's picture choices: the main pictures, the error maps and the difference to
    the reference where some job has them, then each other picture name, those most jobs
    have first (the preferred ones first among equals). ``{"key", "title"}`` each; a name's
    key is the artifact name (role keys have no dot; artifact names do)."""
    roles = Counter(p["role"] for panel in panels for p in panel["pictures"])
    views = [{"key": MAIN, "title": "main pictures (each job's lead, or its candidates)"}]
    if roles["error"]:
        views.append({"key": ERRORS, "title": "error maps (FLIP)"})
    if roles["candidate"] and roles["reference"]:
        views.append({"key": DIFF, "title": "difference: candidate − reference"})
    counts = Counter(
        p["name"] for panel in panels for p in panel["pictures"] if p["role"] in ("lead", "image")
    )

    def key(name: str) -> tuple[int, int, str]:
        rank = PREFERRED.index(name) if name in PREFERRED else len(PREFERRED)
        return (-counts[name], rank, name)

    views += [{"key": name, "title": name} for name in sorted(counts, key=key)]
    return views
