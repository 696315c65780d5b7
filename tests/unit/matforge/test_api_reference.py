"""``docs/api-reference.md`` is generated from the docstrings of ``matforge`` and current."""

from __future__ import annotations

import importlib.util
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]


def test01_api_reference_is_current() -> None:
    spec = importlib.util.spec_from_file_location(
        "api_reference", REPO / "scripts/api_reference.py"
    )
    assert spec and spec.loader
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    text = mod.page()
    for name in ("matforge.Client", "matforge.run", "matforge.datasets.open",
                 "matforge.datasets.BtfSlices", "torch_dataset", "SpecError"):  # fmt: skip
        assert name in text, name
    assert (REPO / "docs/api-reference.md").read_text(encoding="utf-8") == text, (
        "docs/api-reference.md is stale: run `.venv/bin/python scripts/api_reference.py --write`"
    )
