"""The refs check's shortcut (the canonical text holds no ref, so nothing is walked) never
skips a spec that holds one.

Reference: the full walk the check does otherwise (``_strings`` with ``JOB_REF`` /
``SHA_REF``, and ``_external_values``), over random nested params with refs placed at any
depth, in lists and dicts, beside non-ASCII and escaped strings.
"""

from __future__ import annotations

import random
from pathlib import Path
from typing import Any

import pytest

from jobapi.errors import SpecError
from jobapi.params import JOB_REF, SHA_REF
from service import kinds
from service.specs import canonical_json, validate_spec
from service.submission import _external_values, _may_hold_refs, _strings, check_refs
from storage.artifacts import ArtifactStore
from storage.jobs import JobStore

REFS = ["job:" + "a" * 32 + "/x.exr", "sha256:" + "b" * 64, "job:" + "c" * 32]
PLAIN = ["gold", 'a "quoted" job: value', "ünïcode sha256:", "x\\job:", "\n", "external"]


def _value(rng: random.Random, depth: int) -> Any:
    r = rng.random()
    if depth > 3 or r < 0.4:
        pool = PLAIN + (REFS if rng.random() < 0.15 else [])
        return rng.choice([*pool, 1, 2.5, None, True])
    if r < 0.7:
        return [_value(rng, depth + 1) for _ in range(rng.randint(0, 3))]
    out = {f"k{i}": _value(rng, depth + 1) for i in range(rng.randint(0, 3))}
    if rng.random() < 0.05:
        out["external"] = {"model": rng.choice(PLAIN + REFS), "kind": "brdf"}
    return out


def _walk_finds(params: Any) -> bool:
    refs = any(JOB_REF.match(v) or SHA_REF.match(v) for _, v in _strings(params, "params"))
    return refs or any(True for _ in _external_values(params, "params"))


def test01_shortcut_agrees_with_the_full_walk() -> None:
    rng = random.Random(7)
    found = 0
    for _ in range(3000):
        params = {"a": _value(rng, 0)}
        text = canonical_json({"kind": "render", "seed": 0, "params": params})
        if _walk_finds(params):
            found += 1
            assert _may_hold_refs(text), text
    assert found > 100  # the generator does place refs


@pytest.fixture
def stores(tmp_path: Path) -> tuple[JobStore, ArtifactStore]:
    kinds.load_builtin()
    return JobStore(tmp_path / "jobs.sqlite3"), ArtifactStore(tmp_path / "store")


def test02_missing_refs_are_still_refused(stores: tuple[JobStore, ArtifactStore]) -> None:
    jobs, store = stores
    spec = validate_spec({"kind": "render", "params": {"material": {"merl": REFS[1]}}})
    with pytest.raises(SpecError, match="no such object in the store"):
        check_refs(spec, jobs, store)
    spec = validate_spec({"kind": "render", "params": {"material": {"merl": REFS[0]}}})
    with pytest.raises(SpecError, match="no job"):
        check_refs(spec, jobs, store)
    plain = validate_spec(
        {"kind": "render", "params": {"material": {"mitsuba": {"type": "diffuse"}}}}
    )
    assert not _may_hold_refs(plain.canonical)
    check_refs(plain, jobs, store)  # nothing to refuse
