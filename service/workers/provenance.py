"""Provenance for job manifests: code version and package versions."""

from __future__ import annotations

import functools
import platform
import subprocess
from importlib import metadata
from pathlib import Path

#: The packages that decide artifact bytes: the ones ``constraints.txt`` pins (a test keeps
#: the two lists the same).
PINNED_PACKAGES = (
    "mitsuba",
    "drjit",
    "torch",
    "numpy",
    "scipy",
    "flip-evaluator",
    "scikit-image",
    "OpenEXR",
    "colour-science",
    "pillow",
    "matplotlib",
    "onnx",
    "onnxruntime",
)
_REPO = Path(__file__).resolve().parent.parent


@functools.lru_cache(maxsize=1)
def code_version() -> str:
    """The git commit of the code (``"<sha>"``, ``"<sha>+dirty"``, or ``"unknown"``)."""
    try:
        sha = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=_REPO,
            capture_output=True,
            text=True,
            timeout=5,
            check=True,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=_REPO,
            capture_output=True,
            text=True,
            timeout=5,
        ).stdout
        return sha + ("+dirty" if dirty.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


@functools.lru_cache(maxsize=1)
def package_versions() -> dict[str, str | None]:
    """Installed versions of the packages that determine artifact bytes."""
    out: dict[str, str | None] = {"python": platform.python_version()}
    for name in PINNED_PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out
