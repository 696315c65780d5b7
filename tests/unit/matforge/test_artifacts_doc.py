"""``docs/artifacts.md`` keeps up with the dataset kinds: every artifact pattern a dataset
kind declares is documented there, and every dataset kind has a reader."""

from __future__ import annotations

from pathlib import Path

from jobapi.kinds import registered
from matforge.datasets import READERS
from service import kinds

DOC = Path(__file__).resolve().parents[3] / "docs" / "artifacts.md"


def test01_every_dataset_artifact_is_documented() -> None:
    kinds.load_builtin()
    text = DOC.read_text(encoding="utf-8")
    assert set(READERS) == {"generate.fabric", "generate.btf", "import.btf", "generate.merl",
                            "generate.glint"}  # fmt: skip
    for name in READERS:
        headings = [line for line in text.splitlines() if line.startswith("## ")]
        assert any(f"`{name}`" in h for h in headings), f"{name} has no section"
        for pattern in registered()[name].artifacts:
            assert f"`{pattern}`" in text, f"{name}: {pattern} is not in docs/artifacts.md"
        assert READERS[name].__name__ in text
