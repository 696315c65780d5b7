"""The web process imports the ONNX checker's library before it accepts connections.

Imported on the first submission naming an ONNX model, ``onnx`` held the web process for
about 2 s under load (``benchmarks/bench_attack.py``: ``/api/health`` answered in 1.94 s);
the lifespan imports it first. Checked in a fresh interpreter, where nothing else did.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]


def test01_onnx_is_imported_before_the_first_request(tmp_path: Path) -> None:
    code = textwrap.dedent(
        f"""
        import sys
        from fastapi.testclient import TestClient
        from service.api import create_app
        from service.settings import Settings

        app = create_app(Settings.from_env({{"MATFORGE_DATA": {str(tmp_path)!r}}}))
        before = "onnx" in sys.modules
        with TestClient(app) as client:
            during = "onnx" in sys.modules
            assert client.get("/api/health").status_code == 200
        print(before, during)
        """
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["False", "True"], out.stdout
