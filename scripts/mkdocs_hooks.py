"""mkdocs hooks: pages generated at build time (``mkdocs.yml``'s ``hooks``).

``reference/rest.md`` (every route of the REST API, from the OpenAPI document) and
``reference/openapi.json`` (the document itself, every kind's params included) are made
from the application each time the site is built, so they cannot go stale. The kinds and
CLI references are committed pages kept current by tests (``scripts/kinds_table.py``,
``scripts/cli_reference.py``).
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path
from typing import Any

from mkdocs.structure.files import File, Files

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

_METHODS = ("get", "post", "put", "patch", "delete")


def openapi_document() -> dict[str, Any]:
    """The OpenAPI document of ``matforge serve``, built over an empty temporary store."""
    with tempfile.TemporaryDirectory(prefix="matforge-docs-") as tmp:
        os.environ["MATFORGE_DATA"] = tmp
        from service.api import create_app

        return create_app().openapi()


def rest_markdown(doc: dict[str, Any]) -> str:
    """The REST reference page: one row per route and method, from ``doc``."""
    lines = [
        "# REST reference",
        "",
        f"matforge {doc['info']['version']}. Generated at build time from the OpenAPI "
        "document of the running application; the document itself is "
        "[openapi.json](openapi.json), and a running server serves it at `/openapi.json` "
        "with a Swagger UI at `/docs`. The routes in use, with their answers, are described "
        "in [Using matforge](../usage.md#rest).",
        "",
        "| method | path | summary |",
        "| --- | --- | --- |",
    ]
    for path in sorted(doc["paths"]):
        for method in _METHODS:
            op = doc["paths"][path].get(method)
            if op is None:
                continue
            summary = " ".join((op.get("summary") or "").split()).replace("|", "\\|")
            lines.append(f"| `{method.upper()}` | `{path}` | {summary} |")
    return "\n".join(lines) + "\n"


def on_files(files: Files, config: Any) -> Files:
    doc = openapi_document()
    text = json.dumps(doc, indent=1, sort_keys=True)
    files.append(File.generated(config, "reference/openapi.json", content=text))
    files.append(File.generated(config, "reference/rest.md", content=rest_markdown(doc)))
    return files
