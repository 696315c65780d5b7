"""Write ``docs/api-reference.md``, the reference of the public Python API, from docstrings.

Run: ``.venv/bin/python scripts/api_reference.py --write`` (without ``--write`` it prints
the page); ``tests/unit/matforge/test_api_reference.py`` fails when the page is stale.
Documented: every name in ``matforge.__all__``, ``matforge.datasets.__all__``,
``matforge.export.__all__`` and ``matforge.export_onnx.__all__``; for a
class, its public methods and properties defined in matforge (or, for the errors, in the
REST client's module), and for a typed object (a pydantic model) its fields.
"""

from __future__ import annotations

import inspect
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import matforge
import matforge.datasets

PAGE = Path(__file__).resolve().parent.parent / "docs" / "api-reference.md"
#: Modules whose members are documented (a class's inherited members from elsewhere, such
#: as ``Exception``'s or ``object``'s, are not).
OURS = ("matforge", "service.cli.client")


def _doc(obj: Any) -> str:
    return inspect.cleandoc(obj.__doc__ or "").strip()


def _signature(obj: Any) -> str:
    try:
        return str(inspect.signature(obj))
    except (TypeError, ValueError):
        return ""


def _annotation(tp: Any) -> str:
    """A field's type as written, without module prefixes."""
    text = tp.__name__ if isinstance(tp, type) else str(tp)
    for prefix in ("typing.", "matforge.objects.", "service.schemas."):
        text = text.replace(prefix, "")
    return text


def _members(cls: type) -> list[tuple[str, Any]]:
    out = []
    for name in sorted(dir(cls)):
        if name.startswith("_") or name.startswith("model_"):  # pydantic's own
            continue
        attr = inspect.getattr_static(cls, name)
        owner = next((k for k in cls.__mro__ if name in vars(k)), None)
        if owner is None or not owner.__module__.startswith(OURS):
            continue
        if isinstance(attr, property | staticmethod | classmethod) or inspect.isfunction(attr):
            out.append((name, attr))
    return out


def _entry(qual: str, obj: Any, level: str = "###") -> list[str]:
    lines = []
    if inspect.isclass(obj):
        typed = isinstance(getattr(obj, "model_fields", None), dict)  # built by ``.of(raw)``
        lines.append(f"{level} `{qual}{'' if typed else _signature(obj)}`\n")
        if _doc(obj):
            lines.append(_doc(obj) + "\n")
        fields = getattr(obj, "model_fields", None)
        if isinstance(fields, dict) and fields:
            lines.append("Fields:\n")
            for fname, info in fields.items():
                kind = _annotation(info.annotation)
                text = f": {info.description}" if info.description else ""
                lines.append(f"- `{fname}` ({kind}){text}")
            lines.append("")
        for name, attr in _members(obj):
            if isinstance(attr, property):
                lines.append(
                    f"- **`{name}`** (property): {_doc(attr).splitlines()[0] if _doc(attr) else ''}"
                )
                continue
            fn = attr.__func__ if isinstance(attr, staticmethod | classmethod) else attr
            doc = _doc(fn).replace("\n", "\n  ")
            lines.append(f"- **`{name}{_signature(fn)}`**" + (f"\n\n  {doc}\n" if doc else ""))
        lines.append("")
    elif callable(obj):
        lines.append(f"{level} `{qual}{_signature(obj)}`\n")
        lines.append(_doc(obj) + "\n")
    return lines


def page() -> str:
    """The markdown page."""
    lines = [
        "# `matforge` API reference",
        "",
        "Generated from the docstrings by `scripts/api_reference.py --write`; do not edit by",
        "hand. The guide is [python-api.md](python-api.md).",
        "",
        "`matforge.__version__`: the one version (`jobapi/version.py`), "
        f"now `{matforge.__version__}`.",
        "",
        "## `matforge`",
        "",
        _doc(matforge),
        "",
    ]
    modules = ("__version__", "datasets", "export", "export_onnx")
    for name in sorted(n for n in matforge.__all__ if n not in modules):
        lines += _entry(f"matforge.{name}", getattr(matforge, name))
    lines += ["## `matforge.datasets`", "", _doc(matforge.datasets), ""]
    for name in sorted(n for n in matforge.datasets.__all__ if n != "READERS"):
        lines += _entry(f"matforge.datasets.{name}", getattr(matforge.datasets, name))
    for mod in (matforge.export, matforge.export_onnx):
        lines += [f"## `{mod.__name__}`", "", _doc(mod), ""]
        for name in sorted(mod.__all__):
            lines += _entry(f"{mod.__name__}.{name}", getattr(mod, name))
    return "\n".join(lines).rstrip() + "\n"


if __name__ == "__main__":
    if "--write" in sys.argv[1:]:
        PAGE.write_text(page(), encoding="utf-8")
        print(f"wrote {PAGE}")
    else:
        sys.stdout.write(page())
