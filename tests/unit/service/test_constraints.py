"""``constraints.txt`` pins exactly the packages each job manifest records, and the
development environment has the pinned versions installed."""

from __future__ import annotations

from importlib import metadata
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

from service.workers.provenance import PINNED_PACKAGES, package_versions

REPO = Path(__file__).resolve().parents[3]


def _pins() -> dict[str, Requirement]:
    lines = (REPO / "constraints.txt").read_text(encoding="utf-8").splitlines()
    reqs = [Requirement(x) for x in (ln.split("#")[0].strip() for ln in lines) if x]
    return {canonicalize_name(r.name): r for r in reqs}


def test01_manifest_records_what_is_pinned() -> None:
    assert set(_pins()) == {canonicalize_name(n) for n in PINNED_PACKAGES}
    assert set(PINNED_PACKAGES) <= set(package_versions())


def test02_pins_are_exact_and_installed() -> None:
    for name, req in _pins().items():
        (spec,) = req.specifier
        assert spec.operator == "==", f"{name}: pin an exact version"
        assert req.specifier.contains(metadata.version(name)), (
            f"{name} {metadata.version(name)} installed, constraints.txt says {req.specifier}"
        )
