"""``docs/api-reference.md`` is generated from the docstrings of ``matforge`` and current."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
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
                 "matforge.datasets.BtfSlices", "torch_dataset", "SpecError",
                 "matforge.export.brdf_mlp", "matforge.export.btf_mlp",
                 "matforge.export_onnx.brdf_onnx", "matforge.export_onnx.btf_onnx"):  # fmt: skip
        assert name in text, name
    assert (REPO / "docs/api-reference.md").read_text(encoding="utf-8") == text, (
        "docs/api-reference.md is stale: run `.venv/bin/python scripts/api_reference.py --write`"
    )


def test02_export_modules_are_public_and_imported_on_first_use() -> None:
    """``matforge.export`` and ``matforge.export_onnx`` are in ``__all__`` and reachable as
    attributes of ``matforge``, yet ``import matforge`` imports neither them nor torch."""
    code = (
        "import sys, matforge\n"
        "assert {'export', 'export_onnx'} <= set(matforge.__all__)\n"
        "before = sorted(m for m in ('matforge.export', 'matforge.export_onnx', 'torch', "
        "'onnx') if m in sys.modules)\n"
        "fns = (matforge.export.brdf_mlp, matforge.export.btf_mlp, "
        "matforge.export_onnx.brdf_onnx, matforge.export_onnx.btf_onnx)\n"
        "print(before, all(callable(f) for f in fns), 'torch' in sys.modules)\n"
        "try:\n    matforge.no_such_name\nexcept AttributeError as e:\n    print(e)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=REPO, check=True).stdout.splitlines()  # fmt: skip
    assert out[0] == "[] True False", out
    assert "no_such_name" in out[1]
