"""Print the kinds reference of the docs site, generated from the registry.

Run: ``.venv/bin/python scripts/kinds_table.py --write`` to rewrite the part of
``docs/reference/kinds.md`` between the markers ``<!-- kinds:start -->`` and
``<!-- kinds:end -->``, and the typed documents' field tables of ``docs/artifacts.md``
(between ``<!-- fields:MODULE.TYPE -->`` and ``<!-- /fields -->``); without ``--write`` it
prints the kinds table;
``tests/unit/service/test_readme.py`` fails when the page is stale.
"""

from __future__ import annotations

import importlib
import inspect
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from jobapi.documents import document_fields
from jobapi.kinds import Kind
from service import kinds
from service.kind_docs import param_rows


def timing_line(kind: Kind) -> str:
    """What the kind declares as timing artifacts (:attr:`jobapi.kinds.Kind.timing_artifacts`),
    the exception to "same spec, same bytes", or ``""``."""
    rule = kind.timing_artifacts
    if not rule:
        return ""
    head = (
        "Timing artifacts (their bytes vary between runs of a spec; "
        "[Determinism](../concepts.md#determinism)): "
    )
    if callable(rule):
        doc = " ".join((inspect.getdoc(rule) or "they depend on the params").split())
        return head + doc
    return head + ", ".join(f"`{a}`" for a in rule) + "."


def kinds_markdown() -> str:
    """The markdown table of the built-in kinds, their parameters and their typed documents'
    fields (:mod:`jobapi.documents`; an installed plugin's
    kinds are its package's to document: the README stays the same with or without it)."""
    lines = []
    builtin = [k for k in kinds.all_kinds().values() if kinds.plugin_of(k.name) is None]
    for kind in sorted(builtin, key=lambda k: k.name):
        arts = ", ".join(f"`{a}`" for a in kind.artifacts) or "(see below)"
        lines.append(f"### `{kind.name}`\n\n{kind.description}\n\nArtifacts: {arts}\n")
        if timed := timing_line(kind):
            lines.append(timed + "\n")
        if kind.metrics:
            names = ", ".join(f"`{m}`" for m in kind.metrics)
            lines.append(f"Metrics of its result rows ([names](../usage.md#results)): {names}.\n")
        if kind.layout:
            lines.append(kind.layout.strip() + "\n")
        lines.append("| param | type | default | description |")
        lines.append("| --- | --- | --- | --- |")
        for name, type_, default, desc in param_rows(kind, markdown=True):
            cell = desc.replace("|", "\\|")
            lines.append(f"| `{name}` | {type_} | {default} | {cell} |")
        lines.append("")
        for artifact, typed in kind.documents.items():
            lines.append(f"`{artifact}` (`{typed.__module__}.{typed.__qualname__}`):\n")
            lines.extend(fields_table(typed))
            lines.append("")
    return "\n".join(lines).rstrip() + "\n"


def fields_table(typed: type) -> list[str]:
    """The markdown table of a typed document's fields (:func:`document_fields`)."""
    lines = ["| field | type | required | description |", "| --- | --- | --- | --- |"]
    for field, json_type, required, desc in document_fields(typed):
        cell = desc.replace("|", "\\|")
        lines.append(f"| `{field}` | {json_type} | {'yes' if required else 'no'} | {cell} |")
    return lines


#: ``docs/artifacts.md``: each block between ``<!-- fields:MODULE.TYPE -->`` and
#: ``<!-- /fields -->`` is the field table of that typed document.
ARTIFACTS = Path(__file__).resolve().parent.parent / "docs" / "artifacts.md"
FIELDS = re.compile(r"(<!-- fields:([\w.]+) -->\n).*?(<!-- /fields -->)", re.S)


def artifacts_with_fields(text: str) -> str:
    """``text`` (the artifacts page) with every fields block regenerated from its type."""

    def table(m: re.Match[str]) -> str:
        module, _, name = m[2].rpartition(".")
        typed = getattr(importlib.import_module(module), name)
        return m[1] + "\n".join(fields_table(typed)) + "\n" + m[3]

    return FIELDS.sub(table, text)


START, END = "<!-- kinds:start -->", "<!-- kinds:end -->"
PAGE = Path(__file__).resolve().parent.parent / "docs" / "reference" / "kinds.md"


def page_with_table(text: str) -> str:
    """``text`` (the kinds page) with the part between the markers replaced by the table."""
    head, _, rest = text.partition(START)
    _, _, tail = rest.partition(END)
    return f"{head}{START}\n{kinds_markdown()}{END}{tail}"


if __name__ == "__main__":
    if "--write" in sys.argv[1:]:
        PAGE.write_text(page_with_table(PAGE.read_text(encoding="utf-8")), encoding="utf-8")
        text = ARTIFACTS.read_text(encoding="utf-8")
        ARTIFACTS.write_text(artifacts_with_fields(text), encoding="utf-8")
    else:
        sys.stdout.write(kinds_markdown())
