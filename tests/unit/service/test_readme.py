"""The README's table of job kinds is generated from the registry and must be current."""

from __future__ import annotations

import importlib.util
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]


def test01_readme_kinds_table_is_current() -> None:
    spec = importlib.util.spec_from_file_location("kinds_table", REPO / "scripts/kinds_table.py")
    assert spec and spec.loader
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    text = (REPO / "README.md").read_text(encoding="utf-8")
    assert mod.START in text and mod.END in text
    assert text == mod.readme_with_table(text), (
        "README.md's table of job kinds is stale: run "
        "`.venv/bin/python scripts/kinds_table.py --write`"
    )


def test02_readme_shows_the_two_commands() -> None:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    assert "make demo" in text and "make test" in text
