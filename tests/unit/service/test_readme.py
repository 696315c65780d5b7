"""The kinds reference of the docs site is generated from the registry and must be current;
the README keeps its two commands."""

from __future__ import annotations

import importlib.util
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]


def test01_kinds_reference_is_current() -> None:
    spec = importlib.util.spec_from_file_location("kinds_table", REPO / "scripts/kinds_table.py")
    assert spec and spec.loader
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    text = (REPO / "docs/reference/kinds.md").read_text(encoding="utf-8")
    assert mod.START in text and mod.END in text
    assert text == mod.page_with_table(text), (
        "docs/reference/kinds.md is stale: run `.venv/bin/python scripts/kinds_table.py --write`"
    )


def test02_readme_shows_the_two_commands() -> None:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    assert "make demo" in text and "make test" in text
