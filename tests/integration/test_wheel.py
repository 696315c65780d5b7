"""The built wheel (not the editable install) carries the public API: ``import matforge``,
``matforge.Client``, ``matforge.datasets`` and the ``matforge`` command, at the one version.

The wheel is built with pip (no dependencies, no build isolation: the venv's setuptools)
from a copy of the working tree (a build writes ``build/`` and ``*.egg-info`` beside the
sources; the checkout stays untouched), unpacked, and imported from there in a process
whose working directory is not the checkout, so the modules come from the wheel's files.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

import matforge

REPO = Path(__file__).resolve().parents[2]
#: What is not source: venvs, build outputs, caches, data directories.
NOT_SOURCE = shutil.ignore_patterns(
    ".git",
    ".venv",
    "build",
    "dist",
    "*.egg-info",
    "__pycache__",
    ".*_cache",
    "matforge-data",
    "node_modules",
    "btf-eval-data",
    "tests",
    "benchmarks",
    "docs",
)


@pytest.mark.slow
def test01_wheel_has_the_public_api(tmp_path: Path) -> None:
    src = tmp_path / "src"
    shutil.copytree(REPO, src, ignore=NOT_SOURCE)
    done = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
         "-w", str(tmp_path / "dist"), str(src)],
        capture_output=True, text=True, timeout=300, cwd=tmp_path,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    (wheel,) = (tmp_path / "dist").glob("matforge-*.whl")
    assert wheel.name.startswith(f"matforge-{matforge.__version__}-")
    with zipfile.ZipFile(wheel) as zf:
        names = set(zf.namelist())
        meta = next(n for n in names if n.endswith(".dist-info/entry_points.txt"))
        entry_points = zf.read(meta).decode()
        zf.extractall(tmp_path / "site")
    for module in ("matforge/__init__.py", "matforge/client.py", "matforge/datasets/btf.py",
                   "matforge/datasets/torch_data.py", "jobapi/version.py"):  # fmt: skip
        assert module in names, module
    assert "matforge = service.cli.main:main" in entry_points
    code = (
        "import matforge, matforge.datasets as d, sys;"
        "assert matforge.__file__.startswith(sys.argv[1]), matforge.__file__;"
        "assert 'torch' not in sys.modules;"
        "print(matforge.__version__, matforge.Client.__name__, d.open.__name__)"
    )
    site = str(tmp_path / "site")
    run = subprocess.run(
        [sys.executable, "-c", code, site], capture_output=True, text=True, timeout=120,
        cwd=tmp_path, env={"PYTHONPATH": site, "PATH": "/usr/bin:/bin"},
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.split() == [matforge.__version__, "Client", "open"]
