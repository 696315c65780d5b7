"""Spec validation, canonical form and identity hash."""

from __future__ import annotations

import hashlib
import json

import pytest

from jobapi.errors import SpecError
from jobapi.params import is_ref
from service.specs import canonical_json, parse_spec_text, validate_spec


def test01_defaults_filled_and_hash_is_sha256_of_canonical(toy_kind) -> None:
    s = validate_spec({"kind": "toy", "params": {"n": 2}})
    body = {"kind": "toy", "seed": 0, "params": {"n": 2, "sleep": 0.0, "fail": False}}
    assert json.loads(s.canonical) == body
    assert s.spec_hash == hashlib.sha256(canonical_json(body).encode()).hexdigest()


def test02_identity_ignores_key_order_name_and_force(toy_kind) -> None:
    a = validate_spec({"kind": "toy", "params": {"n": 2, "sleep": 0.0}, "name": "a"})
    b = validate_spec({"params": {"sleep": 0.0, "n": 2}, "kind": "toy", "force": True})
    assert a.spec_hash == b.spec_hash
    assert (
        validate_spec({"kind": "toy", "seed": 1}).spec_hash
        != validate_spec({"kind": "toy", "seed": 2}).spec_hash
    )


@pytest.mark.parametrize(
    ("spec", "field"),
    [
        ({"kind": "nope"}, "kind"),
        ({"kind": "toy", "params": {"m": 1}}, "params.m"),
        ({"kind": "toy", "params": {"n": "3"}}, "params.n"),
        ({"kind": "toy", "params": {"n": 0}}, "params.n"),
        ({"kind": "toy", "params": {"n": 1001}}, "params.n"),
        ({"kind": "toy", "seed": -1}, "seed"),
        ({"kind": "toy", "seed": "1"}, "seed"),
        ({"kind": "toy", "extra": 1}, "extra"),
        ({"params": {}}, "kind"),
        ([1, 2], ""),
    ],
)
def test03_bad_specs_name_the_field(toy_kind, spec, field: str) -> None:
    with pytest.raises(SpecError) as info:
        validate_spec(spec)
    locs = [loc for loc, _ in info.value.errors]
    assert field in locs, info.value.errors
    if field:
        assert field in str(info.value)


def test04_parse_yaml_and_json() -> None:
    assert parse_spec_text('{"kind": "toy"}') == {"kind": "toy"}
    assert parse_spec_text("kind: toy\nseed: 3\n") == {"kind": "toy", "seed": 3}
    with pytest.raises(SpecError, match="not valid JSON or YAML"):
        parse_spec_text("kind: [unclosed", "bad.yaml")


def test05_refs() -> None:
    assert is_ref("sha256:" + "a" * 64)
    assert is_ref("job:" + "0" * 32 + "/image.exr")
    assert is_ref("job:" + "0" * 32 + "/shard-0001.npz")
    assert not is_ref("job:" + "0" * 32 + "/../x")
    assert not is_ref("sha256:" + "A" * 64)
    assert not is_ref("/etc/passwd")
