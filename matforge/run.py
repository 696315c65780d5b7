"""``matforge.run``: one job in this process, no server (``matforge run``)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from matforge.client import JobFailed, SpecError, load_spec


def run(
    spec: Any, data_dir: str | os.PathLike[str] | None = None, *, check: bool = True
) -> dict[str, Any]:
    """Validate ``spec`` (a dict, or the path of a JSON/YAML file), queue it in the local
    store of ``data_dir`` (default ``MATFORGE_DATA`` or ``./matforge-data``) and run it
    here, now; returns the job document, as ``GET /api/jobs/{id}`` would.

    An identical spec that already succeeded is returned as it is (unless ``"force":
    true``). Raises :class:`matforge.SpecError` (``errors`` lists ``(field, message)``,
    as from a server) for a bad spec, and with ``check`` (default) :class:`JobFailed` for a job
    that failed. Read its dataset with ``matforge.datasets.open(doc["id"],
    data_dir=data_dir)``.
    """
    from jobapi.errors import SpecError as LocalSpecError
    from service.settings import Settings
    from service.submission import run_in_process

    settings = Settings.from_env()
    if data_dir is not None:
        settings = settings.with_(data_dir=Path(data_dir))
    (settings.data_dir / "scratch").mkdir(parents=True, exist_ok=True)
    try:
        doc = run_in_process(load_spec(spec), settings).document()
    except LocalSpecError as exc:
        detail = [{"loc": loc.split("."), "msg": msg} for loc, msg in exc.errors]
        raise SpecError(str(exc), list(exc.errors), detail) from None
    if check and doc.get("state") != "succeeded":
        raise JobFailed(doc)
    return doc
