"""Print the kinds reference of the docs site, generated from the registry.

Run: ``.venv/bin/python scripts/kinds_table.py --write`` to rewrite the part of
``docs/reference/kinds.md`` between the markers ``<!-- kinds:start -->`` and
``<!-- kinds:end -->`` (without ``--write`` it prints the table);
``tests/unit/service/test_readme.py`` fails when the page is stale.
"""

from __future__ import annotations

import inspect
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
            lines.append("| field | type | required | description |")
            lines.append("| --- | --- | --- | --- |")
            for field, json_type, required, desc in document_fields(typed):
                cell = desc.replace("|", "\\|")
                lines.append(
                    f"| `{field}` | {json_type} | {'yes' if required else 'no'} | {cell} |"
                )
            lines.append("")
    return "\n".join(lines).rstrip() + "\n"


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
    else:
        sys.stdout.write(kinds_markdown())
