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


@pytest.mark.install
def test02_wheel_installs_into_a_clean_venv(tmp_path: Path) -> None:
    """``pip install`` of the wheel, with its dependencies, into a new venv that shares
    nothing with ``.venv``: ``import matforge``, ``matforge.Client``, ``matforge.datasets``
    and the ``matforge`` command work there, from the installed files. torch is installed
    first at the running version, as ``make setup`` does (a bare requirement would pull a
    CUDA build of several GB). About 2 minutes and 2 GB from pip's cache, so it is marked
    ``install`` and run by ``make check-wheel``, not by every ``make test``."""
    from importlib import metadata

    dist = tmp_path / "dist"
    src = tmp_path / "src"
    shutil.copytree(REPO, src, ignore=NOT_SOURCE)
    done = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
         "-w", str(dist), str(src)],
        capture_output=True, text=True, timeout=300, cwd=tmp_path,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    (wheel,) = dist.glob("matforge-*.whl")
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=120)
    pip = [str(venv / "bin" / "python"), "-m", "pip", "install", "-q"]
    torch_pin = f"torch=={metadata.version('torch').split('+')[0]}"
    for args in ([torch_pin], [str(wheel)]):
        step = subprocess.run(pip + args, capture_output=True, text=True, timeout=900)
        assert step.returncode == 0, step.stderr[-3000:]
    code = (
        "import sys, matforge, matforge.datasets as d;"
        "assert matforge.__file__.startswith(sys.prefix), matforge.__file__;"
        "print(matforge.__version__, matforge.Client.__name__, d.open.__name__)"
    )
    env = {"PATH": f"{venv / 'bin'}:/usr/bin:/bin", "HOME": str(tmp_path)}
    run = subprocess.run([str(venv / "bin" / "python"), "-c", code], capture_output=True,
                         text=True, timeout=300, cwd=tmp_path, env=env)  # fmt: skip
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.split() == [matforge.__version__, "Client", "open"]
    cli = subprocess.run([str(venv / "bin" / "matforge"), "--version"], capture_output=True,
                         text=True, timeout=300, cwd=tmp_path, env=env)  # fmt: skip
    assert cli.returncode == 0 and cli.stdout.strip() == f"matforge {matforge.__version__}"
