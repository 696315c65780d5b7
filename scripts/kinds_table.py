"""Print the README's table of job kinds, generated from the registry.

Run: ``.venv/bin/python scripts/kinds_table.py --write`` to rewrite the part of README.md
between the markers ``<!-- kinds:start -->`` and ``<!-- kinds:end -->`` (without
``--write`` it prints the table); ``tests/unit/service/test_readme.py`` fails when the
README's table is stale.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from service import kinds


def _type(prop: dict) -> str:
    if "enum" in prop:
        return " \\| ".join(f"`{v}`" for v in prop["enum"])
    if "const" in prop:
        return f"`{prop['const']}`"
    if "anyOf" in prop:
        return " or ".join(_type(p) for p in prop["anyOf"])
    if "$ref" in prop:
        return prop["$ref"].rsplit("/", 1)[-1]
    t = prop.get("type", "object")
    if t == "array":
        return "array"
    return str(t)


def kinds_markdown() -> str:
    """The markdown table of kinds and their parameters."""
    lines = []
    for kind in sorted(kinds.all_kinds().values(), key=lambda k: k.name):
        schema = kind.params.model_json_schema()
        arts = ", ".join(f"`{a}`" for a in kind.artifacts) or "(see below)"
        lines.append(f"### `{kind.name}`\n\n{kind.description}\n\nArtifacts: {arts}\n")
        if kind.layout:
            lines.append(kind.layout.strip() + "\n")
        lines.append("| param | type | default | description |")
        lines.append("| --- | --- | --- | --- |")
        required = set(schema.get("required", []))
        for name, prop in schema.get("properties", {}).items():
            default = "required" if name in required else f"`{prop.get('default')!r}`"
            desc = " ".join(str(prop.get("description", "")).split()).replace("|", "\\|")
            lines.append(f"| `{name}` | {_type(prop)} | {default} | {desc} |")
        lines.append("")
    return "\n".join(lines).rstrip() + "\n"


START, END = "<!-- kinds:start -->", "<!-- kinds:end -->"
README = Path(__file__).resolve().parent.parent / "README.md"


def readme_with_table(text: str) -> str:
    """``text`` (the README) with the part between the markers replaced by the table."""
    head, _, rest = text.partition(START)
    _, _, tail = rest.partition(END)
    return f"{head}{START}\n{kinds_markdown()}{END}{tail}"


if __name__ == "__main__":
    if "--write" in sys.argv[1:]:
        README.write_text(readme_with_table(README.read_text(encoding="utf-8")), encoding="utf-8")
    else:
        sys.stdout.write(kinds_markdown())
